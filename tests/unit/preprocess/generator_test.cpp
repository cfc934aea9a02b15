// The procedural scenes: exact size, determinism, complete attributes, and
// (for the instancing stage) exact translated copies.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <map>
#include <set>
#include <unordered_map>
#include <unordered_set>

#include "common/errors.hpp"
#include "preprocess/generator.hpp"

using pointillist::Splat;
using namespace pointillist::preprocess;

namespace {

struct PositionKey {
  std::uint32_t bits[3];
  bool operator==(const PositionKey& o) const {
    return std::memcmp(bits, o.bits, sizeof bits) == 0;
  }
};
struct PositionHash {
  std::size_t operator()(const PositionKey& k) const {
    return (std::size_t{k.bits[0]} * 0x9E3779B1u) ^ (std::size_t{k.bits[1]} * 0x85EBCA77u) ^
           (std::size_t{k.bits[2]} * 0xC2B2AE3Du);
  }
};
PositionKey keyOf(const float p[3]) {
  PositionKey k{};
  std::memcpy(k.bits, p, sizeof k.bits);
  return k;
}

}  // namespace

TEST(Generator, NamesAndUsageErrors) {
  const auto names = generatorNames();
  EXPECT_NE(std::find(names.begin(), names.end(), "city"), names.end());
  EXPECT_THROW(generateScene("atlantis", 1000, 1), pointillist::UsageError);
  EXPECT_THROW(generateScene("city", 0, 1), pointillist::UsageError);
  for (const std::string& name : names) {
    const PointCloud cloud = generateScene(name, 5000, 2);
    EXPECT_EQ(cloud.splats.size(), 5000u) << name;
    EXPECT_NE(cloud.source.find(name), std::string::npos);
  }
}

TEST(Generator, CityCountAttributesAndDeterminism) {
  for (const std::size_t n : {1000u, 37777u, 250000u}) {
    const PointCloud cloud = generateScene("city", n, 42);
    EXPECT_EQ(cloud.splats.size(), n);  // exact, as asked
    EXPECT_TRUE(cloud.hasNormals && cloud.hasColors && cloud.hasRadii);
    for (const Splat& s : cloud.splats) {
      const double len = std::sqrt(static_cast<double>(
          s.normal[0] * s.normal[0] + s.normal[1] * s.normal[1] + s.normal[2] * s.normal[2]));
      ASSERT_NEAR(len, 1.0, 1e-5);
      ASSERT_GT(s.radius, 0.0f);
      ASSERT_TRUE(std::isfinite(s.radius));
      for (const float c : s.position) ASSERT_TRUE(std::isfinite(c));
      ASSERT_EQ(s.color[3], 255);
    }
  }
  const PointCloud a = generateScene("city", 60000, 7);
  const PointCloud b = generateScene("city", 60000, 7);
  const PointCloud c = generateScene("city", 60000, 8);
  ASSERT_EQ(a.splats.size(), b.splats.size());
  EXPECT_EQ(0, std::memcmp(a.splats.data(), b.splats.data(), a.splats.size() * sizeof(Splat)));
  EXPECT_NE(0, std::memcmp(a.splats.data(), c.splats.data(), a.splats.size() * sizeof(Splat)));
}

TEST(Generator, CityIsVaried) {
  const PointCloud cloud = generateScene("city", 200000, 1);
  float lo[3] = {1e30f, 1e30f, 1e30f}, hi[3] = {-1e30f, -1e30f, -1e30f};
  std::set<std::uint32_t> colours;
  std::set<float> radii;
  std::size_t downward = 0, steep = 0;
  for (const Splat& s : cloud.splats) {
    for (int k = 0; k < 3; ++k) {
      lo[k] = std::min(lo[k], s.position[k]);
      hi[k] = std::max(hi[k], s.position[k]);
    }
    colours.insert(std::uint32_t{s.color[0]} << 16 | std::uint32_t{s.color[1]} << 8 | s.color[2]);
    radii.insert(s.radius);
    downward += s.normal[2] < -0.5f ? 1u : 0u;        // undersides of domes, spheres, arches
    steep += std::abs(s.normal[2]) < 0.3f ? 1u : 0u;  // walls, columns
  }
  EXPECT_GT(hi[0] - lo[0], 350.0f);
  EXPECT_GT(hi[2] - lo[2], 30.0f);  // hills and the dome
  EXPECT_GT(colours.size(), 1000u);
  EXPECT_GT(radii.size(), 1000u);  // density varies over the terrain
  EXPECT_GT(downward, 1000u);
  EXPECT_GT(steep, 20000u);
}

TEST(Generator, CityContainsExactTranslatedCopies) {
  const PointCloud cloud = generateScene("city", 100000, 3);
  std::unordered_set<PositionKey, PositionHash> positions;
  for (const Splat& s : cloud.splats) positions.insert(keyOf(s.position));
  // Copies share normal, colour and radius bit for bit: group by those and
  // test the translation between two members of a group on every point.
  std::unordered_map<std::string, std::vector<std::size_t>> groups;
  for (std::size_t i = 0; i < cloud.splats.size(); ++i) {
    const Splat& s = cloud.splats[i];
    std::string key(reinterpret_cast<const char*>(s.normal), 12 + 4 + 4);
    groups[key].push_back(i);
  }
  std::size_t translations = 0;
  std::size_t bestMatched = 0;
  for (const auto& [key, members] : groups) {
    if (members.size() < 2 || translations >= 20 || bestMatched > 500) continue;
    const Splat& a = cloud.splats[members[0]];
    const Splat& b = cloud.splats[members[1]];
    const float t[3] = {b.position[0] - a.position[0], b.position[1] - a.position[1],
                        b.position[2] - a.position[2]};
    std::size_t matched = 0;
    for (const Splat& s : cloud.splats) {
      const float moved[3] = {s.position[0] + t[0], s.position[1] + t[1], s.position[2] + t[2]};
      matched += positions.count(keyOf(moved));
    }
    bestMatched = std::max(bestMatched, matched);
    ++translations;
  }
  EXPECT_GT(translations, 0u);
  // A house or tree copy is hundreds of points; the best translation moves a whole object.
  EXPECT_GT(bestMatched, 500u);
}

TEST(Generator, SphereAndTorusLieOnTheirSurfaces) {
  const PointCloud sphere = generateScene("sphere", 3000, 4);
  for (const Splat& s : sphere.splats) {
    const double r = std::sqrt(static_cast<double>(s.position[0] * s.position[0] +
                                                   s.position[1] * s.position[1] +
                                                   s.position[2] * s.position[2]));
    ASSERT_NEAR(r, 1.0, 1e-6);
    for (int k = 0; k < 3; ++k) ASSERT_NEAR(s.normal[k], s.position[k], 1e-6);
  }
  const PointCloud torus = generateScene("torus", 3000, 4);
  for (const Splat& s : torus.splats) {
    const double ring = static_cast<double>(std::hypot(s.position[0], s.position[1])) - 1.0;
    ASSERT_NEAR(std::hypot(ring, static_cast<double>(s.position[2])), 0.35, 1e-6);
  }
}
