#pragma once
// The data-traverse walk of seed 003 §4.3 over the octree-cell-array: the
// sibling-skip loop, conservative culling against a mini frustum (tile) and by
// normal cone, and level-of-detail selection from projected splat size.
//
// Every decision except the frustum test depends on the camera only, never on
// the tile, so the union of all tiles' packets draws exactly what a full-frame
// traversal draws: that is what makes composed frames match the reference.
#include <cstdint>
#include <memory>
#include <mutex>
#include <span>
#include <string>
#include <vector>

#include "common/camera.hpp"
#include "common/cell_prefix.hpp"
#include "common/dataset.hpp"
#include "common/octree_cell.hpp"
#include "common/statistical_cut.hpp"
#include "traverse/core/culling_table.hpp"
#include "traverse/core/packet_layers.hpp"

namespace pointillist {
struct ViewOptions;
}

namespace pointillist::traverse {

// --mode instanced: the instancing units' sections (seed 000), per octree
// cell, from the dataset's instanced-sections.bin.
class InstancedCells {
 public:
  // Throws UsageError for a dataset built without --instanced, InputError
  // when a section lies outside its packet's sections.
  InstancedCells(std::span<const OctreeCell> cells, std::span<const TopLevelCell> topLevel,
                 std::span<const std::byte> sectionsFile, const std::string& datasetName);
  // Reads the file from the dataset (which must have its cells loaded).
  static std::shared_ptr<const InstancedCells> load(const Dataset& dataset);
  struct Cell {
    std::uint32_t offset = 0;   // the section's first record in the packet
    std::uint32_t records = 0;  // 0: no section, the cell draws its points
  };
  const Cell& operator[](std::uint32_t cell) const { return cells_[cell]; }

 private:
  std::vector<Cell> cells_;
};

// --mode statistical: the cut of one camera, kept while tiles of its frame
// come in (the cut is the same for every tile of a frame). Thread-safe.
class StatisticalCutMemo {
 public:
  explicit StatisticalCutMemo(std::shared_ptr<const StatisticalTrees> trees);
  const StatisticalTrees& trees() const { return *trees_; }
  std::shared_ptr<const StatisticalCut> cutFor(const Camera& camera,
                                               const StatisticalCutSettings& settings);

 private:
  struct Entry {
    std::string camera;  // serialized
    StatisticalCutSettings settings;
    std::shared_ptr<const StatisticalCut> cut;
  };
  std::shared_ptr<const StatisticalTrees> trees_;
  std::mutex mutex_;
  std::vector<Entry> recent_;
};

struct TraversalSettings {
  // Draw a cell's level-splats once its largest splat projects to at most this
  // many pixels in radius at the cell's nearest point (about one splat per pixel).
  float lodPixels = 1.0f;
  // Renderer's radius multiplier; culling grows splat radii by the same factor.
  float sizeScale = 1.0f;
  // Pixels added around the tile: a rasterized splat may reach about one pixel
  // beyond its projected radius (rounding of point sizes, minimum sizes).
  float marginPixels = 1.0f;
  bool backfaceCull = true;
  // A cell whose parent lies wholly inside some of the tile's planes, or
  // whose splats all face the eye, is not tested against those planes, or for
  // facing away: the answers are known. Off only to test that it decides the
  // same.
  bool inheritCulling = true;
  // --mode instanced: an instancing unit of which a whole-frame walk would
  // draw any point draws its whole section instead. The frustum plays no part
  // in that choice (a camera-only decision, like level of detail), so tiles
  // still add up to the full frame; sections lie before the points, so the
  // prefix a render process needs is shorter.
  std::shared_ptr<const InstancedCells> instanced;
  // --mode statistical (seed 004): the octree plays no part; the ranges are
  // node ranges of the cut (common/statistical_cut.hpp) in statistical packets.
  std::shared_ptr<StatisticalCutMemo> statistical;
  // Fill TraversalResult::needBoxes (the walk projects every drawn cell's
  // bounds): the screen box of a packet, which the simulator takes for the
  // box its render draws in and sends. Not for statistical walks.
  bool screenBoxes = false;
};

// Frame pixels [x0, x1) x [y0, y1) (bottom-left origin), not clipped to any
// tile; a box of a cell reaching behind the eye spans everything.
struct ScreenBox {
  float x0 = 0.0f, y0 = 0.0f, x1 = 0.0f, y1 = 0.0f;
  bool empty() const { return !(x1 > x0 && y1 > y0); }
  void add(const ScreenBox& other);  // the union
};
// The part of `rect` that boxes cover, whole pixels; zero sides when none.
TileRect clipScreenBox(const ScreenBox& box, const TileRect& rect);

// Where a camera puts the grown bounds of cells on its frame.
class ScreenBoxProjector {
 public:
  ScreenBoxProjector(const Camera& camera, float marginPixels);
  ScreenBox project(const glm::vec3& low, const glm::vec3& high) const;

 private:
  glm::mat4 viewProjection_;
  float width_, height_, margin_;
};

// A view's level of detail, size scale and back-face culling (the tools'
// --lod-pixels, --size-scale, --no-backface-cull); a mode's instanced or
// statistical data is the caller's to load.
TraversalSettings traversalSettings(const ViewOptions& view);

// One drawn range: splats [offset, offset + count) of a top-level cell's packet.
struct PacketRange {
  std::uint32_t topLevel = 0;
  std::uint32_t offset = 0;
  std::uint32_t count = 0;
  bool section = false;  // an instanced section (never merged with a neighbour)
  bool operator==(const PacketRange&) const = default;
};

struct TraversalResult {
  // Sorted by (topLevel, offset), merged when adjacent. An instanced section
  // is one range of its records (common/octree_cell.hpp, inInstancedSection).
  std::vector<PacketRange> ranges;
  // The top-level cells drawn from (distinct, ascending), each with the
  // shortest prefix holding its ranges (the largest range end).
  std::vector<CellPrefix> needs;
  // With TraversalSettings::screenBoxes, parallel to needs: the box that the
  // drawn cells of each need's top-level cell cover (their grown bounds
  // projected, grown by the margin). Empty otherwise.
  std::vector<ScreenBox> needBoxes;
  // To draw: an instanced section counts the points it generates, a
  // statistical node its estimated generated points.
  std::uint64_t splats = 0;
  std::uint64_t sections = 0;  // instanced sections drawn, or statistical nodes
  std::uint64_t cellsVisited = 0;
  std::uint64_t cellsCulledFrustum = 0;
  std::uint64_t cellsCulledBackface = 0;
};

// Walks the table's cells for the tile `rect` of `camera` (pass the full frame
// rect for a whole-frame traversal). The table's size scale must be the settings'.
TraversalResult traverseTile(const CullingTable& table, const Camera& camera, const TileRect& rect,
                             const TraversalSettings& settings);
// The same, making the culling table first (for one-off walks and tests).
TraversalResult traverseTile(std::span<const OctreeCell> cells, const Camera& camera,
                             const TileRect& rect, const TraversalSettings& settings);

// The top-level cells whose bounds reach into the tile: the same culling as
// traverseTile down to the top-level depth, without level-of-detail selection
// (a superset of the cells traverseTile returns, at a fraction of the walk),
// each with the prefix its distance probably needs (PacketLayers::prefixAt).
std::vector<CellPrefix> topLevelCellsInTile(const CullingTable& table, const PacketLayers& layers,
                                            const Camera& camera, const TileRect& rect,
                                            const TraversalSettings& settings);
std::vector<CellPrefix> topLevelCellsInTile(std::span<const OctreeCell> cells,
                                            const PacketLayers& layers, const Camera& camera,
                                            const TileRect& rect,
                                            const TraversalSettings& settings);

// True when every splat of the cell faces away from the eye (conservative:
// combines the normal cone with the cone of view directions onto the cell).
bool cellBackfacing(const OctreeCell& cell, const glm::vec3& eye, float sizeScale);

// Euclidean distance from the eye to the cell's bounds grown by its splat radius (0 inside).
float distanceToCell(const OctreeCell& cell, const glm::vec3& eye, float sizeScale);

}  // namespace pointillist::traverse
