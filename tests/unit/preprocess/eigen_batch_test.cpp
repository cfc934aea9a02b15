#include "preprocess/eigen_batch.hpp"
#include "preprocess/simd_targets.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <random>
#include <vector>

namespace pointillist::preprocess {
namespace {

// Covariances as the preprocess meets them -- flat, round, line-like,
// isotropic, rank-deficient -- over 12 orders of magnitude, and the odd ones:
// zero, diagonal, repeated values, NaN and infinity.
std::vector<Sym3> testMatrices() {
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  std::vector<Sym3> out;
  for (int i = 0; i < 20000; ++i) {
    const Vec3d a = normalized({unit(rng), unit(rng), unit(rng)});
    const Vec3d b = normalized(cross(a, {unit(rng), unit(rng), unit(rng)}));
    const Vec3d c = cross(a, b);
    const double s = std::pow(10.0, 6.0 * unit(rng));
    double l0 = 0.0, l1 = 0.0, l2 = 0.0;
    switch (i % 6) {
      case 0:
        l0 = 1e-4 * s * std::abs(unit(rng)), l1 = s * (0.5 + 0.5 * std::abs(unit(rng))), l2 = s;
        break;
      case 1:
        l0 = 1e-3 * s, l1 = s, l2 = s * (1.0 + 1e-9 * unit(rng));
        break;  // round disk
      case 2:
        l0 = 0.01 * s, l1 = 0.0100001 * s, l2 = s;
        break;  // a line
      case 3:
        l0 = s * std::abs(unit(rng)), l1 = s * std::abs(unit(rng)), l2 = s * std::abs(unit(rng));
        break;
      case 4:
        l0 = 0.0, l1 = s * std::abs(unit(rng)), l2 = s;
        break;  // exactly flat
      default:
        l0 = l1 = l2 = s;
        break;  // a sphere
    }
    Sym3 m{};
    addOuterProduct(m, a, l0);
    addOuterProduct(m, b, l1);
    addOuterProduct(m, c, l2);
    out.push_back(m);
  }
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  for (const Sym3& m : {Sym3{}, Sym3{1, 0, 0, 2, 0, 3}, Sym3{2, 0, 0, 2, 0, 1},
                        Sym3{1, 0, 0, 1, 0, 1}, Sym3{nan, 0, 0, 1, 0, 1}, Sym3{inf, 0, 0, 1, 0, 1},
                        Sym3{1, 1, 1, 1, 1, 1}, Sym3{1e-300, 0, 0, 1e-300, 0, 2e-300}}) {
    out.push_back(m);
  }
  return out;
}

bool sameBits(const SmallestEigen3& a, const SmallestEigen3& b) {
  return std::memcmp(a.values.data(), b.values.data(), sizeof a.values) == 0 &&
         std::memcmp(a.vector.data(), b.vector.data(), sizeof a.vector) == 0;
}

// Every SIMD target gives the scalar function's bits for every matrix, in
// blocks of every length around the batch's inner block.
TEST(EigenBatch, EqualsTheScalarFunctionBitForBitOnEveryTarget) {
  const std::vector<Sym3> matrices = testMatrices();
  std::vector<SmallestEigen3> expected;
  for (const Sym3& m : matrices) expected.push_back(smallestEigen3(m));
  const std::vector<std::int64_t> targets = simdTargets();
  ASSERT_FALSE(targets.empty());
  for (const std::int64_t target : targets) {
    forceSimdTarget(target);
    SCOPED_TRACE("target " + std::to_string(target));
    std::vector<SmallestEigen3> out(matrices.size());
    smallestEigen3Batch(matrices, out);
    for (std::size_t i = 0; i < matrices.size(); ++i) {
      ASSERT_TRUE(sameBits(out[i], expected[i])) << "matrix " << i;
    }
    for (const std::size_t length : {std::size_t{0}, std::size_t{1}, std::size_t{63},
                                     std::size_t{64}, std::size_t{65}, std::size_t{200}}) {
      std::vector<SmallestEigen3> part(length);
      smallestEigen3Batch(std::span(matrices).subspan(7, length), part);
      for (std::size_t i = 0; i < length; ++i) {
        ASSERT_TRUE(sameBits(part[i], expected[7 + i])) << "length " << length << ", " << i;
      }
    }
  }
  forceSimdTarget(0);
}

// The closed form stays as accurate as Jacobi where the smallest eigenvalue
// is simple: values to 1e-7 of the largest, vectors parallel.
TEST(EigenBatch, AgreesWithJacobi) {
  const std::vector<Sym3> matrices = testMatrices();
  std::vector<SmallestEigen3> out(matrices.size());
  smallestEigen3Batch(matrices, out);
  std::size_t compared = 0;
  for (std::size_t i = 0; i < matrices.size(); ++i) {
    if (!std::all_of(matrices[i].begin(), matrices[i].end(),
                     [](double v) { return std::isfinite(v); }))
      continue;
    const Eigen3 e = eigenSymmetric3(matrices[i]);
    if (!(e.values[2] > 0.0)) continue;
    for (std::size_t k = 0; k < 3; ++k) {
      ASSERT_NEAR(out[i].values[k], e.values[k], 1e-7 * e.values[2]) << "matrix " << i;
    }
    ASSERT_NEAR(length(out[i].vector), 1.0, 1e-12) << "matrix " << i;
    if (e.values[1] - e.values[0] > 1e-3 * e.values[2]) {
      ASSERT_NEAR(std::abs(dot(out[i].vector, e.vectors[0])), 1.0, 1e-12) << "matrix " << i;
      ++compared;
    }
  }
  EXPECT_GT(compared, matrices.size() / 2);
}

}  // namespace
}  // namespace pointillist::preprocess
