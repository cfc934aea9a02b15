#include "common/geometry.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

namespace pointillist {

Eigen3 eigenSymmetric3(const Sym3& m) {
  std::array<std::array<double, 3>, 3> a{
      {{m[0], m[1], m[2]}, {m[1], m[3], m[4]}, {m[2], m[4], m[5]}}};
  std::array<std::array<double, 3>, 3> v{{{1, 0, 0}, {0, 1, 0}, {0, 0, 1}}};
  // The rotations keep the Frobenius norm, so the input's serves as a fixed
  // convergence scale (the diagonal alone may be zero).
  double frobenius = 0;
  for (const auto& row : a) {
    for (const double x : row) frobenius += x * x;
  }
  for (int sweep = 0; sweep < 64; ++sweep) {
    const double off = a[0][1] * a[0][1] + a[0][2] * a[0][2] + a[1][2] * a[1][2];
    if (off <= 1e-30 * frobenius || off == 0) break;
    for (std::size_t p = 0; p < 2; ++p) {
      for (std::size_t q = p + 1; q < 3; ++q) {
        const double apq = a[p][q];
        if (apq == 0) continue;
        // Rotation angle that zeroes a[p][q]; t = tan, the smaller root. hypot
        // and the 1 / (2 theta) limit keep t finite where theta^2 would overflow.
        const double theta = (a[q][q] - a[p][p]) / (2 * apq);
        const double t = std::abs(theta) > 1e150 ? 0.5 / theta
                                                 : std::copysign(1.0, theta) /
                                                       (std::abs(theta) + std::hypot(theta, 1.0));
        const double c = 1 / std::sqrt(t * t + 1);
        const double s = t * c;
        for (std::size_t k = 0; k < 3; ++k) {
          const double akp = a[k][p], akq = a[k][q];
          a[k][p] = c * akp - s * akq;
          a[k][q] = s * akp + c * akq;
        }
        for (std::size_t k = 0; k < 3; ++k) {
          const double apk = a[p][k], aqk = a[q][k];
          a[p][k] = c * apk - s * aqk;
          a[q][k] = s * apk + c * aqk;
        }
        for (std::size_t k = 0; k < 3; ++k) {
          const double vkp = v[k][p], vkq = v[k][q];
          v[k][p] = c * vkp - s * vkq;
          v[k][q] = s * vkp + c * vkq;
        }
      }
    }
  }
  std::array<std::size_t, 3> order{0, 1, 2};
  std::sort(order.begin(), order.end(),
            [&](std::size_t i, std::size_t j) { return a[i][i] < a[j][j]; });
  Eigen3 result{};
  for (std::size_t i = 0; i < 3; ++i) {
    result.values[i] = a[order[i]][order[i]];
    for (std::size_t k = 0; k < 3; ++k) result.vectors[i][k] = v[k][order[i]];
  }
  return result;
}

namespace {
// With u = sqrt(1 - det B / 2) in [0, sqrt 2], the smallest root of
// beta^3 - 3 beta = det B is -1 - u g, where g solves 3 g^2 + u g^3 = 2:
// smooth in u (between 1/sqrt 2 and sqrt(2/3)), where beta itself has a
// square-root corner at u = 0. A quadratic guess and three Newton steps give
// g to a few ulps over the whole range.
double smallestRootScale(double u) {
  const double t = u * 0.70710678118654752440;  // in [0, 1]
  double g = 0.81649658092772603 + t * (-0.14664724674687624 + t * 0.037257447005697664);
  for (int step = 0; step < 3; ++step) {
    const double g2 = g * g;
    g = g - (3.0 * g2 + u * g2 * g - 2.0) / (6.0 * g + 3.0 * u * g2);
  }
  return g;
}
}  // namespace

SmallestEigen3 smallestEigen3(const Sym3& m) {
  auto jacobi = [&] {
    const Eigen3 e = eigenSymmetric3(m);
    return SmallestEigen3{e.values, e.vectors[0]};
  };
  // Each step as the batched form in preprocess/eigen_batch.cpp takes it, so
  // the two give the same bits.
  const double q = (m[0] + m[3] + m[5]) / 3.0;
  const double d0 = m[0] - q, d3 = m[3] - q, d5 = m[5] - q;
  const double p1 = m[1] * m[1] + m[2] * m[2] + m[4] * m[4];
  const double p2 = d0 * d0 + d3 * d3 + d5 * d5 + 2.0 * p1;
  const double p = std::sqrt(p2 / 6.0);
  if (!(p > 0.0 && p < std::numeric_limits<double>::infinity())) return jacobi();
  const double ip = 1.0 / p;
  const double b0 = d0 * ip, b1 = m[1] * ip, b2 = m[2] * ip;
  const double b3 = d3 * ip, b4 = m[4] * ip, b5 = d5 * ip;
  const double det = b0 * (b3 * b5 - b4 * b4) - b1 * (b1 * b5 - b4 * b2) + b2 * (b1 * b4 - b3 * b2);
  const double r = std::clamp(0.5 * det, -1.0, 1.0);
  const double u = std::sqrt(1.0 - r);
  const double g = smallestRootScale(u);
  const double betaLo = -1.0 - u * g;
  const double disc = std::max(0.0, 12.0 - 3.0 * betaLo * betaLo);
  const double lo = q + p * betaLo;
  const double hi = q + p * (0.5 * (std::sqrt(disc) - betaLo));
  const double mid = 3.0 * q - hi - lo;
  if (mid - lo < 1e-6 * (hi - lo)) return jacobi();
  const Vec3d r0 = {m[0] - lo, m[1], m[2]};
  const Vec3d r1 = {m[1], m[3] - lo, m[4]};
  const Vec3d r2 = {m[2], m[4], m[5] - lo};
  Vec3d best = cross(r0, r1);
  double bestSquared = dot(best, best);
  for (const Vec3d& c : {cross(r0, r2), cross(r1, r2)}) {
    const double squared = dot(c, c);
    if (squared > bestSquared) {
      best = c;
      bestSquared = squared;
    }
  }
  const double len = std::sqrt(bestSquared);
  if (!(len > 1e-300)) return jacobi();
  return {{lo, mid, hi}, scale(best, 1.0 / len)};
}

namespace {
Sym3 squared(const Sym3& a) {
  return {a[0] * a[0] + a[1] * a[1] + a[2] * a[2], a[0] * a[1] + a[1] * a[3] + a[2] * a[4],
          a[0] * a[2] + a[1] * a[4] + a[2] * a[5], a[1] * a[1] + a[3] * a[3] + a[4] * a[4],
          a[1] * a[2] + a[3] * a[4] + a[4] * a[5], a[2] * a[2] + a[4] * a[4] + a[5] * a[5]};
}
}  // namespace

Vec3d majorAxis(const Sym3& m) {
  const Vec3d cols[3] = {{m[0], m[1], m[2]}, {m[1], m[3], m[4]}, {m[2], m[4], m[5]}};
  Vec3d v = cols[0];
  for (const Vec3d& col : cols)
    if (dot(col, col) > dot(v, v)) v = col;
  // Eight power-iteration steps from the largest column as one product with
  // M^8, which three squarings make: no chain of eight dependent divisions.
  // Scaled so the largest entry is 1 (entries of the eighth power stay below
  // 3^7, far from overflow).
  double largest = 0.0;
  for (const double e : m) largest = std::max(largest, std::abs(e));
  if (largest > 0.0 && std::isfinite(largest)) {
    Sym3 a;
    for (std::size_t i = 0; i < 6; ++i) a[i] = m[i] / largest;
    a = squared(squared(squared(a)));
    for (double& c : v) c /= largest;
    v = {a[0] * v[0] + a[1] * v[1] + a[2] * v[2], a[1] * v[0] + a[3] * v[1] + a[4] * v[2],
         a[2] * v[0] + a[4] * v[1] + a[5] * v[2]};
  }
  const Vec3d n = normalized(v);
  return length(n) > 0.0 ? n : eigenSymmetric3(m).vectors[2];
}

Vec3d CovarianceAccumulator::mean() const {
  if (!(weight_ > 0.0)) return origin_;
  return pointillist::add(origin_, scale(sum_, 1.0 / weight_));
}

Sym3 covarianceFromSums(double weight, const Vec3d& sum, const Sym3& sumSquares) {
  if (!(weight > 0.0)) return {};
  const Vec3d m = scale(sum, 1.0 / weight);
  const double w = 1.0 / weight;
  Sym3 c = {sumSquares[0] * w - m[0] * m[0], sumSquares[1] * w - m[0] * m[1],
            sumSquares[2] * w - m[0] * m[2], sumSquares[3] * w - m[1] * m[1],
            sumSquares[4] * w - m[1] * m[2], sumSquares[5] * w - m[2] * m[2]};
  c[0] = std::max(c[0], 0.0);
  c[3] = std::max(c[3], 0.0);
  c[5] = std::max(c[5], 0.0);
  return c;
}

Sym3 CovarianceAccumulator::covariance() const {
  return covarianceFromSums(weight_, sum_, sumSq_);
}

}  // namespace pointillist

namespace pointillist {

namespace {
std::int16_t toSnorm16(double v) {
  const double c = std::clamp(v, -1.0, 1.0) * 32767.0;
  return static_cast<std::int16_t>(std::lround(c));
}
}  // namespace

ConeAxisQ quantizeConeAxis(const Vec3d& axis) {
  return {toSnorm16(axis[0]), toSnorm16(axis[1]), toSnorm16(axis[2])};
}

Vec3d decodeConeAxis(const ConeAxisQ& q) {
  return normalized(
      {static_cast<double>(q[0]), static_cast<double>(q[1]), static_cast<double>(q[2])});
}

NormalCone decodeNormalCone(const OctreeCell& cell) {
  NormalCone cone;
  const ConeAxisQ q = {cell.coneAxis[0], cell.coneAxis[1], cell.coneAxis[2]};
  cone.axis = decodeConeAxis(q);
  cone.valid = cell.coneCos > kNoNormalCone && length(cone.axis) > 0.5;
  cone.cosHalfAngle = cone.valid ? cell.coneCos / 32767.0 : -1.0;
  return cone;
}

void encodeNormalCone(OctreeCell& cell, const ConeAxisQ& q, double minDot) {
  for (std::size_t i = 0; i < 3; ++i) cell.coneAxis[i] = q[i];
  // One step below the floor absorbs float rounding in consumers.
  const double scaled = std::floor(std::clamp(minDot, -1.0, 1.0) * 32767.0) - 1.0;
  cell.coneCos = static_cast<std::int16_t>(std::clamp(scaled, -32767.0, 32767.0));
  if (q == ConeAxisQ{0, 0, 0}) clearNormalCone(cell);
}

void clearNormalCone(OctreeCell& cell) {
  cell.coneAxis[0] = cell.coneAxis[1] = cell.coneAxis[2] = 0;
  cell.coneCos = kNoNormalCone;
}

}  // namespace pointillist
