// Cube moments (NormalMethod::Moments): the lattice and the cubes' blocks
// against brute force. The normals' rules (outward, anchored sides, thread
// counts, real data) are normals_test.cpp's, run for both methods.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <map>
#include <numbers>
#include <random>
#include <vector>

#include "common/geometry.hpp"
#include "preprocess/cube_normals.hpp"
#include "preprocess/generator.hpp"
#include "preprocess/normals.hpp"
#include "preprocess/octree_builder.hpp"

using pointillist::Splat;
using namespace pointillist::preprocess;

namespace {

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
    const auto& n = blocks.blockNormal(c);
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

// A fold (two planes meeting at a right angle): cubes beside the edge take
// the normal of the face their points lie on from the flattest 2x2x2 block,
// where the 3x3x3 block's normal blends both faces.
TEST(CubeBlocks, CubesBesideAnEdgeTakeTheirOwnFace) {
  std::vector<Splat> points;
  const float spacing = 0.01f;
  for (int i = 0; i < 200; ++i)
    for (int j = 0; j < 100; ++j) {
      Splat floor{}, wall{};
      floor.position[0] = static_cast<float>(i) * spacing;
      floor.position[1] = static_cast<float>(j) * spacing + 0.003f;  // y > 0: the floor
      wall.position[0] = static_cast<float>(i) * spacing;
      wall.position[2] = static_cast<float>(j) * spacing + 0.003f;  // z > 0: the wall
      points.push_back(floor);
      points.push_back(wall);
    }
  const CubeLattice lattice = latticeFor(points);
  const CubeBlocks blocks(points, lattice, 6, 2);
  std::size_t nearEdge = 0, ownFace = 0, blendedOwnFace = 0;
  for (std::size_t c = 0; c < blocks.cubes(); ++c) {
    const auto own = blocks.pointsOf(c);
    const bool onFloor = points[own[0]].position[2] == 0.0f;
    bool oneFace = true;
    for (const std::uint32_t i : own)
      oneFace = oneFace && (points[i].position[2] == 0.0f) == onFloor;
    const float distance = onFloor ? points[own[0]].position[1] : points[own[0]].position[2];
    if (!oneFace || distance > 1.5f * static_cast<float>(lattice.side)) continue;
    ++nearEdge;
    const std::size_t axis = onFloor ? 2 : 1;  // the face's normal
    const double within = std::cos(10 * std::numbers::pi / 180);
    ownFace += std::abs(static_cast<double>(blocks.normal(c)[axis])) > within ? 1u : 0u;
    blendedOwnFace += std::abs(static_cast<double>(blocks.blockNormal(c)[axis])) > within ? 1u : 0u;
  }
  ASSERT_GT(nearEdge, 200u);
  EXPECT_GT(ownFace, nearEdge * 9 / 10);
  EXPECT_LT(blendedOwnFace, nearEdge / 2);
}

TEST(CubeBlocks, ThreadCountDoesNotChangeAnything) {
  const std::vector<Splat> points = generateScene("city", 80000, 5).splats;
  const CubeLattice lattice = latticeFor(points);
  const CubeBlocks one(points, lattice, 8, 1), three(points, lattice, 8, 3);
  ASSERT_EQ(one.cubes(), three.cubes());
  for (std::size_t c = 0; c < one.cubes(); ++c) {
    ASSERT_EQ(one.normal(c), three.normal(c));
    ASSERT_EQ(one.blockNormal(c), three.blockNormal(c));
    ASSERT_EQ(one.radius(c), three.radius(c));
    ASSERT_TRUE(std::ranges::equal(one.pointsOf(c), three.pointsOf(c)));
  }
  EXPECT_TRUE(std::ranges::equal(one.neighbours(), three.neighbours()));
}

TEST(MomentNormals, AutoTakesMomentsForLargeClouds) {
  EXPECT_EQ(resolveNormalMethod(NormalMethod::Auto, kMomentNormalsFromPoints),
            NormalMethod::Moments);
  EXPECT_EQ(resolveNormalMethod(NormalMethod::Auto, kMomentNormalsFromPoints - 1),
            NormalMethod::Neighbours);
  EXPECT_EQ(resolveNormalMethod(NormalMethod::Neighbours, 1u << 30), NormalMethod::Neighbours);
  EXPECT_EQ(resolveNormalMethod(NormalMethod::Moments, 10), NormalMethod::Moments);
}
