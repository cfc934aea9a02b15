#include "preprocess/leaf_distances.hpp"
#include "preprocess/selection.hpp"
#include "preprocess/simd_targets.hpp"

#include <gtest/gtest.h>

#include <cstring>
#include <limits>
#include <random>
#include <stdexcept>
#include <vector>

namespace pointillist::preprocess {
namespace {

// The scalar reference: the distances as sampledRadius wrote them, selected
// by kthSmallest.
float scalarKth(const std::vector<Splat>& points, const float p[3], std::size_t k) {
  std::vector<float> distances(points.size()), spare(points.size());
  for (std::size_t i = 0; i < points.size(); ++i) {
    const float* q = points[i].position;
    const float dx = q[0] - p[0], dy = q[1] - p[1], dz = q[2] - p[2];
    distances[i] = dx * dx + dy * dy + dz * dz;
  }
  return kthSmallest(distances.data(), spare.data(), points.size(), k);
}

// On every target, every rank of leaves of 1 to 256 points gives kthSmallest's
// value bit for bit, whatever bound is given: with repeated points (ties of
// rank), points on a coarse grid (many equal distances), distances that
// overflow to +inf, and sizes around whole vectors.
TEST(LeafColumns, EveryRankIsKthSmallestsValueOnEveryTarget) {
  std::mt19937 rng(17);
  std::uniform_real_distribution<float> unit(-1.0f, 1.0f);
  std::uniform_int_distribution<int> grid(-3, 3);
  const auto targets = simdTargets();
  ASSERT_FALSE(targets.empty());
  std::size_t checked = 0, ties = 0;
  for (const std::size_t n : {1u, 2u, 13u, 15u, 16u, 17u, 52u, 64u, 65u, 100u, 255u, 256u}) {
    for (int variant = 0; variant < 4; ++variant) {
      std::vector<Splat> points(n);
      for (std::size_t i = 0; i < n; ++i) {
        for (float& c : points[i].position)
          c = variant == 1 ? static_cast<float>(grid(rng)) : unit(rng);
        if (variant == 2 && i % 3 == 1) points[i] = points[i - 1];      // repeated points
        if (variant == 3 && i % 4 == 0) points[i].position[0] = 3e38f;  // overflows when squared
      }
      LeafColumns columns;
      columns.assign(points);
      ASSERT_EQ(columns.size(), n);
      for (std::size_t sample = 0; sample < std::min<std::size_t>(n, 5); ++sample) {
        const float* p = points[(2 * sample + 1) * n / 10 % n].position;
        for (std::size_t k = 0; k < n; k += 1 + n / 20) {
          const float expected = scalarKth(points, p, k);
          ties += k > 0 && scalarKth(points, p, k - 1) == expected;
          // Bounds that too few pass, that just enough pass, that all pass,
          // and none (infinite, NaN).
          const float bounds[] = {std::numeric_limits<float>::infinity(),
                                  0.0f,
                                  0.5f * expected,
                                  expected,
                                  4.0f * expected,
                                  std::numeric_limits<float>::max(),
                                  std::numeric_limits<float>::quiet_NaN()};
          for (const std::int64_t target : targets) {
            forceSimdTarget(target);
            for (const float bound : bounds) {
              const float got = columns.kthSmallestSquaredDistance(p, k, bound);
              ASSERT_EQ(std::memcmp(&got, &expected, sizeof got), 0)
                  << "n " << n << " variant " << variant << " k " << k << " target " << target
                  << " bound " << bound << ": " << got << " against " << expected;
              ++checked;
            }
          }
          forceSimdTarget(0);
        }
      }
    }
  }
  EXPECT_GT(checked, 1000u);
  EXPECT_GT(ties, 50u);  // the equal-rank cases were met
}

TEST(LeafColumns, RefusesARankBeyondThePointsAndLeavesTooLarge) {
  std::vector<Splat> points(3);
  LeafColumns columns;
  columns.assign(points);
  const float p[3] = {0.0f, 0.0f, 0.0f};
  EXPECT_EQ(columns.kthSmallestSquaredDistance(p, 2), 0.0f);
  EXPECT_THROW((void)columns.kthSmallestSquaredDistance(p, 3), std::invalid_argument);
  points.resize(LeafColumns::kMaxPoints + 1);
  columns.assign(points);
  EXPECT_THROW((void)columns.kthSmallestSquaredDistance(p, 0), std::invalid_argument);
}

}  // namespace
}  // namespace pointillist::preprocess
