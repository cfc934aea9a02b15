#pragma once
// The radius estimate's inner step (preprocess/normals.cpp, sampledRadius):
// the k-th smallest squared distance from a point to a leaf's points. A leaf
// holds a few dozen points and the estimate samples millions of them, so the
// distances are computed and ranked in SIMD (Highway, run-time dispatch):
// each distance's rank is counted against all the others, a vector of
// candidates at a time, which beats selecting by partitions at this size.
// The value is the one kthSmallest (preprocess/selection.hpp) gives for the
// same float distances, (dx*dx + dy*dy) + dz*dz.
#include <cstddef>
#include <span>
#include <vector>

#include "common/splat.hpp"

namespace pointillist::preprocess {

// A leaf's positions as columns, padded with +inf to whole vectors.
class LeafColumns {
 public:
  // Leaves larger than this are left to kthSmallest: ranking costs n^2.
  static constexpr std::size_t kMaxPoints = 256;

  void assign(std::span<const Splat> points);
  std::size_t size() const { return size_; }
  // The k-th smallest (0-based, k < size()) squared distance from p to the
  // points. Needs size() <= kMaxPoints.
  float kthSmallestSquaredDistance(const float p[3], std::size_t k) const;

 private:
  std::size_t size_ = 0;
  std::size_t padded_ = 0;
  std::vector<float> x_, y_, z_;
  mutable std::vector<float> distances_;
};

}  // namespace pointillist::preprocess
