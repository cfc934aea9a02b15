#pragma once
// What the simulator renders: a dataset's octree-cell-array and top-level
// table, the cameras of a camera path, and the real traversal of every tile
// (traverse/octree_traversal.hpp), memoized because the same tiles recur
// across the configurations of a sweep.
#include <cstdint>
#include <memory>
#include <mutex>
#include <span>
#include <string>
#include <unordered_map>
#include <vector>

#include "common/camera.hpp"
#include "common/camera_path.hpp"
#include "common/octree_cell.hpp"
#include "common/view_options.hpp"
#include "simulator/lit_pixels.hpp"
#include "traverse/core/octree_traversal.hpp"

namespace pointillist::simulator {

// The part of a tile's traversal the model needs.
struct TileWork {
  std::vector<CellPrefix> needs;  // distinct cells, ascending (TraversalResult::needs)
  std::uint64_t splats = 0;
  std::uint64_t cellsVisited = 0;
  std::vector<traverse::PacketRange> ranges;  // drawn (TraversalResult::ranges)
  std::vector<traverse::ScreenBox> boxes;     // where each need draws (TraversalResult::needBoxes)
};

class Scene {
 public:
  // `name` labels reports (the dataset directory, say).
  Scene(std::string name, std::vector<OctreeCell> cells, std::vector<TopLevelCell> topLevel,
        SceneBounds bounds, std::vector<Camera> cameras,
        const traverse::TraversalSettings& traversal, std::size_t loopFrames = 0,
        std::unique_ptr<const LitPixels> litPixels = nullptr, int compressionLevel = 0);
  Scene(const Scene&) = delete;
  Scene& operator=(const Scene&) = delete;

  // Opens a dataset (cells only, as a traverse process does) and builds the
  // cameras of `view` from its bounds; with `litPixels` its points too, to
  // draw each frame once and size tile images by the pixels they light
  // (LitPixels, `threads` drawing; not for statistical packets, which the
  // CPU kernel does not draw). With those, a `compressionLevel` (zstd's, not
  // 0) measures how much each frame's tile images compress at it. Throws
  // InputError / UsageError.
  static Scene load(const std::string& datasetPath, const ViewOptions& view, bool litPixels = false,
                    unsigned threads = 1, int compressionLevel = 0);

  // Tile images sized by the pixels each frame lights (load's litPixels).
  bool hasLitPixels() const { return litPixels_ != nullptr; }
  // The lit pixels and runs of `box` in frame `frame`; hasLitPixels() only.
  LitRuns litRuns(std::uint64_t frame, const TileRect& box) const;
  // How many times smaller frame `frame`'s tile images (a part's words, or a
  // whole tile's RGBA) go compressed; 1 where load measured none.
  double imageCompression(std::uint64_t frame, bool part) const;
  // The level load measured compression at (0: none).
  int compressionLevel() const { return compressionLevel_; }

  const std::string& name() const { return name_; }
  std::span<const OctreeCell> cells() const { return cells_; }
  std::span<const TopLevelCell> topLevel() const { return topLevel_; }
  const SceneBounds& bounds() const { return bounds_; }
  const std::vector<Camera>& cameras() const { return cameras_; }
  // Frames of one loop of a path played several times (--loops), else 0:
  // later loops walk the first's tiles again (the walks are kept once).
  std::size_t loopFrames() const { return loopFrames_; }
  const traverse::TraversalSettings& traversal() const { return traversal_; }
  std::uint32_t width() const;
  std::uint32_t height() const;
  // World margin of the box of interest, as the display computes it: the
  // root's largest splat radius times the size scale.
  float marginWorld() const;
  std::uint64_t datasetBytes() const;

  // The traversal of tile `rect` of frame `frame`; thread-safe, computed once.
  const TileWork& tileWork(std::uint64_t frame, const TileRect& rect) const;
  // The top-level cells reaching into `rect` of frame `frame` (the traverse's
  // prefetch walk, topLevelCellsInTile); thread-safe, computed once.
  const std::vector<CellPrefix>& cellsInTile(std::uint64_t frame, const TileRect& rect) const;
  // The layers of every top-level packet (shared with the simulated traverses).
  const std::shared_ptr<const traverse::PacketLayers>& layers() const { return layers_; }
  // Bytes of the ranges a whole-frame traversal of `frame` draws, joined
  // where at most `gapSplats` apart: with 0 the least any tiling moves, with
  // the traverse's gap (needGapSplats) the most one render holding every tile
  // is sent (a tile's joins are the whole frame's too).
  std::uint64_t frameWorkingSetBytes(std::uint64_t frame, std::uint32_t gapSplats = 0) const;
  // Times whole-frame traversals of the first frames: seconds per visited cell.
  double measureTraverseSecondsPerCell() const;

 private:
  struct Key {
    std::uint64_t frame;
    std::uint32_t x, y, width, height;
    bool operator==(const Key&) const = default;
  };
  struct KeyHash {
    std::size_t operator()(const Key& key) const;
  };

  std::string name_;
  std::vector<OctreeCell> cells_;
  std::vector<TopLevelCell> topLevel_;
  std::shared_ptr<const traverse::PacketLayers> layers_;
  std::unique_ptr<const traverse::CullingTable> culling_;  // over cells_, which never move
  SceneBounds bounds_;
  std::vector<Camera> cameras_;
  std::size_t loopFrames_ = 0;
  traverse::TraversalSettings traversal_;
  std::unique_ptr<const LitPixels> litPixels_;
  int compressionLevel_ = 0;
  mutable std::mutex mutex_;
  // Node-based: references stay valid while other tiles are added.
  mutable std::unordered_map<Key, TileWork, KeyHash> memo_;
  mutable std::unordered_map<Key, std::vector<CellPrefix>, KeyHash> cellsMemo_;
};

}  // namespace pointillist::simulator
