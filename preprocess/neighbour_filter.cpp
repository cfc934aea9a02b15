#include "preprocess/neighbour_filter.hpp"

#include <algorithm>
#include <limits>

// Highway compiles the SIMD part once per target by including this file again.
#undef HWY_TARGET_INCLUDE
#define HWY_TARGET_INCLUDE "preprocess/neighbour_filter.cpp"
#include <hwy/foreach_target.h>  // IWYU pragma: keep
// foreach_target.h must come first.
#include <hwy/highway.h>

HWY_BEFORE_NAMESPACE();
namespace pointillist::preprocess {
namespace HWY_NAMESPACE {
namespace hn = hwy::HWY_NAMESPACE;

std::size_t CandidatesWithin(const float* x, const float* y, const float* z,
                             const std::uint32_t* id, std::size_t n, const float* p, float bound,
                             float* distance2, std::uint32_t* idOut) {
  const hn::ScalableTag<float> df;
  const hn::RebindToUnsigned<decltype(df)> du;
  const std::size_t lanes = hn::Lanes(df);
  const auto px = hn::Set(df, p[0]), py = hn::Set(df, p[1]), pz = hn::Set(df, p[2]);
  const auto limit = hn::Set(df, bound);
  std::size_t kept = 0;
  // Compressed in registers, then stored whole: the store lands within the
  // outputs (kept <= i), and the memory form of the compress is slow on some
  // processors (AMD Zen 4). The last, partial vector goes through a buffer.
  const auto filter = [&](const float* xs, const float* ys, const float* zs,
                          const std::uint32_t* ids, float* dOut, std::uint32_t* idsOut) {
    const auto dx = hn::Sub(hn::LoadU(df, xs), px);
    const auto dy = hn::Sub(hn::LoadU(df, ys), py);
    const auto dz = hn::Sub(hn::LoadU(df, zs), pz);
    const auto d = hn::Add(hn::Add(hn::Mul(dx, dx), hn::Mul(dy, dy)), hn::Mul(dz, dz));
    const auto within = hn::Le(d, limit);  // false for NaN
    hn::StoreU(hn::Compress(d, within), df, dOut);
    hn::StoreU(hn::Compress(hn::LoadU(du, ids), hn::RebindMask(du, within)), du, idsOut);
    return hn::CountTrue(df, within);
  };
  std::size_t i = 0;
  for (; i + lanes <= n; i += lanes)
    kept += filter(x + i, y + i, z + i, id + i, distance2 + kept, idOut + kept);
  if (i < n) {
    // The tail through a vector of NaN positions, which pass no bound.
    constexpr std::size_t kMaxLanes = HWY_MAX_BYTES / sizeof(float);
    HWY_ALIGN float tx[kMaxLanes], ty[kMaxLanes], tz[kMaxLanes], td[kMaxLanes];
    HWY_ALIGN std::uint32_t tid[kMaxLanes] = {}, tidOut[kMaxLanes];
    for (std::size_t j = 0; j < lanes; ++j) {
      const bool real = i + j < n;
      tx[j] = real ? x[i + j] : std::numeric_limits<float>::quiet_NaN();
      ty[j] = real ? y[i + j] : tx[j];
      tz[j] = real ? z[i + j] : tx[j];
      tid[j] = real ? id[i + j] : 0;
    }
    const std::size_t tail = filter(tx, ty, tz, tid, td, tidOut);
    std::copy_n(td, tail, distance2 + kept);
    std::copy_n(tidOut, tail, idOut + kept);
    kept += tail;
  }
  return kept;
}

void SortDistinctKeys(std::uint64_t* keys, std::size_t n, std::uint64_t* sorted) {
  const hn::ScalableTag<std::uint64_t> d;
  const std::size_t lanes = hn::Lanes(d);
  // The last vector is filled up with the largest key, which is below none.
  const std::size_t padded = (n + lanes - 1) / lanes * lanes;
  for (std::size_t j = n; j < padded; ++j) keys[j] = ~std::uint64_t{0};
  for (std::size_t i = 0; i < n; ++i) {
    const auto key = hn::Set(d, keys[i]);
    std::size_t below = 0;
    for (std::size_t j = 0; j < padded; j += lanes)
      below += hn::CountTrue(d, hn::Lt(hn::LoadU(d, keys + j), key));
    sorted[below] = keys[i];
  }
}

}  // namespace HWY_NAMESPACE
}  // namespace pointillist::preprocess
HWY_AFTER_NAMESPACE();

#if HWY_ONCE
namespace pointillist::preprocess {

HWY_EXPORT(CandidatesWithin);

std::size_t candidatesWithin(const float* x, const float* y, const float* z,
                             const std::uint32_t* id, std::size_t n, const float p[3], float bound,
                             float* distance2, std::uint32_t* idOut) {
  return HWY_DYNAMIC_DISPATCH(CandidatesWithin)(x, y, z, id, n, p, bound, distance2, idOut);
}

HWY_EXPORT(SortDistinctKeys);

void sortDistinctKeys(std::uint64_t* keys, std::size_t n, std::uint64_t* sorted) {
  static_assert(HWY_MAX_BYTES / sizeof(std::uint64_t) <= kSortKeysPad + 1);
  HWY_DYNAMIC_DISPATCH(SortDistinctKeys)(keys, n, sorted);
}

}  // namespace pointillist::preprocess
#endif
