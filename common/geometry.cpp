#include "common/geometry.hpp"

#include <algorithm>
#include <cmath>
#include <utility>

namespace pointillist {

double length(const Vec3d& a) {
  return std::sqrt(dot(a, a));
}

Vec3d normalized(const Vec3d& a) {
  const double len = length(a);
  if (!(len > 1e-300)) return {0.0, 0.0, 0.0};
  return scale(a, 1.0 / len);
}

Eigen3 eigenSymmetric3(const Sym3& m) {
  double a[3][3] = {{m[0], m[1], m[2]}, {m[1], m[3], m[4]}, {m[2], m[4], m[5]}};
  double v[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  for (int sweep = 0; sweep < 32; ++sweep) {
    const double off = a[0][1] * a[0][1] + a[0][2] * a[0][2] + a[1][2] * a[1][2];
    const double diag = a[0][0] * a[0][0] + a[1][1] * a[1][1] + a[2][2] * a[2][2];
    if (off <= 1e-30 * diag || off == 0.0) break;
    for (int p = 0; p < 2; ++p) {
      for (int q = p + 1; q < 3; ++q) {
        const double apq = a[p][q];
        if (apq == 0.0) continue;
        // Rotation that zeroes a[p][q] (Numerical Recipes' stable form).
        const double theta = (a[q][q] - a[p][p]) / (2.0 * apq);
        const double t =
            (theta >= 0 ? 1.0 : -1.0) / (std::abs(theta) + std::sqrt(theta * theta + 1.0));
        const double c = 1.0 / std::sqrt(t * t + 1.0);
        const double s = t * c;
        for (int k = 0; k < 3; ++k) {
          const double akp = a[k][p];
          const double akq = a[k][q];
          a[k][p] = c * akp - s * akq;
          a[k][q] = s * akp + c * akq;
        }
        for (int k = 0; k < 3; ++k) {
          const double apk = a[p][k];
          const double aqk = a[q][k];
          a[p][k] = c * apk - s * aqk;
          a[q][k] = s * apk + c * aqk;
        }
        for (int k = 0; k < 3; ++k) {
          const double vkp = v[k][p];
          const double vkq = v[k][q];
          v[k][p] = c * vkp - s * vkq;
          v[k][q] = s * vkp + c * vkq;
        }
      }
    }
  }
  std::array<int, 3> order = {0, 1, 2};
  std::sort(order.begin(), order.end(), [&](int i, int j) { return a[i][i] < a[j][j]; });
  Eigen3 result{};
  for (std::size_t i = 0; i < 3; ++i) {
    const int col = order[i];
    result.values[i] = a[col][col];
    result.vectors[i] = normalized({v[0][col], v[1][col], v[2][col]});
  }
  return result;
}

SmallestEigen3 smallestEigen3(const Sym3& m) {
  auto jacobi = [&] {
    const Eigen3 e = eigenSymmetric3(m);
    return SmallestEigen3{e.values, e.vectors[0]};
  };
  const double q = (m[0] + m[3] + m[5]) / 3.0;
  const double p1 = m[1] * m[1] + m[2] * m[2] + m[4] * m[4];
  const double p2 =
      (m[0] - q) * (m[0] - q) + (m[3] - q) * (m[3] - q) + (m[5] - q) * (m[5] - q) + 2.0 * p1;
  const double p = std::sqrt(p2 / 6.0);
  if (!(p > 0.0) || !std::isfinite(p)) return jacobi();
  const double ip = 1.0 / p;
  const double b0 = (m[0] - q) * ip, b1 = m[1] * ip, b2 = m[2] * ip;
  const double b3 = (m[3] - q) * ip, b4 = m[4] * ip, b5 = (m[5] - q) * ip;
  const double r = std::clamp(
      0.5 * (b0 * (b3 * b5 - b4 * b4) - b1 * (b1 * b5 - b4 * b2) + b2 * (b1 * b4 - b3 * b2)), -1.0,
      1.0);
  const double phi = std::acos(r) / 3.0;
  constexpr double kTwoPiThirds = 2.0943951023931954923;
  const double hi = q + 2.0 * p * std::cos(phi);
  const double lo = q + 2.0 * p * std::cos(phi + kTwoPiThirds);
  const double mid = 3.0 * q - hi - lo;
  if (mid - lo < 1e-6 * (hi - lo)) return jacobi();
  const Vec3d r0 = {m[0] - lo, m[1], m[2]};
  const Vec3d r1 = {m[1], m[3] - lo, m[4]};
  const Vec3d r2 = {m[2], m[4], m[5] - lo};
  auto cross = [](const Vec3d& a, const Vec3d& b) -> Vec3d {
    return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
  };
  Vec3d best = cross(r0, r1);
  for (const Vec3d& c : {cross(r0, r2), cross(r1, r2)})
    if (dot(c, c) > dot(best, best)) best = c;
  const Vec3d v = normalized(best);
  if (length(v) == 0.0) return jacobi();
  return {{lo, mid, hi}, v};
}

void CovarianceAccumulator::add(const Vec3d& p, double weight) {
  if (count_ == 0) origin_ = p;
  const Vec3d d = sub(p, origin_);
  sum_ = pointillist::add(sum_, scale(d, weight));
  sumSq_[0] += weight * d[0] * d[0];
  sumSq_[1] += weight * d[0] * d[1];
  sumSq_[2] += weight * d[0] * d[2];
  sumSq_[3] += weight * d[1] * d[1];
  sumSq_[4] += weight * d[1] * d[2];
  sumSq_[5] += weight * d[2] * d[2];
  weight_ += weight;
  ++count_;
}

Vec3d CovarianceAccumulator::mean() const {
  if (!(weight_ > 0.0)) return origin_;
  return pointillist::add(origin_, scale(sum_, 1.0 / weight_));
}

Sym3 CovarianceAccumulator::covariance() const {
  if (!(weight_ > 0.0)) return {};
  const Vec3d m = scale(sum_, 1.0 / weight_);
  const double w = 1.0 / weight_;
  Sym3 c = {sumSq_[0] * w - m[0] * m[0], sumSq_[1] * w - m[0] * m[1], sumSq_[2] * w - m[0] * m[2],
            sumSq_[3] * w - m[1] * m[1], sumSq_[4] * w - m[1] * m[2], sumSq_[5] * w - m[2] * m[2]};
  // Cancellation can leave tiny negative variances; covariance is PSD.
  c[0] = std::max(c[0], 0.0);
  c[3] = std::max(c[3], 0.0);
  c[5] = std::max(c[5], 0.0);
  return c;
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
