#include "render/raster/cpu_point_renderer.hpp"

#include <algorithm>
#include <bit>
#include <chrono>
#include <cmath>
#include <thread>

#include "common/errors.hpp"

namespace pointillist::render {
namespace {

std::uint8_t unitToByte(float value) {
  return static_cast<std::uint8_t>(std::clamp(value, 0.0f, 1.0f) * 255.0f + 0.5f);
}

std::uint32_t packColor(std::uint32_t r, std::uint32_t g, std::uint32_t b, std::uint32_t a) {
  return r | (g << 8) | (b << 16) | (a << 24);
}

}  // namespace

PointRaster pointRaster(const Camera& camera, const TileRect& rect,
                        const RenderSettings& settings) {
  PointRaster raster;
  raster.viewProjection = viewProjectionMatrix(camera);
  raster.frameWidth = static_cast<float>(camera.image_width());
  raster.frameHeight = static_cast<float>(camera.image_height());
  const float scale = settings.sizeScale > 0.0f ? settings.sizeScale : 1.0f;
  raster.diameterScale = 2.0f * pixelsPerUnit(camera, 1.0f) * scale;
  raster.constantSize = std::max(settings.pointSize, 0.0f);
  raster.maxSize = std::max(1.0f, std::floor(settings.maxPointSize));
  raster.lighting = settings.lighting;
  raster.ambient = std::clamp(settings.ambient, 0.0f, 1.0f);
  raster.eye = cameraEye(camera);
  raster.tileX = static_cast<std::int32_t>(rect.x());
  raster.tileY = static_cast<std::int32_t>(rect.y());
  raster.tileWidth = static_cast<std::int32_t>(rect.width());
  raster.tileHeight = static_cast<std::int32_t>(rect.height());
  return raster;
}

void rasterizePoints(const PointRaster& r, std::span<const Splat> splats, std::uint64_t* buffer) {
  const glm::mat4& m = r.viewProjection;  // column-major: m[column][row]
  const auto tileX = static_cast<float>(r.tileX);
  const auto tileY = static_cast<float>(r.tileY);
  const auto tileRight = static_cast<float>(r.tileX + r.tileWidth);
  const auto tileTop = static_cast<float>(r.tileY + r.tileHeight);
  const std::size_t stride = static_cast<std::size_t>(r.tileWidth);
  for (const Splat& s : splats) {
    const float x = s.position[0], y = s.position[1], z = s.position[2];
    const float cw = m[0][3] * x + m[1][3] * y + m[2][3] * z + m[3][3];
    if (!(cw > 0.0f)) continue;  // behind the eye
    const float inverse = 1.0f / cw;
    const float nz = (m[0][2] * x + m[1][2] * y + m[2][2] * z + m[3][2]) * inverse;
    if (!(nz >= -1.0f && nz <= 1.0f)) continue;  // before the near or beyond the far plane
    const float nx = (m[0][0] * x + m[1][0] * y + m[2][0] * z + m[3][0]) * inverse;
    const float ny = (m[0][1] * x + m[1][1] * y + m[2][1] * z + m[3][1]) * inverse;
    float size = r.constantSize > 0.0f ? r.constantSize : s.radius * r.diameterScale * inverse;
    size = std::clamp(std::floor(size + 0.5f), 1.0f, r.maxSize);
    // As GL points: odd sizes centred on a pixel centre, even ones on a corner.
    const float wx = (nx * 0.5f + 0.5f) * r.frameWidth;
    const float wy = (ny * 0.5f + 0.5f) * r.frameHeight;
    const bool odd = std::fmod(size, 2.0f) == 1.0f;
    const float sx = odd ? std::floor(wx) + 0.5f : std::floor(wx + 0.5f);
    const float sy = odd ? std::floor(wy) + 0.5f : std::floor(wy + 0.5f);
    const float half = 0.5f * size;
    const float x0f = std::floor(sx - half + 0.5f);
    const float y0f = std::floor(sy - half + 0.5f);
    if (!(x0f < tileRight && x0f + size > tileX && y0f < tileTop && y0f + size > tileY)) {
      continue;  // misses the tile (also NaN and far outside)
    }
    const auto x0 = static_cast<std::int32_t>(std::max(x0f, tileX)) - r.tileX;
    const auto y0 = static_cast<std::int32_t>(std::max(y0f, tileY)) - r.tileY;
    const auto x1 = static_cast<std::int32_t>(std::min(x0f + size, tileRight)) - r.tileX;
    const auto y1 = static_cast<std::int32_t>(std::min(y0f + size, tileTop)) - r.tileY;

    float shade = 1.0f;
    const glm::vec3 normal(s.normal[0], s.normal[1], s.normal[2]);
    if (r.lighting && glm::dot(normal, normal) > 0.25f) {  // no normal: unshaded
      const glm::vec3 toEye = r.eye - glm::vec3(x, y, z);
      const float distance = glm::length(toEye);
      if (distance > 0.0f) {
        shade = r.ambient +
                (1.0f - r.ambient) * std::abs(glm::dot(glm::normalize(normal), toEye / distance));
      }
    }
    const auto channel = [shade](std::uint8_t value) {
      return static_cast<std::uint32_t>(static_cast<float>(value) * shade + 0.5f);
    };
    const std::uint32_t color =
        packColor(channel(s.color[0]), channel(s.color[1]), channel(s.color[2]), s.color[3]);
    const std::uint64_t word =
        (static_cast<std::uint64_t>(std::bit_cast<std::uint32_t>(nz * 0.5f + 0.5f)) << 32) | color;
    for (std::int32_t py = y0; py < y1; ++py) {
      std::uint64_t* row = buffer + static_cast<std::size_t>(py) * stride;
      for (std::int32_t px = x0; px < x1; ++px) row[px] = std::min(row[px], word);
    }
  }
}

CpuPointRenderer::CpuPointRenderer(unsigned threads) : threads_(std::max(1u, threads)) {}

void CpuPointRenderer::uploadCell(std::uint32_t id, std::span<const Splat> splats) {
  cells_[id].assign(splats.begin(), splats.end());
}

void CpuPointRenderer::releaseCell(std::uint32_t id) {
  cells_.erase(id);
}

std::string CpuPointRenderer::describe() const {
  return "cpu: point kernel, " + std::to_string(threads_) + " thread(s) per tile";
}

RenderStats CpuPointRenderer::render(const Camera& camera, const TileRect& rect,
                                     std::span<const DrawRange> ranges,
                                     const RenderSettings& settings) {
  if (settings.mode != SplatMode::Points) {
    throw UsageError(std::string("the cpu renderer draws points only, not ") +
                     splatModeName(settings.mode));
  }
  validateCamera(camera);
  if (!tileInsideFrame(camera, rect)) {
    throw UsageError("CpuPointRenderer::render: tile rectangle is empty or outside the image");
  }
  const auto start = std::chrono::steady_clock::now();
  // The splats to draw, as spans of cached cells.
  std::vector<std::span<const Splat>> parts;
  parts.reserve(ranges.size());
  RenderStats stats;
  for (const DrawRange& range : ranges) {
    const auto found = cells_.find(range.cell);
    if (found == cells_.end()) {
      throw UsageError("CpuPointRenderer::render: cell " + std::to_string(range.cell) +
                       " is not uploaded");
    }
    const std::vector<Splat>& cell = found->second;
    if (range.offset > cell.size() || range.count > cell.size() - range.offset) {
      throw UsageError("CpuPointRenderer::render: range " + std::to_string(range.offset) + "+" +
                       std::to_string(range.count) + " is outside cell " +
                       std::to_string(range.cell) + " (" + std::to_string(cell.size()) +
                       " splats)");
    }
    if (range.count == 0) continue;
    parts.emplace_back(cell.data() + range.offset, range.count);
    stats.splats += range.count;
  }
  stats.drawCalls = static_cast<std::uint32_t>(parts.size());

  const PointRaster raster = pointRaster(camera, rect, settings);
  const std::size_t tilePixels = static_cast<std::size_t>(rect.width()) * rect.height();
  // More threads than a few thousand splats each would cost more than they save.
  const auto threads =
      static_cast<unsigned>(std::clamp<std::uint64_t>(stats.splats / 8192, 1, threads_));
  buffers_.assign(tilePixels * threads, kEmptyPixel);
  const auto drawShare = [&](unsigned share) {
    std::uint64_t* buffer = buffers_.data() + tilePixels * share;
    // Splats [begin, end) of the whole list, cut across parts.
    const std::uint64_t begin = stats.splats * share / threads;
    const std::uint64_t end = stats.splats * (share + 1) / threads;
    std::uint64_t at = 0;
    for (std::span<const Splat> part : parts) {
      const std::uint64_t partEnd = at + part.size();
      if (partEnd > begin && at < end) {
        const std::uint64_t from = std::max(begin, at) - at;
        const std::uint64_t to = std::min(end, partEnd) - at;
        rasterizePoints(raster, part.subspan(from, to - from), buffer);
      }
      at = partEnd;
    }
  };
  if (threads == 1) {
    drawShare(0);
  } else {
    std::vector<std::jthread> workers;
    for (unsigned share = 1; share < threads; ++share) workers.emplace_back(drawShare, share);
    drawShare(0);
    workers.clear();  // joins
    for (unsigned share = 1; share < threads; ++share) {
      const std::uint64_t* other = buffers_.data() + tilePixels * share;
      for (std::size_t i = 0; i < tilePixels; ++i) buffers_[i] = std::min(buffers_[i], other[i]);
    }
  }

  const std::array<std::uint8_t, 4> background{
      unitToByte(settings.clearColor[0]), unitToByte(settings.clearColor[1]),
      unitToByte(settings.clearColor[2]), unitToByte(settings.clearColor[3])};
  pixels_.resize(tilePixels * 4);
  for (std::size_t i = 0; i < tilePixels; ++i) {
    const std::uint64_t word = buffers_[i];
    std::uint8_t* out = pixels_.data() + 4 * i;
    if (word == kEmptyPixel) {
      std::copy(background.begin(), background.end(), out);
      continue;
    }
    const auto color = static_cast<std::uint32_t>(word);
    out[0] = static_cast<std::uint8_t>(color);
    out[1] = static_cast<std::uint8_t>(color >> 8);
    out[2] = static_cast<std::uint8_t>(color >> 16);
    out[3] = static_cast<std::uint8_t>(color >> 24);
  }
  stats.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return stats;
}

}  // namespace pointillist::render
