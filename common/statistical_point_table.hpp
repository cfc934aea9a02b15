#pragma once
// How many points a statistical node generates (seed 004 §6.2, Table 1): an
// empirical table, measured on llvmpipe by `pointillist-statistical-table`,
// of the fewest samples of the quasi-random sequence that cover the screen
// projection of a node's gamma ellipsoid, indexed by that projection's
// semi-axes in pixels. Beyond the paper, which estimates the size from the
// z distance only, the projection here is the node's covariance projected to
// the screen (a Gaussian projects to a Gaussian), so a node seen edge-on
// generates fewer points than one seen face-on.
#include <cstdint>

#include <glm/glm.hpp>

#include "common/camera.hpp"
#include "common/statistical_node.hpp"

namespace pointillist {

// Generated points are drawn this many pixels wide (the table is measured so).
inline constexpr float kStatisticalPointPixels = 2.0f;
// The render's static sample buffer: no node draws more samples than this.
inline constexpr std::uint32_t kStatisticalMaxSamples = 4096;
// The widest point the budget gives (culling grows node spheres by half of it):
// a node nearer than that leaves holes between its points.
inline constexpr float kStatisticalMaxPointPixels = 16.0f;
// The measured table covers semi-axes 1..kStatisticalTableSize pixels (at 7
// and 8 pixels full coverage of the gamma ellipse already needs 5740 to 14148
// samples: the Gaussian's rim is thin, so beyond the table the points widen).
inline constexpr std::uint32_t kStatisticalTableSize = 6;

// The screen ellipse of a node's gamma ellipsoid (kStatisticalGamma * sigma),
// semi-axes in full-frame pixels, major >= minor >= 0, from the covariance
// projected through the perspective at the node's mean (the Jacobian of the
// projection there). Zero when the mean is behind the eye.
struct NodeFootprint {
  float major = 0.0f;
  float minor = 0.0f;
};
NodeFootprint nodeFootprint(const StatisticalNode& node, const Camera& camera);
// nodeFootprint for many nodes of one camera (the camera's frame taken once);
// the same values.
class FootprintProjector {
 public:
  explicit FootprintProjector(const Camera& camera);
  NodeFootprint operator()(const StatisticalNode& node) const;

 private:
  glm::vec3 eye_, forward_, right_, up_;
  float focal_;  // pixels
};

struct PointBudget {
  std::uint32_t count = 1;                      // samples 0..count-1 of the sequence
  float pointPixels = kStatisticalPointPixels;  // point width: larger only when count is capped
};
// The table's entry for the footprint (semi-axes rounded up to whole pixels,
// at least 1); beyond the table (a semi-axis above kStatisticalTableSize) the
// entry at the clamped semi-axes times the ratio of the areas,
// ceil(entry * (a / a') * (b / b')); above kStatisticalMaxSamples the count is
// capped and the points widened to ceil(kStatisticalPointPixels *
// sqrt(wanted / cap)) pixels, so the same area is covered. Monotone in both
// semi-axes.
PointBudget statisticalPointBudget(const NodeFootprint& footprint);
// The measured table's entry for semi-axes (a, b) in whole pixels, each
// clamped to [1, kStatisticalTableSize] (order does not matter).
std::uint32_t statisticalTableEntry(std::uint32_t a, std::uint32_t b);
// The ellipse a node's points must cover: half its gamma footprint. Seed
// 004's Table 1 sizes an ellipsoid by gamma * sigma across (its (4, 4, 4)
// needs 54 quasi-random points, not the thousands that covering all of the
// 3.5-sigma ellipse, where samples are rare, would take); the overlapping
// tails of neighbouring nodes fill the rest.
inline NodeFootprint coverageEllipse(const NodeFootprint& footprint) {
  return {0.5f * footprint.major, 0.5f * footprint.minor};
}
inline PointBudget nodePointBudget(const StatisticalNode& node, const Camera& camera) {
  return statisticalPointBudget(coverageEllipse(nodeFootprint(node, camera)));
}
inline PointBudget nodePointBudget(const StatisticalNode& node, const FootprintProjector& project) {
  return statisticalPointBudget(coverageEllipse(project(node)));
}

}  // namespace pointillist
