// The one 3x3 symmetric eigen solver (normals, level-splats) and the running
// covariance sums: eigen pairs, orthonormal vectors, ascending values, exact on
// repeated roots, and no precision lost far from the origin.
#include "common/geometry.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

namespace pointillist {
namespace {

using Matrix = std::array<std::array<double, 3>, 3>;

// The solver of common/geometry.hpp on a full (symmetric) matrix.
Eigen3 eigenOf(const Matrix& m) {
  return eigenSymmetric3({m[0][0], m[0][1], m[0][2], m[1][1], m[1][2], m[2][2]});
}

void expectEigenPairs(const Matrix& m, const Eigen3& e) {
  EXPECT_LE(e.values[0], e.values[1]);
  EXPECT_LE(e.values[1], e.values[2]);
  double scale = 1e-300;
  for (const auto& row : m) {
    for (const double x : row) scale = std::max(scale, std::abs(x));
  }
  for (std::size_t i = 0; i < 3; ++i) {
    const auto& v = e.vectors[i];
    for (std::size_t r = 0; r < 3; ++r) {
      const double mv = m[r][0] * v[0] + m[r][1] * v[1] + m[r][2] * v[2];
      EXPECT_NEAR(mv, e.values[i] * v[r], 1e-10 * scale) << "pair " << i;
    }
    for (std::size_t j = 0; j < 3; ++j) {
      const auto& w = e.vectors[j];
      EXPECT_NEAR(v[0] * w[0] + v[1] * w[1] + v[2] * w[2], i == j ? 1.0 : 0.0, 1e-12);
    }
  }
}

TEST(Eigen3, DecomposesRotatedDiagonalMatrices) {
  std::mt19937 rng(4);
  std::normal_distribution<double> g(0.0, 1.0);
  for (int trial = 0; trial < 200; ++trial) {
    // Random orthonormal basis by Gram-Schmidt, random (sometimes repeated) eigenvalues.
    Vec3d a = {g(rng), g(rng), g(rng)}, b = {g(rng), g(rng), g(rng)};
    a = normalized(a);
    b = normalized(sub(b, scale(a, dot(a, b))));
    const Vec3d c = {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                     a[0] * b[1] - a[1] * b[0]};
    double l[3] = {std::abs(g(rng)), std::abs(g(rng)), trial % 3 == 0 ? 0.0 : std::abs(g(rng))};
    if (trial % 5 == 0) l[1] = l[0];
    const Vec3d* v[3] = {&a, &b, &c};
    Sym3 m{};
    const int idx[6][2] = {{0, 0}, {0, 1}, {0, 2}, {1, 1}, {1, 2}, {2, 2}};
    for (int e = 0; e < 6; ++e)
      for (int k = 0; k < 3; ++k)
        m[static_cast<std::size_t>(e)] += l[k] * (*v[k])[static_cast<std::size_t>(idx[e][0])] *
                                          (*v[k])[static_cast<std::size_t>(idx[e][1])];
    const Eigen3 r = eigenSymmetric3(m);
    std::vector<double> expected(l, l + 3);
    std::sort(expected.begin(), expected.end());
    for (std::size_t k = 0; k < 3; ++k) {
      EXPECT_NEAR(r.values[k], expected[k], 1e-9);
      EXPECT_NEAR(length(r.vectors[k]), 1.0, 1e-12);
      // A v = lambda v
      const Vec3d& x = r.vectors[k];
      const Vec3d ax = {m[0] * x[0] + m[1] * x[1] + m[2] * x[2],
                        m[1] * x[0] + m[3] * x[1] + m[4] * x[2],
                        m[2] * x[0] + m[4] * x[1] + m[5] * x[2]};
      EXPECT_NEAR(length(sub(ax, scale(x, r.values[k]))), 0.0, 1e-9);
    }
    EXPECT_NEAR(dot(r.vectors[0], r.vectors[1]), 0.0, 1e-9);
    EXPECT_NEAR(dot(r.vectors[1], r.vectors[2]), 0.0, 1e-9);
    // The closed form agrees (its values lose digits near repeated roots, and
    // the vector is only defined for a simple smallest value).
    const SmallestEigen3 f = smallestEigen3(m);
    for (std::size_t k = 0; k < 3; ++k) EXPECT_NEAR(f.values[k], expected[k], 1e-6);
    if (expected[1] - expected[0] > 1e-3) {
      EXPECT_NEAR(std::abs(dot(f.vector, r.vectors[0])), 1.0, 1e-9);
    }
    EXPECT_NEAR(length(f.vector), 1.0, 1e-12);
  }
  const Eigen3 zero = eigenSymmetric3(Sym3{});
  EXPECT_EQ(zero.values[2], 0.0);
  EXPECT_NEAR(length(zero.vectors[0]), 1.0, 1e-12);
}

TEST(Covariance, MeanAndCovarianceFarFromTheOrigin) {
  CovarianceAccumulator acc;
  for (double x : {1e6 + 1.0, 1e6 - 1.0}) acc.add({x, 5.0, -3.0});
  EXPECT_DOUBLE_EQ(acc.mean()[0], 1e6);
  EXPECT_DOUBLE_EQ(acc.covariance()[0], 1.0);
  EXPECT_DOUBLE_EQ(acc.covariance()[3], 0.0);
}

TEST(SymmetricEigen3, DiagonalRepeatedAndRandom) {
  expectEigenPairs({{{3, 0, 0}, {0, 1, 0}, {0, 0, 2}}},
                   eigenOf({{{3, 0, 0}, {0, 1, 0}, {0, 0, 2}}}));
  const auto diag = eigenOf({{{3, 0, 0}, {0, 1, 0}, {0, 0, 2}}});
  EXPECT_DOUBLE_EQ(diag.values[0], 1);
  EXPECT_DOUBLE_EQ(std::abs(diag.vectors[0][1]), 1);
  const Matrix repeated{{{2, 1, 1}, {1, 2, 1}, {1, 1, 2}}};  // eigenvalues 1, 1, 4
  const auto e = eigenOf(repeated);
  expectEigenPairs(repeated, e);
  EXPECT_NEAR(e.values[0], 1, 1e-12);
  EXPECT_NEAR(e.values[2], 4, 1e-12);
  expectEigenPairs(Matrix{}, eigenOf(Matrix{}));
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> exponent(-8.0, 8.0), entry(-1.0, 1.0);
  for (int t = 0; t < 200; ++t) {
    Matrix m{};
    const double scale = std::pow(10.0, exponent(rng));
    for (std::size_t r = 0; r < 3; ++r) {
      for (std::size_t c = r; c < 3; ++c) m[r][c] = m[c][r] = scale * entry(rng);
    }
    expectEigenPairs(m, eigenOf(m));
  }
  // A nearly flat covariance: the normal is the thin direction.
  const auto flat = eigenOf({{{4, 0.001, 0}, {0.001, 3, 0.002}, {0, 0.002, 1e-6}}});
  EXPECT_GT(std::abs(flat.vectors[0][2]), 0.9999);
}

TEST(MajorAxis, FindsTheDirectionOfLargestSpread) {
  // Spread 9 along (1, 1, 0)/sqrt 2, 1 across it, 0.1 up.
  const double h = 0.5 * (9.0 + 1.0), d = 0.5 * (9.0 - 1.0);
  const Vec3d axis = majorAxis({h, d, 0.0, h, 0.0, 0.1});
  EXPECT_NEAR(std::abs(dot(axis, normalized({1.0, 1.0, 0.0}))), 1.0, 1e-6);
  EXPECT_NEAR(length(axis), 1.0, 1e-12);
}

}  // namespace
}  // namespace pointillist
