#pragma once
// Which pixels of a frame the job lights, for sizing tile images. A tile
// image goes as runs of the lit pixels of its box (common/pixel_runs.hpp)
// where that is fewer bytes; every lit pixel belongs to one tile, so the
// runs carry the frame's lit pixels however it is cut. The count of a
// packet's splats (what the model used alone) counts the splats of every
// cell the tile touches, those outside it too, and so grew with the number
// of tiles (docs/scheduling.md §20). Here each frame is drawn once, whole,
// by the CPU point kernel the render processes draw with, and a box's lit
// pixels and runs are counted in that frame.
#include <cstdint>
#include <memory>
#include <mutex>
#include <span>
#include <vector>

#include "common/camera.hpp"
#include "common/dataset.hpp"
#include "traverse/core/octree_traversal.hpp"

namespace pointillist::render {
class CpuPointRenderer;
}

namespace pointillist::simulator {

// A box's lit pixels, and the runs encodePixelRuns would cut them into
// (a run per stretch of lit pixels in a row, and one more for empty pixels
// at the box's end).
struct LitRuns {
  std::uint64_t lit = 0;
  std::uint64_t runs = 0;
  bool operator==(const LitRuns&) const = default;
};

// A frame's lit pixels as bits, rows bottom-up as the renderers keep them.
class FrameCoverage {
 public:
  FrameCoverage() = default;
  // Lit where a word is not `empty` (width x height words, rows bottom-up).
  FrameCoverage(std::span<const std::uint64_t> words, std::uint32_t width, std::uint32_t height,
                std::uint64_t empty);

  std::uint64_t litPixels() const { return lit_; }
  // The part of `box` inside the frame.
  LitRuns count(const TileRect& box) const;

  // How many times smaller zstd made this frame's tile images, whole tiles'
  // RGBA runs and parts' word runs (LitPixels measures them; 1: not measured).
  double wholeCompression() const { return wholeCompression_; }
  double partCompression() const { return partCompression_; }
  void setCompression(double whole, double part) {
    wholeCompression_ = whole;
    partCompression_ = part;
  }

 private:
  bool bit(std::uint32_t x, std::uint32_t y) const {
    return ((bits_[std::size_t{y} * rowWords_ + x / 64] >> (x % 64)) & 1u) != 0;
  }
  std::uint32_t width_ = 0, height_ = 0;
  std::size_t rowWords_ = 0;
  std::uint64_t lit_ = 0;
  std::vector<std::uint64_t> bits_;
  double wholeCompression_ = 1.0, partCompression_ = 1.0;
};

// The edge of the blocks a frame is cut into to measure compression: about
// a tile of the cost scheduler (zstd's ratio moves little with the size: the
// city's 4K frames 3.7-4.0 times from 32 to 256 pixels at level 3).
inline constexpr std::uint32_t kCompressionBlock = 64;

// How many times smaller compressImageBytes at `level` makes the runs of a
// frame's pixels (`pixelBytes` each: 4 RGBA, 8 words; `empty` skipped) cut
// into kCompressionBlock squares, each compressed apart as tile images are.
// 1 where nothing is lit.
double measureCompression(std::span<const std::byte> frame, std::size_t pixelBytes,
                          std::uint32_t width, std::uint32_t height,
                          std::span<const std::byte> empty, int level);

// Every frame of a camera path drawn once (on first use, then kept) from a
// dataset's points: thread-safe.
class LitPixels {
 public:
  // Takes the points of every top-level packet (`dataset` opened with its
  // points); `cameras` and `traversal` as the scene's. Throws UsageError for
  // a dataset the point kernel cannot draw (statistical packets). A
  // `compressionLevel` (zstd's, not 0) also measures each frame's compression.
  LitPixels(const Dataset& dataset, std::span<const Camera> cameras,
            const traverse::TraversalSettings& traversal, unsigned threads,
            int compressionLevel = 0);
  ~LitPixels();
  LitPixels(const LitPixels&) = delete;
  LitPixels& operator=(const LitPixels&) = delete;

  // Frame `frame`'s coverage (a whole-frame traversal of `culling`, drawn).
  const FrameCoverage& frame(std::uint64_t frame, const traverse::CullingTable& culling) const;

 private:
  std::vector<Camera> cameras_;
  traverse::TraversalSettings traversal_;
  int compressionLevel_ = 0;
  std::unique_ptr<render::CpuPointRenderer> renderer_;  // drawn under mutex_
  mutable std::mutex mutex_;
  mutable std::vector<std::unique_ptr<FrameCoverage>> frames_;
};

}  // namespace pointillist::simulator
