#pragma once
// The radius estimate's inner step (preprocess/normals.cpp, sampledRadius):
// the k-th smallest squared distance from a point to a leaf's points. A leaf
// holds a few dozen points and the estimate samples millions of them, so the
// distances are computed and ranked in SIMD (Highway, run-time dispatch):
// each distance's rank is counted against all the others, a vector of
// candidates at a time, which beats selecting by partitions up to about
// eight vectors of points (128 with AVX-512, 64 with AVX2); beyond that the
// SIMD distances are selected by partitions. Given a bound that more than k
// distances pass, only those are ranked.
// The value is the one kthSmallest (preprocess/selection.hpp) gives for the
// same float distances, (dx*dx + dy*dy) + dz*dz.
#include <cstddef>
#include <limits>
#include <span>
#include <vector>

#include "common/splat.hpp"

namespace pointillist::preprocess {

namespace detail {
// What the SIMD kernel returns: the value found, a leaf left to selection by
// partitions, no value of that rank (cannot happen for finite positions).
inline constexpr int kRanked = 1;
inline constexpr int kLeftToSelection = 0;
inline constexpr int kNoRank = -1;
}  // namespace detail

// A leaf's positions as columns, padded with +inf to whole vectors.
class LeafColumns {
 public:
  // Larger leaves are left to the caller (columns would cost more than they save).
  static constexpr std::size_t kMaxPoints = 256;

  void assign(std::span<const Splat> points);
  std::size_t size() const { return size_; }
  // The k-th smallest (0-based, k < size()) squared distance from p to the
  // points. Needs size() <= kMaxPoints. When more than k distances are at
  // most `bound` (a guess, e.g. a nearby point's figure), only those are
  // ranked, which is cheaper; the value is the same for any bound.
  float kthSmallestSquaredDistance(const float p[3], std::size_t k,
                                   float bound = std::numeric_limits<float>::infinity()) const;

 private:
  std::size_t size_ = 0;
  std::size_t padded_ = 0;
  std::vector<float> x_, y_, z_;
  mutable std::vector<float> distances_, values_;
};

}  // namespace pointillist::preprocess
