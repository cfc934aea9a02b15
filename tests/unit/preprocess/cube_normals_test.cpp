// Normals and radii from cube moments (NormalMethod::Moments): the lattice,
// the cubes' blocks against brute force, and the normals' rules (outward,
// anchored sides, spacing radii) as the nearest-neighbour method keeps them.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <map>
#include <numbers>
#include <random>
#include <vector>

#include "common/geometry.hpp"
#include "preprocess/cube_normals.hpp"
#include "preprocess/generator.hpp"
#include "preprocess/normals.hpp"
#include "preprocess/octree_builder.hpp"
#include "preprocess/readers.hpp"

using pointillist::Splat;
using namespace pointillist::preprocess;

namespace {

PointCloud stripped(PointCloud cloud) {
  for (Splat& s : cloud.splats) {
    s.normal[0] = s.normal[1] = s.normal[2] = 0.0f;
    s.radius = 0.0f;
  }
  cloud.hasNormals = cloud.hasRadii = false;
  return cloud;
}

NormalOptions moments() {
  NormalOptions options;
  options.method = NormalMethod::Moments;
  return options;
}

double angleDegrees(const Splat& s, const std::array<double, 3>& direction) {
  const double len = std::sqrt(direction[0] * direction[0] + direction[1] * direction[1] +
                               direction[2] * direction[2]);
  double c = 0;
  for (std::size_t k = 0; k < 3; ++k) c += static_cast<double>(s.normal[k]) * direction[k] / len;
  return std::acos(std::clamp(c, -1.0, 1.0)) * 180.0 / std::numbers::pi;
}

std::array<std::int64_t, 3> cubeOf(const Splat& s, const CubeLattice& lattice) {
  std::array<std::int64_t, 3> q{};
  for (std::size_t a = 0; a < 3; ++a)
    q[a] = static_cast<std::int64_t>(
        std::floor((static_cast<double>(s.position[a]) - lattice.origin[a]) / lattice.side));
  return q;
}

CubeLattice latticeFor(const std::vector<Splat>& points) {
  const PointBounds bounds = pointBounds(points, 1);
  const OctreeCube cube = boundingCube(bounds.lo, bounds.hi);
  return chooseCubeLattice(points, cube.min, cube.size);
}

}  // namespace

// The side depends on the hash sample only: the same for the whole cloud and
// for its sample handed over alone (as out of core), in any order; and it
// puts a few points in each occupied cube of a surface.
TEST(CubeLattice, FromTheSampleAloneInAnyOrderWithAFewPointsACube) {
  std::vector<Splat> sphere = generateScene("sphere", 300000, 4).splats;
  const PointBounds bounds = pointBounds(sphere, 1);
  const OctreeCube cube = boundingCube(bounds.lo, bounds.hi);
  const CubeLattice whole = chooseCubeLattice(sphere, cube.min, cube.size);
  const std::uint64_t every = latticeSampleEvery(sphere.size());
  EXPECT_GT(every, 1u);
  std::vector<Splat> sample;
  for (const Splat& s : sphere)
    if (positionHash(s) % every == 0) sample.push_back(s);
  std::shuffle(sample.begin(), sample.end(), std::mt19937(7));
  const CubeLattice fromSample = chooseCubeLattice(sample, every, cube.min, cube.size);
  EXPECT_EQ(whole.side, fromSample.side);
  for (std::size_t a = 0; a < 3; ++a) EXPECT_EQ(whole.origin[a], cube.min[a]);

  std::map<std::array<std::int64_t, 3>, int> occupancy;
  for (const Splat& s : sphere) ++occupancy[cubeOf(s, whole)];
  const double mean = static_cast<double>(sphere.size()) / static_cast<double>(occupancy.size());
  EXPECT_GT(mean, 1.2);
  EXPECT_LT(mean, 4.0);
}

// Every point in exactly one cube, the one its position falls in; each
// cube's normal and radius those of the brute-force covariance of the points
// in the 27 cubes around it; neighbour lists name occupied adjacent cubes,
// faces before edges before corners.
TEST(CubeBlocks, BlocksEqualBruteForceAndListsNameAdjacentCubes) {
  std::vector<Splat> points = generateScene("torus", 20000, 3).splats;
  for (Splat& s : points) s.position[0] += 50.0f;  // away from the origin
  const CubeLattice lattice = latticeFor(points);
  const CubeBlocks blocks(points, lattice, 8, 2);
  std::map<std::array<std::int64_t, 3>, std::vector<std::uint32_t>> truth;
  for (std::uint32_t i = 0; i < points.size(); ++i) truth[cubeOf(points[i], lattice)].push_back(i);
  ASSERT_EQ(blocks.cubes(), truth.size());
  std::vector<int> seen(points.size(), 0);
  std::map<std::array<std::int64_t, 3>, std::size_t> indexOf;
  for (std::size_t c = 0; c < blocks.cubes(); ++c) {
    const auto own = blocks.pointsOf(c);
    ASSERT_FALSE(own.empty());
    const auto q = cubeOf(points[own[0]], lattice);
    for (const std::uint32_t i : own) {
      ++seen[i];
      EXPECT_EQ(cubeOf(points[i], lattice), q);
    }
    indexOf[q] = c;
  }
  EXPECT_TRUE(std::all_of(seen.begin(), seen.end(), [](int n) { return n == 1; }));

  std::size_t compared = 0;
  for (const auto& [q, c] : indexOf) {
    pointillist::CovarianceAccumulator acc;
    for (std::int64_t dx = -1; dx <= 1; ++dx)
      for (std::int64_t dy = -1; dy <= 1; ++dy)
        for (std::int64_t dz = -1; dz <= 1; ++dz) {
          const auto found = truth.find({q[0] + dx, q[1] + dy, q[2] + dz});
          if (found == truth.end()) continue;
          for (const std::uint32_t i : found->second)
            acc.add({points[i].position[0], points[i].position[1], points[i].position[2]});
        }
    const auto eigen = pointillist::smallestEigen3(acc.covariance());
    if (acc.count() < 10 || !(eigen.values[1] > 1e-3 * eigen.values[2])) continue;
    const auto& n = blocks.normal(c);
    double d = 0.0;
    for (std::size_t a = 0; a < 3; ++a) d += static_cast<double>(n[a]) * eigen.vector[a];
    d = std::abs(d);
    EXPECT_GT(d, std::cos(0.5 * std::numbers::pi / 180)) << c;
    const double area = 12.0 * std::sqrt(eigen.values[2] * eigen.values[1]);
    const double radius =
        std::sqrt(3.0 * area / (std::numbers::pi * static_cast<double>(acc.count())));
    EXPECT_NEAR(blocks.radius(c), radius, 1e-3 * radius) << c;
    ++compared;

    const auto list = blocks.neighbours().subspan(c * 8, 8);
    int lastDistance = 0;
    for (const std::uint32_t other : list) {
      if (other == c) continue;  // padding of a cube with no neighbour
      const auto r = cubeOf(points[blocks.pointsOf(other)[0]], lattice);
      int distance = 0;
      for (std::size_t a = 0; a < 3; ++a) {
        ASSERT_LE(std::abs(r[a] - q[a]), 1);
        distance += static_cast<int>(std::abs(r[a] - q[a]));
      }
      ASSERT_GT(distance, 0);
      EXPECT_GE(distance, lastDistance);
      lastDistance = distance;
    }
  }
  EXPECT_GT(compared, blocks.cubes() / 2);
}

TEST(CubeBlocks, ThreadCountDoesNotChangeAnything) {
  const std::vector<Splat> points = generateScene("city", 80000, 5).splats;
  const CubeLattice lattice = latticeFor(points);
  const CubeBlocks one(points, lattice, 8, 1), three(points, lattice, 8, 3);
  ASSERT_EQ(one.cubes(), three.cubes());
  for (std::size_t c = 0; c < one.cubes(); ++c) {
    ASSERT_EQ(one.normal(c), three.normal(c));
    ASSERT_EQ(one.radius(c), three.radius(c));
    ASSERT_TRUE(std::ranges::equal(one.pointsOf(c), three.pointsOf(c)));
  }
  EXPECT_TRUE(std::ranges::equal(one.neighbours(), three.neighbours()));

  PointCloud a = stripped(PointCloud{points, false, true, false, "city"});
  PointCloud b = a;
  NormalOptions single = moments(), many = moments();
  single.threads = 1;
  many.threads = 3;
  estimateNormalsAndRadii(a, single);
  estimateNormalsAndRadii(b, many);
  EXPECT_EQ(0, std::memcmp(a.splats.data(), b.splats.data(), a.splats.size() * sizeof(Splat)));
}

TEST(MomentNormals, SphereOutwardWithSpacingRadii) {
  PointCloud cloud = stripped(generateScene("sphere", 20000, 3));
  for (Splat& s : cloud.splats) {
    s.position[0] = s.position[0] * 5.0f + 100.0f;
    s.position[1] = s.position[1] * 5.0f - 40.0f;
    s.position[2] = s.position[2] * 5.0f + 7.0f;
  }
  std::uint64_t lastDone = 0, lastTotal = 0;
  NormalOptions options = moments();
  options.progress = [&](std::uint64_t done, std::uint64_t total) {
    EXPECT_GE(done, lastDone);
    lastDone = done;
    lastTotal = total;
  };
  estimateNormalsAndRadii(cloud, options);
  EXPECT_TRUE(cloud.hasNormals && cloud.hasRadii);
  EXPECT_EQ(lastDone, lastTotal);
  std::vector<double> angles;
  for (const Splat& s : cloud.splats) {
    const double a = angleDegrees(
        s, {static_cast<double>(s.position[0]) - 100.0, static_cast<double>(s.position[1]) + 40.0,
            static_cast<double>(s.position[2]) - 7.0});
    ASSERT_LT(a, 90.0) << "inward normal";
    angles.push_back(a);
  }
  std::sort(angles.begin(), angles.end());
  EXPECT_LT(angles[angles.size() * 99 / 100], 6.0);
  const double expected = std::sqrt(3 * 4 * std::numbers::pi * 25 / (std::numbers::pi * 20000));
  double mean = 0;
  for (const Splat& s : cloud.splats) mean += static_cast<double>(s.radius);
  mean /= 20000;
  EXPECT_NEAR(mean, expected, 0.2 * expected);
}

TEST(MomentNormals, GridPlaneNormalsExactRadiiFromTheSpacing) {
  PointCloud cloud;
  const float spacing = 0.5f;
  for (int i = 0; i < 80; ++i) {
    for (int j = 0; j < 80; ++j) {
      Splat s{};
      s.position[0] = static_cast<float>(i) * spacing;
      s.position[1] = static_cast<float>(j) * spacing;
      s.position[2] = 0.3f * s.position[0] + 2.0f;
      cloud.splats.push_back(s);
    }
  }
  estimateNormalsAndRadii(cloud, moments());
  // pi r^2 = 3 / density, the density per area of the tilted plane.
  const double area = static_cast<double>(spacing) * static_cast<double>(spacing) * std::sqrt(1.09);
  const double expected = std::sqrt(3.0 * area / std::numbers::pi);
  for (std::size_t idx = 0; idx < cloud.splats.size(); ++idx) {
    const Splat& s = cloud.splats[idx];
    EXPECT_LT(angleDegrees(s, {-0.3, 0, 1}), 0.05) << idx;
    const int i = static_cast<int>(idx / 80), j = static_cast<int>(idx % 80);
    if (i >= 8 && i < 72 && j >= 8 && j < 72) {
      EXPECT_NEAR(s.radius, expected, 0.15 * expected) << idx;
    }
  }
}

TEST(MomentNormals, TwoClosedShapesOutwardInAnyBlocks) {
  PointCloud shapes = stripped(generateScene("torus", 15000, 1));
  {
    PointCloud b = stripped(generateScene("sphere", 6000, 2));
    for (Splat& s : b.splats) s.position[0] += 4.0f;
    shapes.splats.insert(shapes.splats.end(), b.splats.begin(), b.splats.end());
  }
  for (const std::size_t block : {NormalOptions{}.orientBlockPoints, std::size_t{997}}) {
    PointCloud a = shapes;
    NormalOptions options = moments();
    options.orientBlockPoints = block;
    estimateNormalsAndRadii(a, options);
    std::size_t bad = 0;
    for (std::size_t i = 0; i < a.splats.size(); ++i) {
      const Splat& s = a.splats[i];
      std::array<double, 3> outward{};
      if (i < 15000) {
        const double x = s.position[0], y = s.position[1], r = std::hypot(x, y);
        outward = {x - x / r, y - y / r, s.position[2]};
      } else {
        outward = {static_cast<double>(s.position[0]) - 4.0, s.position[1], s.position[2]};
      }
      bad += angleDegrees(s, outward) > 20.0 ? 1u : 0u;
    }
    EXPECT_LT(bad, a.splats.size() / 100) << "blocks of " << block;
  }
}

TEST(MomentNormals, GivenNormalsAreAnchorsAndRecomputedOnesKeepTheirSide) {
  PointCloud cloud = stripped(generateScene("sphere", 8000, 9));
  for (Splat& s : cloud.splats) {
    if (s.position[2] > 0.3f) {
      for (int k = 0; k < 3; ++k) s.normal[k] = -s.position[k];  // inward
      s.radius = 0.25f;
    }
  }
  const PointCloud before = cloud;
  estimateNormalsAndRadii(cloud, moments());
  std::size_t inward = 0;
  for (std::size_t i = 0; i < cloud.splats.size(); ++i) {
    const Splat& s = cloud.splats[i];
    if (before.splats[i].radius > 0.0f) {
      EXPECT_EQ(s.radius, 0.25f);
      EXPECT_EQ(0, std::memcmp(s.normal, before.splats[i].normal, sizeof s.normal));
    } else {
      EXPECT_GT(s.radius, 0.0f);
    }
    inward += angleDegrees(s, {-s.position[0], -s.position[1], -s.position[2]}) < 30 ? 1u : 0u;
  }
  EXPECT_GT(inward, cloud.splats.size() * 98 / 100);

  NormalOptions all = moments();
  all.onlyWhereMissing = false;
  estimateNormalsAndRadii(cloud, all);
  for (const Splat& s : cloud.splats)
    EXPECT_LT(angleDegrees(s, {-s.position[0], -s.position[1], -s.position[2]}), 30);
}

TEST(MomentNormals, DuplicatesLinesAndTinyClouds) {
  PointCloud cloud;
  Splat s{};
  for (int i = 0; i < 20; ++i) cloud.splats.push_back(s);  // all identical
  for (int i = 1; i < 6; ++i) {                            // and a line
    s.position[0] = static_cast<float>(i);
    cloud.splats.push_back(s);
  }
  estimateNormalsAndRadii(cloud, moments());
  for (const Splat& p : cloud.splats) {
    EXPECT_TRUE(std::isfinite(p.radius));
    EXPECT_GT(p.radius, 0.0f);
    const double len = std::sqrt(static_cast<double>(
        p.normal[0] * p.normal[0] + p.normal[1] * p.normal[1] + p.normal[2] * p.normal[2]));
    EXPECT_NEAR(len, 1.0, 1e-5);
  }
  PointCloud two;
  two.splats.resize(2);
  two.splats[1].position[1] = 1.0f;
  estimateNormalsAndRadii(two, moments());
  for (const Splat& p : two.splats) EXPECT_GT(p.radius, 0.0f);
}

// Real data with known normals: a sampled mesh and CGAL's kitten scan, as
// the nearest-neighbour method is held to, but for 90 % (not 95 %) within
// 15 degrees: 20,000 points on the bunny is a sparse sampling of its curves,
// and a block of cubes spans more of them than 12 neighbours do (the reason
// auto keeps knn below kMomentNormalsFromPoints).
TEST(MomentNormals, RealMeshAndScanAgreeWithKnownNormals) {
  const std::filesystem::path data = std::filesystem::path(POINTILLIST_TEST_DATA_DIR) / "data";
  if (!std::filesystem::exists(data)) {
    GTEST_SKIP() << "test data missing at " << data << "; run `bash deploy/fetch-test-data.sh`";
  }
  ReadOptions read;
  read.meshSamplePoints = 20000;
  for (const auto& file : {data / "meshes" / "bunny00.off", data / "points_3" / "kitten.xyz"}) {
    SCOPED_TRACE(file.string());
    const PointCloud truth = readPointCloud(file, read);
    ASSERT_TRUE(truth.hasNormals);
    PointCloud cloud = stripped(truth);
    estimateNormalsAndRadii(cloud, moments());
    std::size_t flipped = 0, close = 0;
    for (std::size_t i = 0; i < cloud.splats.size(); ++i) {
      double d = 0;
      for (std::size_t k = 0; k < 3; ++k) {
        d += static_cast<double>(cloud.splats[i].normal[k]) *
             static_cast<double>(truth.splats[i].normal[k]);
      }
      flipped += d < 0 ? 1u : 0u;
      close += d > std::cos(15 * std::numbers::pi / 180) ? 1u : 0u;
    }
    EXPECT_LT(flipped, cloud.splats.size() / 200);
    EXPECT_GT(close, cloud.splats.size() * 90 / 100);
  }
}

TEST(MomentNormals, AutoTakesMomentsForLargeClouds) {
  EXPECT_EQ(resolveNormalMethod(NormalMethod::Auto, kMomentNormalsFromPoints),
            NormalMethod::Moments);
  EXPECT_EQ(resolveNormalMethod(NormalMethod::Auto, kMomentNormalsFromPoints - 1),
            NormalMethod::Neighbours);
  EXPECT_EQ(resolveNormalMethod(NormalMethod::Neighbours, 1u << 30), NormalMethod::Neighbours);
  EXPECT_EQ(resolveNormalMethod(NormalMethod::Moments, 10), NormalMethod::Moments);
}
