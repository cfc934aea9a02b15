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

// The index of a value of rank k among values[0, n), padded with +inf to
// `padded` (a multiple of the lane count); n when none has it (cannot happen
// for k < n). A candidate has rank k when fewer than k + 1 values lie below
// it and more than k lie at or below it; padding comes after every real one.
template <class D>
std::size_t RankedIndex(D d, const float* values, std::size_t n, std::size_t padded,
                        std::size_t k) {
  const hn::RebindToSigned<D> di;
  const std::size_t lanes = hn::Lanes(d);
  const auto rank = hn::Set(di, static_cast<std::int32_t>(k));
  for (std::size_t c = 0; c < padded; c += lanes) {
    const auto candidates = hn::LoadU(d, values + c);
    auto below = hn::Zero(di), atOrBelow = hn::Zero(di);
    for (std::size_t j = 0; j < n; ++j) {
      const auto v = hn::Set(d, values[j]);
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

// padded: a multiple of the lane count, the columns +inf beyond n. Sets
// *value to the distance of rank k and returns kRanked; returns
// kLeftToSelection when n is more than 8 vectors and not more than k nor more
// than 8 vectors' worth lie within `bound`, where ranking (n^2 / lanes) would
// cost more than selecting by partitions (the distances are then in
// `distances`). When more than k distances are at most `bound`, only those
// are ranked: the k-th is among them. `within` needs room for padded plus a
// vector.
int KthSmallestDistance(const float* x, const float* y, const float* z, std::size_t n,
                        std::size_t padded, const float* p, std::size_t k, float bound,
                        float* distances, float* within, float* value) {
  const hn::ScalableTag<float> d;
  const std::size_t lanes = hn::Lanes(d);
  const auto px = hn::Set(d, p[0]), py = hn::Set(d, p[1]), pz = hn::Set(d, p[2]);
  const auto limit = hn::Set(d, bound);
  std::size_t kept = 0;
  for (std::size_t i = 0; i < padded; i += lanes) {
    const auto dx = hn::Sub(hn::LoadU(d, x + i), px);
    const auto dy = hn::Sub(hn::LoadU(d, y + i), py);
    const auto dz = hn::Sub(hn::LoadU(d, z + i), pz);
    const auto distance = hn::Add(hn::Add(hn::Mul(dx, dx), hn::Mul(dy, dy)), hn::Mul(dz, dz));
    hn::StoreU(distance, d, distances + i);
    // Padding (+inf) passes only an infinite bound, which the caller never gives.
    const auto in = hn::Le(distance, limit);
    hn::StoreU(hn::Compress(distance, in), d, within + kept);
    kept += hn::CountTrue(d, in);
  }
  const std::size_t most = 8 * lanes;
  if (kept > k && kept <= most) {
    const std::size_t keptPadded = (kept + lanes - 1) / lanes * lanes;
    std::fill(within + kept, within + keptPadded, std::numeric_limits<float>::infinity());
    const std::size_t at = RankedIndex(d, within, kept, keptPadded, k);
    if (at >= kept) return detail::kNoRank;
    *value = within[at];
    return detail::kRanked;
  }
  if (n > most) return detail::kLeftToSelection;
  const std::size_t at = RankedIndex(d, distances, n, padded, k);
  if (at >= n) return detail::kNoRank;
  *value = distances[at];
  return detail::kRanked;
}

// NOLINTNEXTLINE(google-readability-namespace-comments)
}  // namespace HWY_NAMESPACE
}  // namespace pointillist::preprocess
HWY_AFTER_NAMESPACE();

#if HWY_ONCE
namespace pointillist::preprocess {

HWY_EXPORT(KthSmallestDistance);

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
  values_.resize(padded_ + kLanes);
  for (std::size_t i = 0; i < size_; ++i) {
    x_[i] = points[i].position[0];
    y_[i] = points[i].position[1];
    z_[i] = points[i].position[2];
  }
}

float LeafColumns::kthSmallestSquaredDistance(const float p[3], std::size_t k, float bound) const {
  if (k >= size_ || size_ > kMaxPoints)
    throw std::invalid_argument("kthSmallestSquaredDistance: rank " + std::to_string(k) + " of " +
                                std::to_string(size_) + " points");
  // An infinite (or NaN) bound would let the padding through: no bound then.
  if (!(bound < std::numeric_limits<float>::infinity())) bound = -1.0f;
  float value = 0.0f;
  const int status = HWY_DYNAMIC_DISPATCH(KthSmallestDistance)(
      x_.data(), y_.data(), z_.data(), size_, padded_, p, k, bound, distances_.data(),
      values_.data(), &value);
  if (status == detail::kRanked) return value;
  if (status == detail::kLeftToSelection) {
    std::copy_n(distances_.begin(), size_, values_.begin());
    return kthSmallest(values_.data(), distances_.data(), size_, k);
  }
  // Every rank below size_ has a value: finite positions give no NaN (an
  // overflow gives +inf, which ranks like any other value).
  throw std::logic_error("kthSmallestSquaredDistance: no distance of rank " + std::to_string(k) +
                         " among " + std::to_string(size_));
}

}  // namespace pointillist::preprocess
#endif  // HWY_ONCE
