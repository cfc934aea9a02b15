#include "preprocess/likeliest_gaussian.hpp"
#include "preprocess/simd_targets.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>
#include <stdexcept>
#include <vector>

namespace pointillist::preprocess {
namespace {

// A positive definite inverse and its log-determinant stand-in: the search
// takes them as given, so any values do.
GaussianRecord randomGaussian(std::mt19937& rng) {
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  GaussianRecord g{};
  for (double& c : g.mean) c = unit(rng);
  const double a = 1.0 + std::abs(unit(rng)) * 50.0, b = 1.0 + std::abs(unit(rng)) * 50.0;
  const double c = 1.0 + std::abs(unit(rng)) * 50.0;
  g.inverse[0] = a, g.inverse[3] = b, g.inverse[5] = c;
  g.inverse[1] = 0.3 * unit(rng), g.inverse[2] = 0.3 * unit(rng), g.inverse[4] = 0.3 * unit(rng);
  g.logDet = unit(rng) * 3.0;
  return g;
}

// Every target picks, for every input, the cluster of lowest cost and the
// lowest index among equal costs (duplicated Gaussians), keeps the cluster of
// an input that no cost reaches (NaN position), and says whether any moved.
TEST(LikeliestGaussian, EachInputTakesTheLowestCostAndTheLowestIndexOnEveryTarget) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  for (const std::size_t k : {std::size_t{1}, std::size_t{2}, std::size_t{7}, std::size_t{33}}) {
    std::vector<GaussianRecord> gaussians;
    for (std::size_t c = 0; c < k; ++c) gaussians.push_back(randomGaussian(rng));
    if (k > 2) {  // a tie at gaussian 1's mean, where it is the likeliest: index 1 must win
      gaussians[1].logDet = -100.0;
      gaussians[k - 1] = gaussians[1];
    }
    for (const std::size_t n : {std::size_t{1}, std::size_t{9}, std::size_t{255}, std::size_t{256},
                                std::size_t{257}, std::size_t{700}}) {
      std::vector<std::array<double, 3>> positions(n);
      for (auto& p : positions) p = {unit(rng), unit(rng), unit(rng)};
      if (k > 2 && n > 1)
        positions[0] = {gaussians[1].mean[0], gaussians[1].mean[1], gaussians[1].mean[2]};
      positions[n - 1][1] = std::numeric_limits<double>::quiet_NaN();
      std::vector<std::uint32_t> start(n);
      for (std::size_t i = 0; i < n; ++i) start[i] = static_cast<std::uint32_t>(i % k);
      std::vector<std::uint32_t> expected = start;
      for (std::size_t i = 0; i < n; ++i) {
        double lowest = std::numeric_limits<double>::infinity();
        for (std::size_t c = 0; c < k; ++c) {
          const double cost =
              gaussianCost(gaussians[c], positions[i][0], positions[i][1], positions[i][2]);
          if (cost < lowest) {
            lowest = cost;
            expected[i] = static_cast<std::uint32_t>(c);
          }
        }
      }
      EXPECT_EQ(expected[n - 1], start[n - 1]);  // the NaN input stays
      if (k > 2 && n > 1) {
        EXPECT_EQ(expected[0], 1u);
      }
      for (const std::int64_t target : simdTargets()) {
        forceSimdTarget(target);
        std::vector<std::uint32_t> assignment = start;
        const bool changed = assignLikeliestGaussians(positions, gaussians, assignment);
        ASSERT_EQ(assignment, expected) << "k " << k << ", n " << n << ", target " << target;
        EXPECT_EQ(changed, expected != start);
      }
      forceSimdTarget(0);
    }
  }
}

// One assignment per position, or nothing is assigned.
TEST(LikeliestGaussian, RefusesAssignmentsThatDoNotMatchThePositions) {
  std::mt19937 rng(9);
  const std::vector<GaussianRecord> gaussians{randomGaussian(rng), randomGaussian(rng)};
  const std::vector<std::array<double, 3>> positions(5, std::array<double, 3>{0.0, 0.0, 0.0});
  std::vector<std::uint32_t> assignment(4, 1u);
  EXPECT_THROW(assignLikeliestGaussians(positions, gaussians, assignment), std::invalid_argument);
  EXPECT_EQ(assignment, std::vector<std::uint32_t>(4, 1u));
}

}  // namespace
}  // namespace pointillist::preprocess
