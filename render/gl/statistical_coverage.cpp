#include "render/gl/statistical_coverage.hpp"

#include <cmath>

#include "common/statistical_point_table.hpp"

namespace pointillist::render {

namespace {

constexpr float kDistance = 1000.0f;
constexpr float kFovY = 20.0f;

bool inside(std::uint32_t x, std::uint32_t y, float cx, float cy, float a, float b) {
  const float dx = (static_cast<float>(x) + 0.5f - cx) / a;
  const float dy = (static_cast<float>(y) + 0.5f - cy) / b;
  return dx * dx + dy * dy <= 1.0f;
}

}  // namespace

EllipseCoverage::EllipseCoverage(SplatRenderer& renderer, std::uint32_t maxSemiAxis)
    : renderer_(renderer) {
  const std::uint32_t side = 2 * (maxSemiAxis + 8);
  camera_ = makeCamera({0.0f, 0.0f, kDistance}, {0.0f, 0.0f, 0.0f}, {0.0f, 1.0f, 0.0f}, kFovY,
                       0.5f * kDistance, 2.0f * kDistance, side, side);
  unitsPerPixel_ = 1.0f / pixelsPerUnit(camera_, kDistance);
}

StatisticalNode EllipseCoverage::node(float a, float b, float offsetX, float offsetY) const {
  StatisticalNode node{};
  node.mean[0] = offsetX * unitsPerPixel_;
  node.mean[1] = offsetY * unitsPerPixel_;
  for (int k = 0; k < 3; ++k)
    node.axes[k][k] = node.normalFrame[k][k] = node.colorAxes[k][k] = 1.0f;
  // Seed 004's Table 1 sizes a node by gamma * sigma *across*: the ellipse
  // to cover is half the node's gamma ellipse (coverageEllipse).
  node.sigma[0] = 2.0f * a * unitsPerPixel_ / kStatisticalGamma;
  node.sigma[1] = 2.0f * b * unitsPerPixel_ / kStatisticalGamma;
  node.sigma[2] = 1e-3f * node.sigma[1];  // f3 along the view: no screen extent
  for (float& c : node.color) c = 255.0f;
  return node;
}

std::uint32_t EllipseCoverage::insidePixels(float a, float b, float offsetX, float offsetY) const {
  const float cx = 0.5f * static_cast<float>(camera_.image_width()) + offsetX;
  const float cy = 0.5f * static_cast<float>(camera_.image_height()) + offsetY;
  std::uint32_t count = 0;
  for (std::uint32_t y = 0; y < camera_.image_height(); ++y)
    for (std::uint32_t x = 0; x < camera_.image_width(); ++x) count += inside(x, y, cx, cy, a, b);
  return count;
}

bool EllipseCoverage::lastFrameCovers(float a, float b, float offsetX, float offsetY) const {
  const std::span<const std::uint8_t> pixels = renderer_.pixels();
  const std::uint32_t width = camera_.image_width();
  const float cx = 0.5f * static_cast<float>(width) + offsetX;
  const float cy = 0.5f * static_cast<float>(camera_.image_height()) + offsetY;
  for (std::uint32_t y = 0; y < camera_.image_height(); ++y) {
    for (std::uint32_t x = 0; x < width; ++x) {
      if (inside(x, y, cx, cy, a, b) && pixels[(std::size_t{y} * width + x) * 4] == 0) return false;
    }
  }
  return true;
}

bool EllipseCoverage::covered(float a, float b, float offsetX, float offsetY, std::uint32_t n) {
  const StatisticalNode ellipse = node(a, b, offsetX, offsetY);
  const PointBudget budget{n, kStatisticalPointPixels};
  RenderSettings settings;
  settings.mode = SplatMode::Statistical;
  settings.lighting = false;
  settings.clearColor = {0.0f, 0.0f, 0.0f, 1.0f};
  renderer_.renderNodes(camera_, fullFrameRect(camera_), {&ellipse, 1}, settings, {&budget, 1});
  return lastFrameCovers(a, b, offsetX, offsetY);
}

std::uint32_t EllipseCoverage::fewest(float a, float b, float offsetX, float offsetY,
                                      std::uint32_t limit) {
  if (!covered(a, b, offsetX, offsetY, limit)) return limit + 1;
  std::uint32_t low = 0, high = limit;  // low does not cover, high does
  while (high - low > 1) {
    const std::uint32_t mid = low + (high - low) / 2;
    (covered(a, b, offsetX, offsetY, mid) ? high : low) = mid;
  }
  return high;
}

}  // namespace pointillist::render
