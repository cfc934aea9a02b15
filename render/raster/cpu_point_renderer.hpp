#pragma once
// The points mode on the CPU: one splat, one square of whole pixels, as the
// GL points path draws it (size = projected diameter rounded, centre snapped to
// the full-frame pixel grid, headlight shading), without llvmpipe's per-vertex
// pipeline.
//
// Depth and colour are packed into one 64-bit word (depth in the high half, a
// positive float's bits order as the float does) and each pixel keeps the
// minimum: the nearest splat wins and equal depths fall to the smaller colour,
// so the result does not depend on the order splats are drawn in. That makes
// a tile equal the same rectangle of the whole frame, and lets several threads
// draw parts of one tile into their own buffers and merge them by minimum.
//
// rasterizePoints is a SIMD kernel (Highway, dispatched at run time to the
// best target the CPU has); rasterizePointsScalar is its reference. Both give
// every splat the same pixels and the same word, bit for bit, whatever the
// target and wherever the splat falls in a batch: job tiles are compared
// pixel for pixel with a full frame drawn elsewhere.
#include <array>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <new>
#include <span>
#include <string>
#include <unordered_map>
#include <vector>

#include <glm/glm.hpp>

#include "common/pixel_runs.hpp"
#include "common/point_groups.hpp"
#include "render/raster/tile_renderer.hpp"

namespace pointillist::render {

// What the kernel needs of a camera, a tile and the settings, worked out once
// per tile.
struct PointRaster {
  glm::mat4 viewProjection{1.0f};
  float frameWidth = 0.0f;
  float frameHeight = 0.0f;
  float diameterScale = 0.0f;  // 2 * focal length in pixels * size scale
  float constantSize = 0.0f;   // > 0: every point this wide
  float maxSize = 64.0f;
  bool lighting = true;
  float ambient = 0.3f;
  glm::vec3 eye{0.0f};
  std::int32_t tileX = 0;  // the tile in full-frame pixels
  std::int32_t tileY = 0;
  std::int32_t tileWidth = 0;
  std::int32_t tileHeight = 0;
};

PointRaster pointRaster(const Camera& camera, const TileRect& rect, const RenderSettings& settings);

// The packed word of an empty pixel.
inline constexpr std::uint64_t kEmptyPixel = ~std::uint64_t{0};

// The smallest box of a width x height tile of words (rows bottom-up) that
// holds every word drawn (not kEmptyPixel); width and height 0 when none is.
// A part of a split tile sends only this box (v1::TileImageHeader.drawn_rect).
PixelBox drawnWordsBox(std::span<const std::uint64_t> words, std::uint32_t width,
                       std::uint32_t height);
// The same for RGBA8 pixels (4 bytes a pixel, rows bottom-up): the box of
// every pixel that is not `background`. A whole tile sends only this box
// when its background is the display's.
PixelBox drawnRgbaBox(std::span<const std::uint8_t> rgba, std::uint32_t width, std::uint32_t height,
                      const std::array<std::uint8_t, 4>& background);

// Where one splat lands: pixels [x0, x1) x [y0, y1) of the tile, and its word.
// All zero when it is not drawn.
struct PointFootprint {
  std::int32_t x0 = 0, y0 = 0, x1 = 0, y1 = 0;
  std::uint64_t word = 0;
  bool operator==(const PointFootprint&) const = default;
};

PointFootprint pointFootprintScalar(const PointRaster& raster, const Splat& splat);

// The reference kernel: draws `splats` into `buffer` (tileWidth x tileHeight
// words, rows bottom-up), keeping the minimum word per pixel.
void rasterizePointsScalar(const PointRaster& raster, std::span<const Splat> splats,
                           std::uint64_t* buffer);

// A cell as the SIMD kernel streams it: common/point_groups.hpp's layout, in a
// block of its own or, as a view, in a block held elsewhere (a data-send
// process's shared memory, which render processes of its machine draw from
// in place).
class PointCell {
 public:
  static constexpr std::size_t kPad = PointGroups::kPad;
  static constexpr std::size_t kX = PointGroups::kX, kY = PointGroups::kY, kZ = PointGroups::kZ;
  static constexpr std::size_t kRadius = PointGroups::kRadius;
  static constexpr std::size_t kNormalX = PointGroups::kNormalX;
  static constexpr std::size_t kNormalY = PointGroups::kNormalY;
  static constexpr std::size_t kNormalZ = PointGroups::kNormalZ;
  static constexpr std::size_t kColor = PointGroups::kColor;
  static constexpr std::size_t kFields = PointGroups::kFields;
  static constexpr std::size_t kGroupValues = PointGroups::kGroupValues;
  static constexpr std::size_t valueIndex(std::size_t field, std::size_t i) {
    return PointGroups::valueIndex(field, i);
  }

  // A view of `count` splats of a block (kAlignment-aligned, whole groups)
  // that outlives it; appending to it copies the held splats first.
  static PointCell view(const float* values, std::size_t count, bool hasNormals);

  std::size_t count = 0;
  bool hasNormals = false;  // any normal long enough to shade with

  const float* x(std::size_t i) const { return field<float>(kX, i); }
  const float* y(std::size_t i) const { return field<float>(kY, i); }
  const float* z(std::size_t i) const { return field<float>(kZ, i); }
  const float* radius(std::size_t i) const { return field<float>(kRadius, i); }
  const float* nx(std::size_t i) const { return field<float>(kNormalX, i); }
  const float* ny(std::size_t i) const { return field<float>(kNormalY, i); }
  const float* nz(std::size_t i) const { return field<float>(kNormalZ, i); }
  const std::uint32_t* color(std::size_t i) const {  // RGBA8, R low
    return field<std::uint32_t>(kColor, i);
  }

  // The block's values, as valueIndex counts them.
  const float* values() const {
    return view_ != nullptr ? view_ : reinterpret_cast<const float*>(block_.get());
  }
  bool isView() const { return view_ != nullptr; }

  // Room for `splats` (and the padding after them) in a block of its own,
  // keeping the splats held; new entries are zero.
  void reserve(std::size_t splats);

 private:
  friend void writeToPointCell(PointCell& cell, std::size_t first, std::span<const Splat> splats,
                               std::size_t room);
  struct BlockDeleter {
    void operator()(std::byte* block) const {
      ::operator delete (block, std::align_val_t{PointGroups::kAlignment});
    }
  };
  template <class T>
  const T* field(std::size_t k, std::size_t i) const {
    static_assert(sizeof(T) == 4);
    return reinterpret_cast<const T*>(values()) + valueIndex(k, i);
  }
  std::size_t capacity_ = 0;  // splats of the own block, a multiple of kPad
  std::unique_ptr<std::byte[], BlockDeleter> block_;
  const float* view_ = nullptr;
};

PointCell makePointCell(std::span<const Splat> splats);
// Writes splats as splats first, first + 1, ... of the cell, first making
// room for `room` splats (at least first + splats.size()) when they do not
// fit in its own block; a view is copied first. What lies between written
// splats is zero. The cell's count grows to the end of the last written.
void writeToPointCell(PointCell& cell, std::size_t first, std::span<const Splat> splats,
                      std::size_t room = 0);
// Adds splats after the cell's current ones, keeping the padding.
void appendToPointCell(PointCell& cell, std::span<const Splat> splats);

// Draws splats [from, to) of `cell` as rasterizePointsScalar would.
void rasterizePoints(const PointRaster& raster, const PointCell& cell, std::size_t from,
                     std::size_t to, std::uint64_t* buffer);

// Splats [from, to) of one cached cell.
struct PointRange {
  const PointCell* cell = nullptr;
  std::size_t from = 0;
  std::size_t to = 0;
};
// Draws every range as rasterizePoints would one after the other (the same
// pixels: each keeps the minimum word), in one pass of the kernel whose
// batches of footprints run across ranges. A tile holds thousands of short
// ranges (a cell's own level-splats); a batch per range cost more than
// drawing them.
void rasterizePointRanges(const PointRaster& raster, std::span<const PointRange> ranges,
                          std::uint64_t* buffer);

// What the SIMD kernel computes for splats [from, to) of `cell`, one per
// splat, before drawing (for tests).
std::vector<PointFootprint> pointFootprints(const PointRaster& raster, const PointCell& cell,
                                            std::size_t from, std::size_t to);

// The Highway target the kernel dispatches to, e.g. "AVX3", and the ones it
// could use on this CPU (Highway target bits), best first. For tests,
// forcePointKernelTarget(t) makes the kernel use target `t` (0: the best again).
std::string pointKernelTargetName();
std::vector<std::int64_t> pointKernelTargets();
void forcePointKernelTarget(std::int64_t target);

class CpuPointRenderer final : public TileRenderer {
 public:
  // `threads` draw a tile together, each into its own buffer: 1 in a render
  // process that shares the machine with others; the cores for the reference.
  explicit CpuPointRenderer(unsigned threads = 1);

  void uploadCell(std::uint32_t id, std::span<const Splat> splats) override;
  void writeToCell(std::uint32_t id, std::uint32_t first, std::span<const Splat> splats,
                   std::size_t room) override;
  bool viewCell(std::uint32_t id, const float* groups, std::size_t count, bool hasNormals) override;
  bool viewsInPlace() const override { return true; }
  void forEachCell(const CellVisitor& visit) const override;
  void releaseCell(std::uint32_t id) override;
  RenderStats render(const Camera& camera, const TileRect& rect, std::span<const DrawRange> ranges,
                     const RenderSettings& settings) override;
  std::span<const std::uint8_t> pixels() const override { return pixels_; }
  // From the packed words' depth half (settings.keepDepth).
  std::span<const float> depths() const override { return depths_; }
  std::span<const std::uint64_t> pointWords() const override {
    return {buffers_.data(), pixels_.size() / 4};
  }
  void warmUp(const RenderSettings&) override {}
  std::string describe() const override;

  unsigned threads() const { return threads_; }

 private:
  unsigned threads_;
  std::unordered_map<std::uint32_t, PointCell> cells_;
  std::vector<std::uint64_t> buffers_;  // one tile-sized buffer per thread
  std::vector<std::uint8_t> pixels_;
  std::vector<float> depths_;
};

}  // namespace pointillist::render
