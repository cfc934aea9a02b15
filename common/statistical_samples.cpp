#include "common/statistical_samples.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <random>

#include <boost/math/special_functions/erf.hpp>
#include <boost/random/sobol.hpp>
#include <glm/glm.hpp>

namespace pointillist {

namespace {

constexpr std::size_t kDimensions = 8;
// 2^-64 and 2^-53: integer draws to (0, 1).
constexpr double kTwoToMinus64 = 1.0 / 18446744073709551616.0;
constexpr double kTwoToMinus53 = 1.0 / 9007199254740992.0;

// Standard normal quantile: sqrt(2) erf^-1(2u - 1), u in (0, 1).
double normalQuantile(double u) {
  return std::sqrt(2.0) * boost::math::erf_inv(2.0 * u - 1.0);
}

bool withinGamma(std::initializer_list<double> v) {
  double sum = 0.0;
  for (double x : v) sum += x * x;
  constexpr auto gamma = static_cast<double>(kStatisticalGamma);
  return sum <= gamma * gamma;
}

// Maps a point of (0,1)^8 and keeps it when every part lies within gamma.
bool toSample(const std::array<double, kDimensions>& u, GaussianSample& out) {
  std::array<double, kDimensions> g{};
  for (std::size_t i = 0; i < kDimensions; ++i) {
    if (!(u[i] > 0.0 && u[i] < 1.0)) return false;
    g[i] = normalQuantile(u[i]);
  }
  if (!withinGamma({g[0], g[1], g[2]}) || !withinGamma({g[3], g[4]}) ||
      !withinGamma({g[5], g[6], g[7]})) {
    return false;
  }
  for (std::size_t i = 0; i < 3; ++i) out.position[i] = static_cast<float>(g[i]);
  for (std::size_t i = 0; i < 2; ++i) out.normal[i] = static_cast<float>(g[3 + i]);
  for (std::size_t i = 0; i < 3; ++i) out.color[i] = static_cast<float>(g[5 + i]);
  return true;
}

}  // namespace

std::vector<GaussianSample> gaussianSamples(std::uint32_t count, SampleSequence sequence,
                                            std::uint64_t seed) {
  std::vector<GaussianSample> samples;
  samples.reserve(count);
  std::array<double, kDimensions> u{};
  GaussianSample sample{};
  if (sequence == SampleSequence::Sobol) {
    boost::random::sobol engine(kDimensions);  // 64-bit coordinates
    bool first = true;
    while (samples.size() < count) {
      bool origin = true;
      for (double& x : u) {
        const std::uint64_t v = engine();
        origin = origin && v == 0;
        x = static_cast<double>(v) * kTwoToMinus64;
      }
      if (first && origin) {  // the sequence's first point: every coordinate 0
        first = false;
        continue;
      }
      first = false;
      if (toSample(u, sample)) samples.push_back(sample);
    }
    return samples;
  }
  std::mt19937_64 rng(seed);
  while (samples.size() < count) {
    for (double& x : u) x = (static_cast<double>(rng() >> 11) + 0.5) * kTwoToMinus53;
    if (toSample(u, sample)) samples.push_back(sample);
  }
  return samples;
}

Splat generatePoint(const StatisticalNode& node, const GaussianSample& sample, float radius) {
  Splat out{};
  for (int i = 0; i < 3; ++i) {
    float p = node.mean[i];
    for (int k = 0; k < 3; ++k) p += node.axes[k][i] * (node.sigma[k] * sample.position[k]);
    out.position[i] = p;
  }
  const float a = node.sigmaNormal[0] * sample.normal[0];
  const float b = node.sigmaNormal[1] * sample.normal[1];
  const float theta = std::sqrt(a * a + b * b);
  const float c = std::cos(theta);
  const float s = theta > 0.0f ? std::sin(theta) / theta : 1.0f;
  for (int i = 0; i < 3; ++i) {
    out.normal[i] =
        node.normalFrame[2][i] * c + (node.normalFrame[0][i] * a + node.normalFrame[1][i] * b) * s;
  }
  for (int i = 0; i < 3; ++i) {
    float v = node.color[i];
    for (int k = 0; k < 3; ++k) v += node.colorAxes[k][i] * (node.sigmaColor[k] * sample.color[k]);
    v = std::clamp(v, 0.0f, 255.0f);
    out.color[i] = static_cast<std::uint8_t>(std::lround(v));
  }
  out.color[3] = 255;
  out.radius = radius;
  return out;
}

void randomFrame(std::mt19937& rng, float (&axes)[3][3]) {
  std::normal_distribution<float> g;
  glm::vec3 x(g(rng), g(rng), g(rng)), y(g(rng), g(rng), g(rng));
  x = glm::normalize(x);
  y = glm::normalize(y - glm::dot(x, y) * x);
  const glm::vec3 z = glm::cross(x, y);
  for (glm::length_t i = 0; i < 3; ++i) {
    const auto k = static_cast<std::size_t>(i);
    axes[0][k] = x[i];
    axes[1][k] = y[i];
    axes[2][k] = z[i];
  }
}

}  // namespace pointillist
