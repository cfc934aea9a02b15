#include "common/statistical_samples.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <random>
#include <vector>

#include <glm/glm.hpp>

#include "common/camera.hpp"
#include "common/statistical_point_table.hpp"

namespace pointillist {
namespace {

// Test double: a decoded node built directly (no packet), random orthonormal
// frames and the given spreads.

StatisticalNode randomNode(std::mt19937& rng) {
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  StatisticalNode node{};
  for (float& m : node.mean) m = 4.0f * u(rng) - 2.0f;
  randomFrame(rng, node.axes);
  randomFrame(rng, node.normalFrame);
  randomFrame(rng, node.colorAxes);
  node.sigma[0] = 0.1f + u(rng);
  node.sigma[1] = node.sigma[0] * u(rng);
  node.sigma[2] = node.sigma[1] * u(rng);
  node.sigmaNormal[0] = 0.6f * u(rng);
  node.sigmaNormal[1] = node.sigmaNormal[0] * u(rng);
  for (int i = 0; i < 3; ++i) {
    node.color[i] = 255.0f * u(rng);
    node.sigmaColor[i] = 40.0f * u(rng);
  }
  return node;
}

float norm(const float* v, int n) {
  float sum = 0.0f;
  for (int i = 0; i < n; ++i) sum += v[i] * v[i];
  return std::sqrt(sum);
}

class Sequences : public ::testing::TestWithParam<SampleSequence> {};

TEST_P(Sequences, WithinGammaWithUnitMomentsAndDeterministic) {
  const std::vector<GaussianSample> samples = gaussianSamples(4096, GetParam(), 7);
  ASSERT_EQ(samples.size(), 4096u);
  constexpr float gamma = kStatisticalGamma * (1.0f + 1e-6f);
  for (const GaussianSample& s : samples) {
    EXPECT_LE(norm(s.position, 3), gamma);
    EXPECT_LE(norm(s.normal, 2), gamma);
    EXPECT_LE(norm(s.color, 3), gamma);
  }
  // Per coordinate: mean ~0, variance ~1 (truncation at 3.5 takes ~1-2 %).
  for (int c = 0; c < 8; ++c) {
    double sum = 0.0, squares = 0.0;
    for (const GaussianSample& s : samples) {
      const float* v = c < 3 ? &s.position[c] : c < 5 ? &s.normal[c - 3] : &s.color[c - 5];
      const auto x = static_cast<double>(*v);
      sum += x;
      squares += x * x;
    }
    const double mean = sum / 4096.0, variance = squares / 4096.0 - mean * mean;
    EXPECT_NEAR(mean, 0.0, 0.07) << c;
    EXPECT_NEAR(variance, 0.985, 0.08) << c;
  }
  const std::vector<GaussianSample> again = gaussianSamples(4096, GetParam(), 7);
  EXPECT_EQ(std::memcmp(samples.data(), again.data(), samples.size() * sizeof(GaussianSample)), 0);
  // A shorter sequence is a prefix of a longer one.
  const std::vector<GaussianSample> prefix = gaussianSamples(100, GetParam(), 7);
  EXPECT_EQ(std::memcmp(samples.data(), prefix.data(), prefix.size() * sizeof(GaussianSample)), 0);
}

INSTANTIATE_TEST_SUITE_P(Statistical, Sequences,
                         ::testing::Values(SampleSequence::Sobol, SampleSequence::Pseudo));

TEST(StatisticalSamples, SobolIsQuasiAndSeedless) {
  const auto sobol = gaussianSamples(64);
  // The first point after the origin is (1/2, ..., 1/2): every coordinate 0.
  for (float v : sobol[0].position) EXPECT_EQ(v, 0.0f);
  EXPECT_EQ(std::memcmp(sobol.data(), gaussianSamples(64, SampleSequence::Sobol, 99).data(),
                        64 * sizeof(GaussianSample)),
            0);
  const auto a = gaussianSamples(64, SampleSequence::Pseudo, 1);
  const auto b = gaussianSamples(64, SampleSequence::Pseudo, 2);
  EXPECT_NE(std::memcmp(a.data(), b.data(), 64 * sizeof(GaussianSample)), 0);
  // Low discrepancy: the first 256 quasi x coordinates fill 16 equiprobable
  // bins of the normal more evenly than chance would.
  const auto many = gaussianSamples(256);
  int bins[16] = {};
  for (const auto& s : many) {
    const double u = 0.5 * std::erfc(-static_cast<double>(s.position[0]) / std::sqrt(2.0));
    ++bins[std::min(15, static_cast<int>(u * 16.0))];
  }
  for (int bin : bins) EXPECT_NEAR(bin, 16, 2);
}

TEST(StatisticalSamples, GeneratePointFollowsTheFormulas) {
  std::mt19937 rng(3);
  const std::vector<GaussianSample> samples = gaussianSamples(500);
  for (int n = 0; n < 20; ++n) {
    const StatisticalNode node = randomNode(rng);
    for (const GaussianSample& s : samples) {
      const Splat p = generatePoint(node, s, 0.25f);
      EXPECT_EQ(p.radius, 0.25f);
      EXPECT_EQ(p.color[3], 255);
      // Position: its coordinates along the node's axes are sigma_k g_k, so it
      // lies in the gamma ellipsoid.
      const glm::vec3 d = glm::vec3(p.position[0], p.position[1], p.position[2]) -
                          glm::vec3(node.mean[0], node.mean[1], node.mean[2]);
      float mahalanobis = 0.0f;
      for (int k = 0; k < 3; ++k) {
        const float along =
            glm::dot(d, glm::vec3(node.axes[k][0], node.axes[k][1], node.axes[k][2]));
        EXPECT_NEAR(along, node.sigma[k] * s.position[k], 1e-4f);
        if (node.sigma[k] > 1e-3f) mahalanobis += (along / node.sigma[k]) * (along / node.sigma[k]);
      }
      EXPECT_LE(std::sqrt(mahalanobis), kStatisticalGamma + 1e-2f);
      // Normal: unit, at angle theta = |(sigma_n0 n0, sigma_n1 n1)| from the
      // mean normal, which is at most gamma * sigmaNormal[0].
      const glm::vec3 normal(p.normal[0], p.normal[1], p.normal[2]);
      EXPECT_NEAR(glm::length(normal), 1.0f, 1e-5f);
      const glm::vec3 z(node.normalFrame[2][0], node.normalFrame[2][1], node.normalFrame[2][2]);
      const float theta =
          std::hypot(node.sigmaNormal[0] * s.normal[0], node.sigmaNormal[1] * s.normal[1]);
      EXPECT_NEAR(glm::dot(normal, z), std::cos(theta), 1e-5f);
      EXPECT_LE(theta, kStatisticalGamma * node.sigmaNormal[0] + 1e-5f);
      // Colour: clamped mean + sum_k colorAxes[k] sigmaColor[k] c_k, rounded.
      for (int i = 0; i < 3; ++i) {
        float v = node.color[i];
        for (int k = 0; k < 3; ++k) v += node.colorAxes[k][i] * node.sigmaColor[k] * s.color[k];
        EXPECT_NEAR(p.color[i], std::clamp(v, 0.0f, 255.0f), 0.5001f);
      }
    }
  }
}

TEST(StatisticalFootprint, SphereFacingTheCamera) {
  const Camera camera = makeCamera({1, 2, 10}, {1, 2, 0}, {0, 1, 0}, 40.0f, 0.1f, 100.0f, 640, 480);
  StatisticalNode node{};
  node.mean[0] = 1.0f;
  node.mean[1] = 2.0f;
  node.mean[2] = -2.0f;  // depth 12
  std::mt19937 rng(5);
  randomFrame(rng, node.axes);  // any frame: a sphere
  node.sigma[0] = node.sigma[1] = node.sigma[2] = 0.05f;
  const NodeFootprint f = nodeFootprint(node, camera);
  const float expected =
      kStatisticalGamma * 0.05f * static_cast<float>(focalLengthPixels(camera)) / 12.0f;
  EXPECT_NEAR(f.major, expected, 1e-4f * expected);
  EXPECT_NEAR(f.minor, expected, 1e-4f * expected);
  // Behind the eye: nothing.
  node.mean[2] = 11.0f;
  EXPECT_EQ(nodeFootprint(node, camera).major, 0.0f);
}

TEST(StatisticalFootprint, DiskFaceOnAndEdgeOn) {
  const Camera camera = makeCamera({0, 0, 10}, {0, 0, 0}, {0, 1, 0}, 40.0f, 0.1f, 100.0f, 640, 480);
  const float focal = static_cast<float>(focalLengthPixels(camera));
  StatisticalNode node{};
  for (int k = 0; k < 3; ++k) node.axes[k][k] = 1.0f;
  node.sigma[0] = 0.2f;
  node.sigma[1] = 0.1f;
  node.sigma[2] = 0.0f;
  NodeFootprint f = nodeFootprint(node, camera);  // f3 = z: face-on
  EXPECT_NEAR(f.major, kStatisticalGamma * 0.2f * focal / 10.0f, 1e-3f);
  EXPECT_NEAR(f.minor, kStatisticalGamma * 0.1f * focal / 10.0f, 1e-3f);
  // f2 along the view: edge-on, the minor axis vanishes.
  node.axes[1][1] = 0.0f;
  node.axes[1][2] = 1.0f;
  node.axes[2][2] = 0.0f;
  node.axes[2][1] = 1.0f;
  f = nodeFootprint(node, camera);
  EXPECT_NEAR(f.major, kStatisticalGamma * 0.2f * focal / 10.0f, 1e-3f);
  EXPECT_NEAR(f.minor, 0.0f, 1e-3f);
  // The projector gives the same values.
  const FootprintProjector project(camera);
  EXPECT_EQ(project(node).major, f.major);
  EXPECT_EQ(project(node).minor, f.minor);
}

TEST(StatisticalBudget, TableEntriesMonotoneAndCapped) {
  for (std::uint32_t a = 1; a <= kStatisticalTableSize; ++a) {
    for (std::uint32_t b = 1; b <= a; ++b) {
      const PointBudget budget =
          statisticalPointBudget({static_cast<float>(a), static_cast<float>(b)});
      EXPECT_EQ(budget.count, statisticalTableEntry(a, b)) << a << " " << b;
      EXPECT_EQ(budget.pointPixels, kStatisticalPointPixels);
      // Rounded up: just above a whole pixel takes the next entry.
      if (a < kStatisticalTableSize) {
        EXPECT_EQ(
            statisticalPointBudget({static_cast<float>(a) + 0.01f, static_cast<float>(b)}).count,
            statisticalTableEntry(a + 1, b));
      }
    }
  }
  EXPECT_EQ(statisticalPointBudget({0.0f, 0.0f}).count, statisticalTableEntry(1, 1));
  EXPECT_EQ(statisticalPointBudget({0.3f, 0.1f}).count, statisticalTableEntry(1, 1));
  // Monotone in both semi-axes, through the table's edge and the cap.
  std::uint32_t previousRow = 0;
  for (float major = 0.25f; major <= 40.0f; major += 0.25f) {
    std::uint32_t previous = 0;
    float previousWidth = 0.0f;
    for (float minor = 0.25f; minor <= major; minor += 0.25f) {
      const PointBudget budget = statisticalPointBudget({major, minor});
      EXPECT_GE(budget.count, previous) << major << " " << minor;
      EXPECT_GE(budget.pointPixels, previousWidth);
      EXPECT_LE(budget.count, kStatisticalMaxSamples);
      EXPECT_GE(budget.pointPixels, kStatisticalPointPixels);
      previous = budget.count;
      previousWidth = budget.pointPixels;
    }
    const std::uint32_t rowStart = statisticalPointBudget({major, 0.25f}).count;
    EXPECT_GE(rowStart, previousRow) << major;
    previousRow = rowStart;
  }
  const PointBudget huge = statisticalPointBudget({40.0f, 40.0f});
  EXPECT_EQ(huge.count, kStatisticalMaxSamples);
  EXPECT_GT(huge.pointPixels, kStatisticalPointPixels);
  // Beyond the table: the edge entry times the area ratio.
  const std::uint32_t edge = statisticalTableEntry(kStatisticalTableSize, 1);
  EXPECT_EQ(statisticalPointBudget({2.0f * kStatisticalTableSize, 1.0f}).count, 2 * edge);
}

}  // namespace
}  // namespace pointillist
