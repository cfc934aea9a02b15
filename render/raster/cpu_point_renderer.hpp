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
#include <cstdint>
#include <span>
#include <string>
#include <unordered_map>
#include <vector>

#include <glm/glm.hpp>

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

// Draws `splats` into `buffer` (tileWidth x tileHeight words, rows bottom-up),
// keeping the minimum word per pixel.
void rasterizePoints(const PointRaster& raster, std::span<const Splat> splats,
                     std::uint64_t* buffer);

class CpuPointRenderer final : public TileRenderer {
 public:
  // `threads` draw a tile together, each into its own buffer: 1 in a render
  // process that shares the machine with others; the cores for the reference.
  explicit CpuPointRenderer(unsigned threads = 1);

  void uploadCell(std::uint32_t id, std::span<const Splat> splats) override;
  void releaseCell(std::uint32_t id) override;
  RenderStats render(const Camera& camera, const TileRect& rect, std::span<const DrawRange> ranges,
                     const RenderSettings& settings) override;
  std::span<const std::uint8_t> pixels() const override { return pixels_; }
  void warmUp(const RenderSettings&) override {}
  std::string describe() const override;

  unsigned threads() const { return threads_; }

 private:
  unsigned threads_;
  std::unordered_map<std::uint32_t, std::vector<Splat>> cells_;
  std::vector<std::uint64_t> buffers_;  // one tile-sized buffer per thread
  std::vector<std::uint8_t> pixels_;
};

}  // namespace pointillist::render
