#include "preprocess/likeliest_gaussian.hpp"

#include <algorithm>
#include <limits>
#include <stdexcept>
#include <string>

// Highway compiles the SIMD part once per target by including this file again.
#undef HWY_TARGET_INCLUDE
#define HWY_TARGET_INCLUDE "preprocess/likeliest_gaussian.cpp"
#include <hwy/foreach_target.h>  // IWYU pragma: keep
// foreach_target.h must come first.
#include <hwy/highway.h>

HWY_BEFORE_NAMESPACE();
namespace pointillist::preprocess {
namespace HWY_NAMESPACE {
namespace hn = hwy::HWY_NAMESPACE;

// n a multiple of the lane count (the caller pads). best: the cluster index
// as a double, in and out.
void LikeliestColumns(const double* x, const double* y, const double* z, std::size_t n,
                      const GaussianRecord* gaussians, std::size_t k, double* best) {
  const hn::ScalableTag<double> d;
  const std::size_t lanes = hn::Lanes(d);
  const auto two = hn::Set(d, 2.0);
  for (std::size_t i = 0; i < n; i += lanes) {
    const auto px = hn::LoadU(d, x + i), py = hn::LoadU(d, y + i), pz = hn::LoadU(d, z + i);
    auto lowest = hn::Set(d, std::numeric_limits<double>::infinity());
    auto index = hn::LoadU(d, best + i);
    for (std::size_t c = 0; c < k; ++c) {
      const GaussianRecord& g = gaussians[c];
      const auto dx = hn::Sub(px, hn::Set(d, g.mean[0]));
      const auto dy = hn::Sub(py, hn::Set(d, g.mean[1]));
      const auto dz = hn::Sub(pz, hn::Set(d, g.mean[2]));
      const auto diagonal = hn::Add(hn::Add(hn::Mul(hn::Mul(hn::Set(d, g.inverse[0]), dx), dx),
                                            hn::Mul(hn::Mul(hn::Set(d, g.inverse[3]), dy), dy)),
                                    hn::Mul(hn::Mul(hn::Set(d, g.inverse[5]), dz), dz));
      const auto offDiagonal = hn::Add(hn::Add(hn::Mul(hn::Mul(hn::Set(d, g.inverse[1]), dx), dy),
                                               hn::Mul(hn::Mul(hn::Set(d, g.inverse[2]), dx), dz)),
                                       hn::Mul(hn::Mul(hn::Set(d, g.inverse[4]), dy), dz));
      const auto cost = hn::Add(hn::Add(diagonal, hn::Mul(two, offDiagonal)), hn::Set(d, g.logDet));
      // Clusters in index order and a strict test: ties keep the lower index.
      const auto lower = hn::Lt(cost, lowest);
      lowest = hn::IfThenElse(lower, cost, lowest);
      index = hn::IfThenElse(lower, hn::Set(d, static_cast<double>(c)), index);
    }
    hn::StoreU(index, d, best + i);
  }
}

}  // namespace HWY_NAMESPACE
}  // namespace pointillist::preprocess
HWY_AFTER_NAMESPACE();

#if HWY_ONCE
namespace pointillist::preprocess {

HWY_EXPORT(LikeliestColumns);

double gaussianCost(const GaussianRecord& g, double x, double y, double z) {
  const double dx = x - g.mean[0], dy = y - g.mean[1], dz = z - g.mean[2];
  const double* m = g.inverse;
  return m[0] * dx * dx + m[3] * dy * dy + m[5] * dz * dz +
         2.0 * (m[1] * dx * dy + m[2] * dx * dz + m[4] * dy * dz) + g.logDet;
}

bool assignLikeliestGaussians(std::span<const std::array<double, 3>> positions,
                              std::span<const GaussianRecord> gaussians,
                              std::span<std::uint32_t> assignment) {
  // Blocks of a fixed size through columns on the stack, the tail padded to a
  // whole vector.
  constexpr std::size_t kBlock = 256;  // a multiple of every target's lanes
  alignas(64) double x[kBlock], y[kBlock], z[kBlock], best[kBlock];
  if (assignment.size() != positions.size()) {
    throw std::invalid_argument("assignLikeliestGaussians: " + std::to_string(positions.size()) +
                                " positions but " + std::to_string(assignment.size()) +
                                " assignments");
  }
  const std::size_t n = positions.size();
  bool changed = false;
  for (std::size_t begin = 0; begin < n; begin += kBlock) {
    const std::size_t count = std::min(kBlock, n - begin);
    const std::size_t padded = std::min(kBlock, count + HWY_MAX_BYTES / sizeof(double));
    for (std::size_t i = 0; i < padded; ++i) {
      const bool real = i < count;
      x[i] = real ? positions[begin + i][0] : 0.0;
      y[i] = real ? positions[begin + i][1] : 0.0;
      z[i] = real ? positions[begin + i][2] : 0.0;
      best[i] = real ? static_cast<double>(assignment[begin + i]) : 0.0;
    }
    HWY_DYNAMIC_DISPATCH(LikeliestColumns)
    (x, y, z, count, gaussians.data(), gaussians.size(), best);
    for (std::size_t i = 0; i < count; ++i) {
      const auto chosen = static_cast<std::uint32_t>(best[i]);
      changed = changed || chosen != assignment[begin + i];
      assignment[begin + i] = chosen;
    }
  }
  return changed;
}

}  // namespace pointillist::preprocess
#endif  // HWY_ONCE
