#pragma once
// How many samples cover a node's screen ellipse (seed 004 §6.2, Table 1),
// measured with the real statistical program: the node's gamma ellipse faces a
// far perspective camera (its f3 along the view axis, sigma_3 negligible) and
// projects to semi-axes (a, b) pixels along x and y, its centre `offset`
// pixels off the frame's central pixel corner. A pixel is inside when its
// centre lies in the ellipse; the ellipse is covered when every pixel inside
// is drawn. Samples are a prefix of the sequence, so coverage only grows with
// n and the fewest n is found by bisection. pointillist-statistical-table
// builds common/statistical_point_table.cpp's table with it; the tests
// re-measure entries.
#include <array>
#include <cstdint>

#include "common/camera.hpp"
#include "common/statistical_node.hpp"
#include "render/gl/splat_renderer.hpp"

namespace pointillist::render {

// Sub-pixel offsets of the ellipse's centre the table takes the worst of.
inline constexpr std::array<std::array<float, 2>, 4> kCoverageOffsets{
    {{0.0f, 0.0f}, {0.5f, 0.5f}, {0.25f, 0.75f}, {0.8f, 0.35f}}};

class EllipseCoverage {
 public:
  // Semi-axes up to maxSemiAxis pixels fit the frame.
  EllipseCoverage(SplatRenderer& renderer, std::uint32_t maxSemiAxis);

  const Camera& camera() const { return camera_; }
  // The node whose coverage ellipse (half its gamma ellipse, common/
  // statistical_point_table.hpp) projects to (a, b) pixels at the offset.
  StatisticalNode node(float a, float b, float offsetX, float offsetY) const;
  // Pixels inside the ellipse (a, b) at the offset.
  std::uint32_t insidePixels(float a, float b, float offsetX, float offsetY) const;
  // Whether n samples kStatisticalPointPixels wide (the renderer's current
  // sample buffer) cover the ellipse.
  bool covered(float a, float b, float offsetX, float offsetY, std::uint32_t n);
  // The fewest n in [1, limit] that covers it; limit + 1 when none does.
  std::uint32_t fewest(float a, float b, float offsetX, float offsetY, std::uint32_t limit);
  // Whether the last drawn frame covers the ellipse.
  bool lastFrameCovers(float a, float b, float offsetX, float offsetY) const;

 private:
  SplatRenderer& renderer_;
  Camera camera_;
  float unitsPerPixel_ = 1.0f;  // world size of a pixel at the node
};

}  // namespace pointillist::render
