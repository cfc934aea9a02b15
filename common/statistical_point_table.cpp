#include "common/statistical_point_table.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>

namespace pointillist {

namespace {

// kStatisticalQuasiTable[a - 1][b - 1]: the fewest Sobol samples of a node
// whose kStatisticalPointPixels-wide points cover every pixel centre inside
// its coverage ellipse of semi-axes a >= b pixels (coverageEllipse: half its
// gamma ellipse) (the worst of four sub-pixel offsets of
// its centre), measured on llvmpipe (Mesa 22.3.6, LLVM 15) by
// `pointillist-statistical-table --size 6` and made monotone in both axes
// (entries with b > a repeat [a][a]). The raw measurement, with the
// pseudo-random column, is in render/gl/statistical_table.md.
constexpr std::array<std::array<std::uint16_t, kStatisticalTableSize>, kStatisticalTableSize>
    kStatisticalQuasiTable{{
        {3, 3, 3, 3, 3, 3},
        {7, 13, 13, 13, 13, 13},
        {15, 21, 27, 27, 27, 27},
        {21, 21, 37, 66, 66, 66},
        {21, 31, 54, 66, 114, 114},
        {31, 37, 105, 143, 143, 174},
    }};

}  // namespace

std::uint32_t statisticalTableEntry(std::uint32_t a, std::uint32_t b) {
  a = std::clamp<std::uint32_t>(a, 1, kStatisticalTableSize);
  b = std::clamp<std::uint32_t>(b, 1, kStatisticalTableSize);
  if (b > a) std::swap(a, b);
  return kStatisticalQuasiTable[a - 1][b - 1];
}

FootprintProjector::FootprintProjector(const Camera& camera)
    : eye_(cameraEye(camera)), focal_(static_cast<float>(focalLengthPixels(camera))) {
  const glm::vec3 up(camera.up().x(), camera.up().y(), camera.up().z());
  forward_ = glm::normalize(cameraTarget(camera) - eye_);
  right_ = glm::normalize(glm::cross(forward_, up));
  up_ = glm::cross(right_, forward_);
}

NodeFootprint FootprintProjector::operator()(const StatisticalNode& node) const {
  const glm::vec3 toMean = glm::vec3(node.mean[0], node.mean[1], node.mean[2]) - eye_;
  const float depth = glm::dot(toMean, forward_);
  if (!(depth > 0.0f)) return {};
  const float x = glm::dot(toMean, right_) / depth;
  const float y = glm::dot(toMean, up_) / depth;
  const float scale = focal_ / depth;
  // Screen covariance sum_k v_k v_k^T of v_k = J (gamma sigma_k a_k), J the
  // Jacobian of (f x / d, f y / d) at the mean.
  double sxx = 0.0, sxy = 0.0, syy = 0.0;
  for (int k = 0; k < 3; ++k) {
    const glm::vec3 axis = glm::vec3(node.axes[k][0], node.axes[k][1], node.axes[k][2]) *
                           (kStatisticalGamma * node.sigma[k]);
    const float along = glm::dot(axis, forward_);
    const auto u = static_cast<double>(scale * (glm::dot(axis, right_) - x * along));
    const auto v = static_cast<double>(scale * (glm::dot(axis, up_) - y * along));
    sxx += u * u;
    sxy += u * v;
    syy += v * v;
  }
  const double mean = 0.5 * (sxx + syy);
  const double spread = std::sqrt(0.25 * (sxx - syy) * (sxx - syy) + sxy * sxy);
  NodeFootprint out;
  out.major = static_cast<float>(std::sqrt(mean + spread));
  out.minor = static_cast<float>(std::sqrt(std::max(mean - spread, 0.0)));
  return out;
}

NodeFootprint nodeFootprint(const StatisticalNode& node, const Camera& camera) {
  return FootprintProjector(camera)(node);
}

PointBudget statisticalPointBudget(const NodeFootprint& footprint) {
  // Whole pixels, at least 1; NaN counts as 1 (a degenerate node).
  const auto whole = [](float v) {
    return v > 1.0f ? static_cast<double>(std::ceil(std::min(v, 1e6f))) : 1.0;
  };
  const double a = whole(std::max(footprint.major, footprint.minor));
  const double b = whole(std::min(footprint.major, footprint.minor));
  constexpr auto size = static_cast<double>(kStatisticalTableSize);
  const double ta = std::min(a, size), tb = std::min(b, size);
  const double entry =
      statisticalTableEntry(static_cast<std::uint32_t>(ta), static_cast<std::uint32_t>(tb));
  // Beyond the table: the samples grow with the ellipse's area.
  const double wanted = std::ceil(entry * (a / ta) * (b / tb));
  PointBudget budget;
  constexpr auto cap = static_cast<double>(kStatisticalMaxSamples);
  if (wanted <= cap) {
    budget.count = static_cast<std::uint32_t>(wanted);
    return budget;
  }
  // Capped: wider points cover the same area with fewer of them.
  budget.count = kStatisticalMaxSamples;
  budget.pointPixels = static_cast<float>(
      std::min(std::ceil(static_cast<double>(kStatisticalPointPixels) * std::sqrt(wanted / cap)),
               static_cast<double>(kStatisticalMaxPointPixels)));
  return budget;
}

}  // namespace pointillist
