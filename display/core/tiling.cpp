#include "display/core/tiling.hpp"

#include <algorithm>
#include <cmath>

namespace pointillist::display {

std::optional<TileRect> boxOfInterest(const Camera& camera, const glm::vec3& boxMin,
                                      const glm::vec3& boxMax, float marginWorld) {
  const glm::vec3 low = boxMin - glm::vec3(marginWorld);
  const glm::vec3 high = boxMax + glm::vec3(marginWorld);
  if (boxOutside(framePlanes(camera), low, high)) return std::nullopt;
  float minX = INFINITY, minY = INFINITY, maxX = -INFINITY, maxY = -INFINITY;
  for (int corner = 0; corner < 8; ++corner) {
    const glm::vec3 p((corner & 1) != 0 ? high.x : low.x, (corner & 2) != 0 ? high.y : low.y,
                      (corner & 4) != 0 ? high.z : low.z);
    const glm::vec4 window = projectToWindow(camera, p);
    if (window.w <= camera.near_plane()) return fullFrameRect(camera);  // box reaches the eye
    minX = std::min(minX, window.x);
    maxX = std::max(maxX, window.x);
    minY = std::min(minY, window.y);
    maxY = std::max(maxY, window.y);
  }
  const auto width = static_cast<float>(camera.image_width());
  const auto height = static_cast<float>(camera.image_height());
  // Whole pixels touched, with one pixel of slack for rasterization.
  const float x0 = std::clamp(std::floor(minX) - 1.0f, 0.0f, width);
  const float y0 = std::clamp(std::floor(minY) - 1.0f, 0.0f, height);
  const float x1 = std::clamp(std::ceil(maxX) + 1.0f, 0.0f, width);
  const float y1 = std::clamp(std::ceil(maxY) + 1.0f, 0.0f, height);
  if (x1 <= x0 || y1 <= y0) return std::nullopt;
  return makeTileRect(static_cast<std::uint32_t>(x0), static_cast<std::uint32_t>(y0),
                      static_cast<std::uint32_t>(x1 - x0), static_cast<std::uint32_t>(y1 - y0));
}

std::vector<TileRect> splitIntoTiles(const TileRect& area, std::uint32_t targetTiles,
                                     std::uint32_t minTileSize) {
  std::vector<TileRect> tiles;
  if (area.width() == 0 || area.height() == 0) return tiles;
  const std::uint32_t target = std::max<std::uint32_t>(targetTiles, 1);
  const std::uint32_t minSize = std::max<std::uint32_t>(minTileSize, 1);
  const double aspect = static_cast<double>(area.width()) / static_cast<double>(area.height());
  auto columns = static_cast<std::uint32_t>(std::max(1.0, std::round(std::sqrt(target * aspect))));
  auto rows = static_cast<std::uint32_t>(
      std::max(1.0, std::round(static_cast<double>(target) / static_cast<double>(columns))));
  columns =
      std::clamp<std::uint32_t>(columns, 1, std::max<std::uint32_t>(1, area.width() / minSize));
  rows = std::clamp<std::uint32_t>(rows, 1, std::max<std::uint32_t>(1, area.height() / minSize));
  tiles.reserve(static_cast<std::size_t>(columns) * rows);
  for (std::uint32_t row = 0; row < rows; ++row) {
    const std::uint32_t y0 = area.y() + area.height() * row / rows;
    const std::uint32_t y1 = area.y() + area.height() * (row + 1) / rows;
    for (std::uint32_t column = 0; column < columns; ++column) {
      const std::uint32_t x0 = area.x() + area.width() * column / columns;
      const std::uint32_t x1 = area.x() + area.width() * (column + 1) / columns;
      tiles.push_back(makeTileRect(x0, y0, x1 - x0, y1 - y0));
    }
  }
  return tiles;
}

}  // namespace pointillist::display
