#include "preprocess/eigen_batch.hpp"

#include <algorithm>
#include <cstdint>
#include <limits>
#include <stdexcept>

// Highway compiles the SIMD part once per target by including this file again.
#undef HWY_TARGET_INCLUDE
#define HWY_TARGET_INCLUDE "preprocess/eigen_batch.cpp"
#include <hwy/foreach_target.h>  // IWYU pragma: keep
// foreach_target.h must come first.
#include <hwy/highway.h>

#ifndef POINTILLIST_EIGEN_BATCH_ONCE
#define POINTILLIST_EIGEN_BATCH_ONCE
namespace pointillist::preprocess {
namespace {
// Matrices per pass, as columns: a multiple of every target's lane count.
constexpr std::size_t kBlock = 64;
}  // namespace
}  // namespace pointillist::preprocess
#endif

HWY_BEFORE_NAMESPACE();
namespace pointillist::preprocess {
namespace HWY_NAMESPACE {
namespace hn = hwy::HWY_NAMESPACE;

// Columns in: the six entries of n matrices, padded to a whole vector. Columns out:
// lo, mid, hi, the vector, and whether the scalar function would take Jacobi
// instead. Every step is smallestEigen3's, in its order.
void SmallestEigenColumns(const double* const* m, std::size_t n, double* const* out,
                          std::uint8_t* fallback) {
  const hn::ScalableTag<double> d;
  const std::size_t lanes = hn::Lanes(d);
  const auto zero = hn::Zero(d);
  const auto one = hn::Set(d, 1.0);
  const auto two = hn::Set(d, 2.0);
  const auto three = hn::Set(d, 3.0);
  const auto half = hn::Set(d, 0.5);
  const auto infinity = hn::Set(d, std::numeric_limits<double>::infinity());
  for (std::size_t i = 0; i < n; i += lanes) {
    const auto m0 = hn::LoadU(d, m[0] + i), m1 = hn::LoadU(d, m[1] + i);
    const auto m2 = hn::LoadU(d, m[2] + i), m3 = hn::LoadU(d, m[3] + i);
    const auto m4 = hn::LoadU(d, m[4] + i), m5 = hn::LoadU(d, m[5] + i);
    const auto q = hn::Div(hn::Add(hn::Add(m0, m3), m5), three);
    const auto d0 = hn::Sub(m0, q), d3 = hn::Sub(m3, q), d5 = hn::Sub(m5, q);
    const auto p1 = hn::Add(hn::Add(hn::Mul(m1, m1), hn::Mul(m2, m2)), hn::Mul(m4, m4));
    const auto p2 = hn::Add(hn::Add(hn::Add(hn::Mul(d0, d0), hn::Mul(d3, d3)), hn::Mul(d5, d5)),
                            hn::Mul(two, p1));
    const auto p = hn::Sqrt(hn::Div(p2, hn::Set(d, 6.0)));
    const auto usable = hn::And(hn::Gt(p, zero), hn::Lt(p, infinity));
    const auto ip = hn::Div(one, p);
    const auto b0 = hn::Mul(d0, ip), b1 = hn::Mul(m1, ip), b2 = hn::Mul(m2, ip);
    const auto b3 = hn::Mul(d3, ip), b4 = hn::Mul(m4, ip), b5 = hn::Mul(d5, ip);
    const auto det = hn::Add(hn::Sub(hn::Mul(b0, hn::Sub(hn::Mul(b3, b5), hn::Mul(b4, b4))),
                                     hn::Mul(b1, hn::Sub(hn::Mul(b1, b5), hn::Mul(b4, b2)))),
                             hn::Mul(b2, hn::Sub(hn::Mul(b1, b4), hn::Mul(b3, b2))));
    // std::clamp(x, -1, 1): (x < -1) ? -1 : (1 < x) ? 1 : x, NaN kept.
    const auto halfDet = hn::Mul(half, det);
    const auto r = hn::IfThenElse(hn::Lt(halfDet, hn::Neg(one)), hn::Neg(one),
                                  hn::IfThenElse(hn::Lt(one, halfDet), one, halfDet));
    const auto u = hn::Sqrt(hn::Sub(one, r));
    // smallestRootScale(u).
    const auto t = hn::Mul(u, hn::Set(d, 0.70710678118654752440));
    auto g = hn::Add(hn::Set(d, 0.81649658092772603),
                     hn::Mul(t, hn::Add(hn::Set(d, -0.14664724674687624),
                                        hn::Mul(t, hn::Set(d, 0.037257447005697664)))));
    for (int step = 0; step < 3; ++step) {
      const auto g2 = hn::Mul(g, g);
      const auto f = hn::Sub(hn::Add(hn::Mul(three, g2), hn::Mul(hn::Mul(u, g2), g)), two);
      const auto slope = hn::Add(hn::Mul(hn::Set(d, 6.0), g), hn::Mul(hn::Mul(three, u), g2));
      g = hn::Sub(g, hn::Div(f, slope));
    }
    const auto betaLo = hn::Sub(hn::Neg(one), hn::Mul(u, g));
    const auto rest = hn::Sub(hn::Set(d, 12.0), hn::Mul(hn::Mul(three, betaLo), betaLo));
    const auto disc = hn::IfThenElse(hn::Lt(zero, rest), rest, zero);  // std::max(0, rest)
    const auto lo = hn::Add(q, hn::Mul(p, betaLo));
    const auto hi = hn::Add(q, hn::Mul(p, hn::Mul(half, hn::Sub(hn::Sqrt(disc), betaLo))));
    const auto mid = hn::Sub(hn::Sub(hn::Mul(three, q), hi), lo);
    const auto repeated = hn::Lt(hn::Sub(mid, lo), hn::Mul(hn::Set(d, 1e-6), hn::Sub(hi, lo)));
    const auto a0 = hn::Sub(m0, lo), a3 = hn::Sub(m3, lo), a5 = hn::Sub(m5, lo);
    // Rows (a0, m1, m2), (m1, a3, m4), (m2, m4, a5); cross(a, b) =
    // (a1 b2 - a2 b1, a2 b0 - a0 b2, a0 b1 - a1 b0).
    auto x = hn::Sub(hn::Mul(m1, m4), hn::Mul(m2, a3));
    auto y = hn::Sub(hn::Mul(m2, m1), hn::Mul(a0, m4));
    auto z = hn::Sub(hn::Mul(a0, a3), hn::Mul(m1, m1));
    auto best = hn::Add(hn::Add(hn::Mul(x, x), hn::Mul(y, y)), hn::Mul(z, z));
    const auto take = [&](decltype(x) cx, decltype(x) cy, decltype(x) cz) {
      const auto squared = hn::Add(hn::Add(hn::Mul(cx, cx), hn::Mul(cy, cy)), hn::Mul(cz, cz));
      const auto longer = hn::Gt(squared, best);
      x = hn::IfThenElse(longer, cx, x);
      y = hn::IfThenElse(longer, cy, y);
      z = hn::IfThenElse(longer, cz, z);
      best = hn::IfThenElse(longer, squared, best);
    };
    take(hn::Sub(hn::Mul(m1, a5), hn::Mul(m2, m4)), hn::Sub(hn::Mul(m2, m2), hn::Mul(a0, a5)),
         hn::Sub(hn::Mul(a0, m4), hn::Mul(m1, m2)));
    take(hn::Sub(hn::Mul(a3, a5), hn::Mul(m4, m4)), hn::Sub(hn::Mul(m4, m2), hn::Mul(m1, a5)),
         hn::Sub(hn::Mul(m1, m4), hn::Mul(a3, m2)));
    const auto length = hn::Sqrt(best);
    const auto degenerate = hn::Not(hn::Gt(length, hn::Set(d, 1e-300)));
    const auto inverse = hn::Div(one, length);
    hn::StoreU(lo, d, out[0] + i);
    hn::StoreU(mid, d, out[1] + i);
    hn::StoreU(hi, d, out[2] + i);
    hn::StoreU(hn::Mul(x, inverse), d, out[3] + i);
    hn::StoreU(hn::Mul(y, inverse), d, out[4] + i);
    hn::StoreU(hn::Mul(z, inverse), d, out[5] + i);
    const auto jacobi = hn::Or(hn::Not(usable), hn::Or(repeated, degenerate));
    const hn::RebindToSigned<decltype(d)> di;
    alignas(64) std::int64_t flags[HWY_MAX_BYTES / sizeof(double)];
    hn::Store(hn::VecFromMask(di, hn::RebindMask(di, jacobi)), di, flags);
    for (std::size_t lane = 0; lane < lanes; ++lane) {
      fallback[i + lane] = flags[lane] != 0;
    }
  }
}

}  // namespace HWY_NAMESPACE
}  // namespace pointillist::preprocess
HWY_AFTER_NAMESPACE();

#if HWY_ONCE
namespace pointillist::preprocess {

HWY_EXPORT(SmallestEigenColumns);

void smallestEigen3Batch(std::span<const Sym3> matrices, std::span<SmallestEigen3> out) {
  if (out.size() < matrices.size()) {
    throw std::invalid_argument("smallestEigen3Batch: fewer outputs than matrices");
  }
  alignas(64) double columns[6][kBlock];
  alignas(64) double results[6][kBlock];
  std::uint8_t fallback[kBlock];
  const double* in[6] = {columns[0], columns[1], columns[2], columns[3], columns[4], columns[5]};
  double* const resultColumns[6] = {results[0], results[1], results[2],
                                    results[3], results[4], results[5]};
  for (std::size_t begin = 0; begin < matrices.size(); begin += kBlock) {
    const std::size_t n = std::min(kBlock, matrices.size() - begin);
    // Past n up to a whole vector: a plain matrix, so unused lanes compute
    // nothing odd.
    for (std::size_t i = 0; i < std::min(kBlock, n + HWY_MAX_BYTES / sizeof(double)); ++i) {
      const Sym3& m = i < n ? matrices[begin + i] : Sym3{3.0, 0.0, 0.0, 2.0, 0.0, 1.0};
      for (std::size_t e = 0; e < 6; ++e) columns[e][i] = m[e];
    }
    HWY_DYNAMIC_DISPATCH(SmallestEigenColumns)(in, n, resultColumns, fallback);
    for (std::size_t i = 0; i < n; ++i) {
      SmallestEigen3& e = out[begin + i];
      if (fallback[i]) {
        e = smallestEigen3(matrices[begin + i]);  // takes Jacobi, as the scalar call would
        continue;
      }
      e.values = {results[0][i], results[1][i], results[2][i]};
      e.vector = {results[3][i], results[4][i], results[5][i]};
    }
  }
}

}  // namespace pointillist::preprocess
#endif  // HWY_ONCE
