#pragma once
// Small double-precision geometry shared by the preprocess stages: vector
// helpers, the one 3x3 symmetric eigen solver (covariance analysis for normals
// and level-splats) and running covariance sums.
#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>

#include "common/octree_cell.hpp"

namespace pointillist {

using Vec3d = std::array<double, 3>;

// Symmetric 3x3 matrix stored as its upper triangle: xx, xy, xz, yy, yz, zz.
using Sym3 = std::array<double, 6>;

struct Eigen3 {
  std::array<double, 3> values;  // ascending
  // Orthonormal up to rounding (products of exact rotations, not re-normalized);
  // vectors[i] belongs to values[i].
  std::array<Vec3d, 3> vectors;
};

// Cyclic Jacobi rotations: robust for the (near-)degenerate covariances of
// planar or collinear point sets, accurate to a few ulps of the largest value.
Eigen3 eigenSymmetric3(const Sym3& m);

// Eigenvalues (ascending) and the eigenvector of the smallest one, in closed
// form -- several times faster than Jacobi; falls back to Jacobi when the
// smallest eigenvalue is (nearly) repeated and the closed-form vector would be
// unreliable. Smith (1961) scales m - q I (q the mean eigenvalue) to B, whose
// eigenvalues beta solve beta^3 - 3 beta = det B: the smallest is found by
// Newton steps instead of acos and cos (which cost as much as the rest), the
// other two from the quadratic left; the vector is the longest cross product
// of two rows of m - lo I. Only + - * / and sqrt: a batch in SIMD
// (preprocess/eigen_batch) gives the same bits.
struct SmallestEigen3 {
  std::array<double, 3> values;
  Vec3d vector;  // unit
};
SmallestEigen3 smallestEigen3(const Sym3& m);

// Unit direction of the largest eigenvalue by a few power-iteration steps:
// enough for choosing a cut and much cheaper than eigenSymmetric3 (used only
// when the iteration collapses). Not accurate when the two largest are close.
Vec3d majorAxis(const Sym3& m);

// Population covariance from a total weight, the weighted sum of samples and
// the weighted sum of their outer products (about any origin). Cancellation
// can leave tiny negative variances; they are clamped, a covariance is PSD.
// Zero when the weight is not positive.
Sym3 covarianceFromSums(double weight, const Vec3d& sum, const Sym3& sumSquares);

// Accumulates mean and covariance of weighted 3D samples in one pass. Sums are
// taken relative to the first sample so large coordinates lose no precision.
class CovarianceAccumulator {
 public:
  // Inline: the preprocess calls it for every point several times over.
  inline void add(const Vec3d& p, double weight = 1.0);
  double weight() const { return weight_; }
  std::size_t count() const { return count_; }
  Vec3d mean() const;
  // Population covariance (divides by the total weight); zero when empty.
  Sym3 covariance() const;

 private:
  Vec3d origin_{};
  Vec3d sum_{};
  Sym3 sumSq_{};
  double weight_ = 0.0;
  std::size_t count_ = 0;
};

inline double dot(const Vec3d& a, const Vec3d& b) {
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}
inline Vec3d sub(const Vec3d& a, const Vec3d& b) {
  return {a[0] - b[0], a[1] - b[1], a[2] - b[2]};
}
inline Vec3d add(const Vec3d& a, const Vec3d& b) {
  return {a[0] + b[0], a[1] + b[1], a[2] + b[2]};
}
inline Vec3d scale(const Vec3d& a, double s) {
  return {a[0] * s, a[1] * s, a[2] * s};
}
inline Vec3d cross(const Vec3d& a, const Vec3d& b) {
  return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}
// m += weight * d d^T (upper triangle).
inline void addOuterProduct(Sym3& m, const Vec3d& d, double weight = 1.0) {
  m[0] += weight * d[0] * d[0];
  m[1] += weight * d[0] * d[1];
  m[2] += weight * d[0] * d[2];
  m[3] += weight * d[1] * d[1];
  m[4] += weight * d[1] * d[2];
  m[5] += weight * d[2] * d[2];
}
// Inline: called per point in the preprocess's inner loops.
inline double length(const Vec3d& a) {
  return std::sqrt(dot(a, a));
}
// Unit vector along a; {0,0,0} when a is (nearly) zero.
inline Vec3d normalized(const Vec3d& a) {
  const double len = length(a);
  if (!(len > 1e-300)) return {0.0, 0.0, 0.0};
  return scale(a, 1.0 / len);
}

// Normal cones of OctreeCell: axis and cosine of the half angle as snorm16
// (value / 32767). The axis is normalized after decoding; the stored cosine is
// rounded down so the decoded cone contains every normal the encoder saw.
inline constexpr std::int16_t kNoNormalCone = -32767;

struct NormalCone {
  Vec3d axis{};                // unit
  double cosHalfAngle = -1.0;  // -1: the whole sphere
  bool valid = false;          // false: never back-face cull
};

using ConeAxisQ = std::array<std::int16_t, 3>;

ConeAxisQ quantizeConeAxis(const Vec3d& axis);
Vec3d decodeConeAxis(const ConeAxisQ& q);  // unit (normalized after decoding)
NormalCone decodeNormalCone(const OctreeCell& cell);
// Stores axis `q` and a cosine rounded down from `minDot`, the smallest
// dot(decodeConeAxis(q), n) over the unit normals n the cone must contain.
void encodeNormalCone(OctreeCell& cell, const ConeAxisQ& q, double minDot);
void clearNormalCone(OctreeCell& cell);

inline void CovarianceAccumulator::add(const Vec3d& p, double weight) {
  if (count_ == 0) origin_ = p;
  const Vec3d d = sub(p, origin_);
  sum_ = pointillist::add(sum_, scale(d, weight));
  addOuterProduct(sumSq_, d, weight);
  weight_ += weight;
  ++count_;
}

}  // namespace pointillist
