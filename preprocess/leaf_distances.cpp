#include "preprocess/leaf_distances.hpp"

#include <algorithm>
#include <limits>
#include <stdexcept>
#include <string>

#include "preprocess/selection.hpp"

// Highway compiles the SIMD part once per target by including this file again.
#undef HWY_TARGET_INCLUDE
#define HWY_TARGET_INCLUDE "preprocess/leaf_distances.cpp"
#include <hwy/foreach_target.h>  // IWYU pragma: keep
// foreach_target.h must come first.
#include <hwy/highway.h>

HWY_BEFORE_NAMESPACE();
namespace pointillist::preprocess {
namespace HWY_NAMESPACE {
namespace hn = hwy::HWY_NAMESPACE;

// padded: a multiple of the lane count, the columns +inf beyond n. Returns
// the index of a distance of rank k; n when none has it (cannot happen for
// k < n; the caller checks); kNotRanked when n is more than 8 vectors, where
// ranking (n^2 / lanes) would cost more than selecting by partitions.
std::size_t KthSmallestDistanceIndex(const float* x, const float* y, const float* z, std::size_t n,
                                     std::size_t padded, const float* p, std::size_t k,
                                     float* distances) {
  const hn::ScalableTag<float> d;
  const hn::RebindToSigned<decltype(d)> di;
  const std::size_t lanes = hn::Lanes(d);
  const auto px = hn::Set(d, p[0]), py = hn::Set(d, p[1]), pz = hn::Set(d, p[2]);
  for (std::size_t i = 0; i < padded; i += lanes) {
    const auto dx = hn::Sub(hn::LoadU(d, x + i), px);
    const auto dy = hn::Sub(hn::LoadU(d, y + i), py);
    const auto dz = hn::Sub(hn::LoadU(d, z + i), pz);
    hn::StoreU(hn::Add(hn::Add(hn::Mul(dx, dx), hn::Mul(dy, dy)), hn::Mul(dz, dz)), d,
               distances + i);
  }
  if (n > 8 * lanes) return detail::kNotRanked;
  // A candidate has rank k when fewer than k + 1 values lie below it and
  // more than k lie at or below it. Padding (+inf) lanes come after every real one.
  const auto rank = hn::Set(di, static_cast<std::int32_t>(k));
  for (std::size_t c = 0; c < padded; c += lanes) {
    const auto candidates = hn::LoadU(d, distances + c);
    auto below = hn::Zero(di), atOrBelow = hn::Zero(di);
    for (std::size_t j = 0; j < n; ++j) {
      const auto v = hn::Set(d, distances[j]);
      below = hn::Sub(below, hn::VecFromMask(di, hn::RebindMask(di, hn::Lt(v, candidates))));
      atOrBelow =
          hn::Sub(atOrBelow, hn::VecFromMask(di, hn::RebindMask(di, hn::Le(v, candidates))));
    }
    const auto hit = hn::AndNot(hn::Lt(rank, below), hn::Lt(rank, atOrBelow));
    const std::intptr_t lane = hn::FindFirstTrue(di, hit);
    if (lane >= 0) return std::min(n, c + static_cast<std::size_t>(lane));
  }
  return n;
}

// NOLINTNEXTLINE(google-readability-namespace-comments)
}  // namespace HWY_NAMESPACE
}  // namespace pointillist::preprocess
HWY_AFTER_NAMESPACE();

#if HWY_ONCE
namespace pointillist::preprocess {

HWY_EXPORT(KthSmallestDistanceIndex);

void LeafColumns::assign(std::span<const Splat> points) {
  size_ = points.size();
  // Whole vectors of any target: HWY_MAX_BYTES here is only the last target compiled's.
  constexpr std::size_t kLanes = 256 / sizeof(float);
  padded_ = (size_ + kLanes - 1) / kLanes * kLanes;
  const float inf = std::numeric_limits<float>::infinity();
  x_.assign(padded_, inf);
  y_.assign(padded_, inf);
  z_.assign(padded_, inf);
  distances_.resize(padded_);
  values_.resize(size_);
  for (std::size_t i = 0; i < size_; ++i) {
    x_[i] = points[i].position[0];
    y_[i] = points[i].position[1];
    z_[i] = points[i].position[2];
  }
}

float LeafColumns::kthSmallestSquaredDistance(const float p[3], std::size_t k) const {
  if (k >= size_ || size_ > kMaxPoints)
    throw std::invalid_argument("kthSmallestSquaredDistance: rank " + std::to_string(k) + " of " +
                                std::to_string(size_) + " points");
  const std::size_t at = HWY_DYNAMIC_DISPATCH(KthSmallestDistanceIndex)(
      x_.data(), y_.data(), z_.data(), size_, padded_, p, k, distances_.data());
  if (at == detail::kNotRanked) {
    std::copy_n(distances_.begin(), size_, values_.begin());
    return kthSmallest(values_.data(), distances_.data(), size_, k);
  }
  // Every rank below size_ has a value: finite positions give no NaN (an
  // overflow gives +inf, which ranks like any other value).
  if (at >= size_)
    throw std::logic_error("kthSmallestSquaredDistance: no distance of rank " + std::to_string(k) +
                           " among " + std::to_string(size_));
  return distances_[at];
}

}  // namespace pointillist::preprocess
#endif  // HWY_ONCE
