// The grid's k nearest neighbours are exactly the brute-force ones (distance,
// then index) on surfaces, volumes, stacks of equal points, far outliers and
// clouds smaller than k; and normals from the grid equal those from the
// kd-tree.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <random>
#include <set>
#include <vector>

#include "preprocess/generator.hpp"
#include "preprocess/neighbour_filter.hpp"
#include "preprocess/neighbour_grid.hpp"
#include "preprocess/normals.hpp"
#include "preprocess/octree_builder.hpp"
#include "preprocess/simd_targets.hpp"

using pointillist::Splat;
using namespace pointillist::preprocess;

namespace {

std::vector<std::pair<float, std::uint32_t>> bruteForce(const std::vector<Splat>& pts,
                                                        std::size_t i, std::size_t k) {
  std::vector<std::pair<float, std::uint32_t>> all;
  for (std::size_t j = 0; j < pts.size(); ++j) {
    if (j == i) continue;
    const float dx = pts[j].position[0] - pts[i].position[0];
    const float dy = pts[j].position[1] - pts[i].position[1];
    const float dz = pts[j].position[2] - pts[i].position[2];
    all.push_back({dx * dx + dy * dy + dz * dz, static_cast<std::uint32_t>(j)});
  }
  std::sort(all.begin(), all.end());
  all.resize(std::min(k, all.size()));
  return all;
}

void expectExact(const std::vector<Splat>& pts, std::size_t k, std::size_t every = 1) {
  const NeighbourGrid grid(pts);
  std::vector<std::uint32_t> index(k);
  std::vector<float> d2(k);
  for (std::size_t i = 0; i < pts.size(); i += every) {
    const std::size_t m = grid.nearest(i, k, index.data(), d2.data());
    const auto want = bruteForce(pts, i, k);
    ASSERT_EQ(m, want.size()) << "point " << i;
    for (std::size_t j = 0; j < m; ++j) {
      ASSERT_EQ(index[j], want[j].second) << "point " << i << " neighbour " << j;
      ASSERT_EQ(d2[j], want[j].first);
    }
  }
}

// The same through nearestInCube, the batched search the normals use: every
// point is reported once, with the brute-force neighbours.
void expectExactInCubes(const std::vector<Splat>& pts, std::size_t k) {
  const NeighbourGrid grid(pts);
  std::vector<int> seen(pts.size(), 0);
  for (std::size_t cube = 0; cube < grid.occupiedCubes(); ++cube) {
    grid.nearestInCube(
        cube, k, [&](std::size_t i, const std::uint32_t* index, const float* d2, std::size_t m) {
          ++seen[i];
          const auto want = bruteForce(pts, i, k);
          ASSERT_EQ(m, want.size()) << "point " << i;
          for (std::size_t j = 0; j < m; ++j) {
            ASSERT_EQ(index[j], want[j].second) << "point " << i << " neighbour " << j;
            ASSERT_EQ(d2[j], want[j].first);
          }
        });
  }
  for (std::size_t i = 0; i < pts.size(); ++i) ASSERT_EQ(seen[i], 1) << "point " << i;
}

Splat at(float x, float y, float z) {
  Splat s{};
  s.position[0] = x;
  s.position[1] = y;
  s.position[2] = z;
  return s;
}

}  // namespace

TEST(NeighbourGrid, SurfacePointsMatchBruteForce) {
  auto pts = generateScene("city", 6000, 4).splats;
  expectExact(pts, 12, 3);
  // Shuffled: the grid sorts what is not in Morton order.
  std::shuffle(pts.begin(), pts.end(), std::mt19937(2));
  expectExact(pts, 12, 7);
  expectExactInCubes(pts, 12);
}

// A preprocess hands the points over sorted down to its octree's leaves and
// in any order inside them: the grid then sorts only runs that share a
// leaf's code, and must find what it finds for a cloud in full order.
TEST(NeighbourGrid, PointsSortedDownToLeavesMatchBruteForce) {
  auto pts = generateScene("city", 6000, 5).splats;
  const PointBounds bounds = pointBounds(pts, 1);
  const MortonCoder morton(boundingCube(bounds.lo, bounds.hi), 16);
  std::shuffle(pts.begin(), pts.end(), std::mt19937(3));
  for (const unsigned levels : {8u, 4u}) {  // runs sorted apart, and the whole sorted
    std::stable_sort(pts.begin(), pts.end(), [&](const Splat& a, const Splat& b) {
      return morton(a.position) >> (3 * (16 - levels)) < morton(b.position) >> (3 * (16 - levels));
    });
    expectExact(pts, 12, 5);
    expectExactInCubes(pts, 12);
  }
}

TEST(NeighbourGrid, VolumeStacksOutliersAndTinyClouds) {
  std::mt19937 rng(9);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  std::vector<Splat> volume;
  for (int i = 0; i < 3000; ++i) volume.push_back(at(u(rng), u(rng), u(rng)));
  // Stacks of equal points: ties broken by index.
  for (int i = 0; i < 60; ++i) volume.push_back(at(0.25f, 0.25f, 0.25f));
  // Far outliers, alone in their corner of the grid.
  volume.push_back(at(500.0f, 500.0f, 500.0f));
  volume.push_back(at(-300.0f, 480.0f, 2.0f));
  expectExact(volume, 12);
  expectExact(volume, 40, 5);
  expectExactInCubes(volume, 12);
  expectExactInCubes(volume, 40);

  expectExact({at(0, 0, 0)}, 12);
  expectExact({at(0, 0, 0), at(1, 0, 0), at(0, 2, 0)}, 12);
  expectExact(std::vector<Splat>(20, at(3, 3, 3)), 8);
  expectExactInCubes({at(0, 0, 0)}, 12);
  expectExactInCubes({at(0, 0, 0), at(1, 0, 0), at(0, 2, 0)}, 12);
  expectExactInCubes(std::vector<Splat>(20, at(3, 3, 3)), 8);
}

TEST(NeighbourGrid, NormalsEqualTheKdTrees) {
  PointCloud a;
  a.splats = generateScene("sphere", 8000, 3).splats;
  for (Splat& s : a.splats) s.normal[0] = s.normal[1] = s.normal[2] = 0.0f;
  for (Splat& s : a.splats) s.radius = 0.0f;
  PointCloud b = a;
  NormalOptions grid, kd;
  kd.search = NeighbourSearch::KdTree;
  estimateNormalsAndRadii(a, grid);
  estimateNormalsAndRadii(b, kd);
  std::size_t differ = 0;
  for (std::size_t i = 0; i < a.splats.size(); ++i)
    differ += std::memcmp(&a.splats[i], &b.splats[i], sizeof(Splat)) != 0;
  // Equal but for points whose k-th neighbour ties another one.
  EXPECT_LE(differ, a.splats.size() / 1000) << differ << " of " << a.splats.size();
}

// The SIMD filter keeps exactly the candidates the scalar test keeps, in
// order, with the scalar code's distances bit for bit: every length up to
// three vectors of the widest target (tails included), NaN positions, and
// bounds from none to all.
TEST(NeighbourGrid, FilterKeepsWhatTheScalarTestKeeps) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(-2.0f, 2.0f);
  const float p[3] = {0.3f, -0.7f, 1.1f};
  for (std::size_t n = 0; n <= 50; ++n) {
    std::vector<float> x(n), y(n), z(n);
    std::vector<std::uint32_t> id(n);
    for (std::size_t i = 0; i < n; ++i) {
      x[i] = u(rng);
      y[i] = i % 7 == 3 ? std::numeric_limits<float>::quiet_NaN() : u(rng);
      z[i] = u(rng);
      id[i] = static_cast<std::uint32_t>(1000 + 3 * i);
    }
    for (const float bound : {-1.0f, 0.0f, 1.5f, 4.0f, std::numeric_limits<float>::infinity()}) {
      std::vector<float> d(n);
      std::vector<std::uint32_t> kept(n);
      const std::size_t m = candidatesWithin(x.data(), y.data(), z.data(), id.data(), n, p, bound,
                                             d.data(), kept.data());
      std::size_t j = 0;
      for (std::size_t i = 0; i < n; ++i) {
        const float dx = x[i] - p[0], dy = y[i] - p[1], dz = z[i] - p[2];
        const float want = dx * dx + dy * dy + dz * dz;
        if (!(want <= bound)) continue;
        ASSERT_LT(j, m) << "n " << n << " bound " << bound;
        EXPECT_EQ(kept[j], id[i]);
        EXPECT_EQ(std::memcmp(&d[j], &want, sizeof want), 0) << "candidate " << i;
        ++j;
      }
      EXPECT_EQ(m, j) << "n " << n << " bound " << bound;
    }
  }
}

// Sorting by counting the keys below each, on every SIMD target: every
// length up to eight vectors of the widest target, keys up to the largest
// but one, and the room past n is all it writes outside `sorted`.
TEST(NeighbourGrid, KeysSortByCountingEqualsStdSort) {
  std::mt19937_64 rng(11);
  for (std::size_t n = 0; n <= 64; ++n) {
    std::set<std::uint64_t> distinct;
    // Every fifth key near the top, where the padding's largest key sits.
    while (distinct.size() < n)
      distinct.insert(distinct.size() % 5 == 4 ? ~std::uint64_t{0} - 1 - distinct.size() : rng());
    std::vector<std::uint64_t> want(distinct.begin(), distinct.end());
    std::shuffle(want.begin(), want.end(), rng);
    std::vector<std::uint64_t> ascending = want;
    std::sort(ascending.begin(), ascending.end());
    for (const std::int64_t target : simdTargets()) {
      forceSimdTarget(target);
      std::vector<std::uint64_t> keys(n + kSortKeysPad + 4, 7);
      std::copy(want.begin(), want.end(), keys.begin());
      std::vector<std::uint64_t> sorted(n + 1, 5);
      sortDistinctKeys(keys.data(), n, sorted.data());
      EXPECT_TRUE(std::equal(ascending.begin(), ascending.end(), sorted.begin()))
          << "n " << n << " target " << target;
      EXPECT_EQ(sorted[n], 5u) << "n " << n << " target " << target;
      for (std::size_t j = n + kSortKeysPad; j < keys.size(); ++j)
        EXPECT_EQ(keys[j], 7u) << "n " << n << " target " << target;
    }
    forceSimdTarget(0);
  }
}
