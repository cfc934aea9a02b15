// Level-splats (seed 003 §4.1.2) and the covariance tools under them.
#include "preprocess/level_splats.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <mutex>
#include <random>
#include <set>
#include <vector>

#include "common/errors.hpp"
#include "common/geometry.hpp"
#include "preprocess/octree_builder.hpp"

namespace pointillist::preprocess {
namespace {

double distance(const Splat& a, const Splat& b) {
  double s = 0.0;
  for (int k = 0; k < 3; ++k) {
    const double d = static_cast<double>(a.position[k]) - static_cast<double>(b.position[k]);
    s += d * d;
  }
  return std::sqrt(s);
}

// A wavy patch z = 0.05 sin(3x) over [0,1]^2 with normals close to +z.
std::vector<Splat> patch(std::size_t n, std::uint32_t seed, float z0 = 0.0f) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  std::vector<Splat> out(n);
  for (auto& s : out) {
    s = Splat{};
    s.position[0] = u(rng);
    s.position[1] = u(rng);
    s.position[2] = z0 + 0.05f * std::sin(3.0f * s.position[0]);
    const float slope = 0.15f * std::cos(3.0f * s.position[0]);
    const float len = std::sqrt(1.0f + slope * slope);
    s.normal[0] = -slope / len;
    s.normal[2] = 1.0f / len;
    s.radius = 0.5f / std::sqrt(static_cast<float>(n));
    s.color[0] = 100;
    s.color[1] = 150;
    s.color[2] = 200;
    s.color[3] = 255;
  }
  return out;
}

TEST(LevelSplats, TargetIsAQuarterWithinLimits) {
  LevelSplatOptions o;
  EXPECT_EQ(levelSplatTarget(0, o), 0u);
  EXPECT_EQ(levelSplatTarget(1, o), 1u);
  EXPECT_EQ(levelSplatTarget(4, o), 1u);
  EXPECT_EQ(levelSplatTarget(5, o), 2u);
  EXPECT_EQ(levelSplatTarget(128, o), 32u);
  EXPECT_EQ(levelSplatTarget(100000, o), 256u);
}

TEST(LevelSplats, EveryReplacedCentreLiesWithinItsLevelSplat) {
  const LevelSplatOptions o;
  for (std::uint32_t seed = 1; seed <= 10; ++seed) {
    const auto in = patch(100 + 37 * seed, seed);
    const std::size_t target = levelSplatTarget(in.size(), o);
    const Clustering c = clusterSplats(in, target, o);
    ASSERT_GE(c.splats.size(), 1u);
    ASSERT_LE(c.splats.size(), target);
    EXPECT_GE(c.splats.size() * 10, target * 9) << "refinement should not collapse clusters";
    ASSERT_EQ(c.assignment.size(), in.size());
    std::vector<int> used(c.splats.size(), 0);
    for (std::size_t i = 0; i < in.size(); ++i) {
      ASSERT_LT(c.assignment[i], c.splats.size());
      const Splat& out = c.splats[c.assignment[i]];
      ++used[c.assignment[i]];
      EXPECT_LE(distance(in[i], out), static_cast<double>(out.radius))
          << "seed " << seed << " input " << i;
      // Default share 1: the replaced splat's whole sphere is inside (no holes).
      EXPECT_LE(distance(in[i], out) + static_cast<double>(in[i].radius),
                static_cast<double>(out.radius));
      EXPECT_GE(out.radius, in[i].radius);
    }
    EXPECT_TRUE(std::all_of(used.begin(), used.end(), [](int n) { return n > 0; }));
    for (const Splat& s : c.splats) {
      // Flat-ish patch: normals near +z and oriented like the inputs; colour kept.
      EXPECT_GT(s.normal[2], 0.9f) << "seed " << seed;
      EXPECT_NEAR(std::sqrt(s.normal[0] * s.normal[0] + s.normal[1] * s.normal[1] +
                            s.normal[2] * s.normal[2]),
                  1.0f, 1e-5f);
      EXPECT_EQ(s.color[1], 150);
    }
  }
}

TEST(LevelSplats, CentroidAndColourAverage) {
  std::vector<Splat> in(2);
  for (int i = 0; i < 2; ++i) {
    in[static_cast<std::size_t>(i)] = Splat{};
    in[static_cast<std::size_t>(i)].position[0] = static_cast<float>(i * 2);
    in[static_cast<std::size_t>(i)].normal[1] = 1.0f;
    in[static_cast<std::size_t>(i)].radius = 0.5f;
    in[static_cast<std::size_t>(i)].color[0] = static_cast<std::uint8_t>(i * 100);
  }
  const Clustering c = clusterSplats(in, 1, LevelSplatOptions{});
  ASSERT_EQ(c.splats.size(), 1u);
  EXPECT_FLOAT_EQ(c.splats[0].position[0], 1.0f);
  EXPECT_EQ(c.splats[0].color[0], 50);
  EXPECT_FLOAT_EQ(c.splats[0].normal[1], 1.0f);  // too few inputs for a plane: mean normal
  EXPECT_FLOAT_EQ(c.splats[0].radius, 1.5f);     // distance 1 + the input's radius 0.5
}

TEST(LevelSplats, IdenticalInputsGiveOneSplat) {
  std::vector<Splat> in(50, patch(1, 1)[0]);
  const Clustering c = clusterSplats(in, 12, LevelSplatOptions{});
  ASSERT_EQ(c.splats.size(), 1u);
  EXPECT_EQ(c.splats[0].radius, in[0].radius);
}

TEST(LevelSplats, UnknownNormalsStayUnknown) {
  auto in = patch(64, 2);
  for (auto& s : in) s.normal[0] = s.normal[1] = s.normal[2] = 0.0f;
  for (const Splat& s : clusterSplats(in, 16, LevelSplatOptions{}).splats)
    EXPECT_EQ(s.normal[0] * s.normal[0] + s.normal[1] * s.normal[1] + s.normal[2] * s.normal[2],
              0.0f);
}

TEST(LevelSplats, ClustersDoNotMixCloseParallelSheets) {
  // Two sheets 0.1 apart, each with ~0.035 point spacing: the Mahalanobis
  // assignment keeps clusters on one sheet.
  auto a = patch(800, 5, 0.0f);
  const auto b = patch(800, 6, 0.1f);
  for (auto& s : a) s.position[2] = 0.0f;
  std::vector<Splat> in = a;
  for (auto s : b) {
    s.position[2] = 0.1f;
    in.push_back(s);
  }
  const Clustering c = clusterSplats(in, 400, LevelSplatOptions{});
  std::vector<std::set<int>> sheets(c.splats.size());
  for (std::size_t i = 0; i < in.size(); ++i) sheets[c.assignment[i]].insert(i < a.size() ? 0 : 1);
  std::size_t mixed = 0;
  for (const auto& s : sheets) mixed += s.size() > 1 ? 1u : 0u;
  EXPECT_EQ(mixed, 0u);
}

TEST(LevelSplats, EveryCellCoversItsLevelBelow) {
  std::vector<Splat> pts;
  for (std::uint32_t s = 0; s < 4; ++s) {
    auto p = patch(1500, 10 + s, 0.3f * static_cast<float>(s));
    pts.insert(pts.end(), p.begin(), p.end());
  }
  OctreeOptions oo;
  oo.maxDepth = 8;
  oo.leafPoints = 24;
  Octree tree = buildOctree(pts, oo);
  assignTopLevelCells(tree, 2);
  const LevelSplatOptions o;
  const LevelSplats ls = buildLevelSplats(tree, o, {}, 2);
  const auto& cells = tree.cells;
  std::size_t leafSplats = 0, points = 0;
  for (std::uint32_t i = 0; i < cells.size(); ++i) {
    const BuildCell& c = cells[i];
    if (c.topLevel == kNoIndex) {
      EXPECT_EQ(ls.cellCount[i], 0u);
      continue;
    }
    std::vector<Splat> inputs;
    if (c.isLeaf()) {
      inputs.assign(tree.points.begin() + static_cast<std::ptrdiff_t>(c.begin),
                    tree.points.begin() + static_cast<std::ptrdiff_t>(c.end));
      leafSplats += ls.cellCount[i];
      points += inputs.size();
    } else {
      for (std::uint32_t j = i + 1; j < cells.size() && cells[j].parent == i;) {
        inputs.insert(
            inputs.end(), ls.splats.begin() + static_cast<std::ptrdiff_t>(ls.cellBegin[j]),
            ls.splats.begin() + static_cast<std::ptrdiff_t>(ls.cellBegin[j] + ls.cellCount[j]));
        if (cells[j].nextSibling == kNoIndex) break;
        j = cells[j].nextSibling;
      }
    }
    const std::size_t n = ls.cellCount[i];
    ASSERT_GE(n, 1u);
    ASSERT_LE(n, levelSplatTarget(inputs.size(), o));
    const Splat* own = ls.splats.data() + ls.cellBegin[i];
    for (const Splat& in : inputs) {
      bool covered = false;
      for (std::size_t k = 0; k < n && !covered; ++k)
        covered = distance(in, own[k]) <= static_cast<double>(own[k].radius);
      ASSERT_TRUE(covered) << "cell " << i;
    }
  }
  // Level 1 is about a quarter of the points (ceil per leaf adds a little).
  EXPECT_GE(leafSplats * 4, points);
  EXPECT_LE(leafSplats * 3, points);
  // Each top-level cell's level-splats are laid out as its packet: by level
  // from the highest down, cells of one level in depth-first order, each
  // cell's contiguous, the group ending where the next begins.
  ASSERT_EQ(ls.topLevelBegin.size(), tree.topLevelCells.size() + 1);
  for (std::size_t k = 0; k < tree.topLevelCells.size(); ++k) {
    const std::uint32_t root = tree.topLevelCells[k];
    const std::uint32_t end = cells[root].nextSibling == kNoIndex
                                  ? static_cast<std::uint32_t>(cells.size())
                                  : cells[root].nextSibling;
    std::uint64_t at = ls.topLevelBegin[k];
    for (int level = cells[root].level; level >= 1; --level)
      for (std::uint32_t i = root; i < end; ++i)
        if (cells[i].level == level) {
          EXPECT_EQ(ls.cellBegin[i], at) << "cell " << i;
          at += ls.cellCount[i];
        }
    EXPECT_EQ(at, ls.topLevelBegin[k + 1]) << "top-level cell " << k;
  }
}

TEST(LevelSplats, PacketsAreHandedOnInOrderAsTheyAreMade) {
  std::vector<Splat> pts;
  for (std::uint32_t s = 0; s < 4; ++s) {
    auto p = patch(1500, 20 + s, 0.3f * static_cast<float>(s));
    pts.insert(pts.end(), p.begin(), p.end());
  }
  OctreeOptions oo;
  oo.maxDepth = 8;
  oo.leafPoints = 24;
  Octree tree = buildOctree(pts, oo);
  assignTopLevelCells(tree, 3);
  ASSERT_GT(tree.topLevelCells.size(), 8u);
  std::vector<std::size_t> order;
  std::vector<std::vector<Splat>> handed;
  std::mutex mutex;
  std::vector<std::size_t> made;  // by the workers, in any order
  std::vector<std::vector<std::uint32_t>> madeBegin(tree.topLevelCells.size());
  LevelSplatHooks hooks;
  hooks.made = [&](const MadePacket& p) {
    std::lock_guard lock(mutex);
    made.push_back(p.k);
    madeBegin[p.k].assign(p.cellBegin.begin(), p.cellBegin.end());
  };
  hooks.handOn = [&](const MadePacket& p) {
    order.push_back(p.k);
    handed.emplace_back(p.levelSplats.begin(), p.levelSplats.end());
  };
  const LevelSplats ls = buildLevelSplats(tree, LevelSplatOptions{}, {}, 3, hooks);
  ASSERT_EQ(order.size(), tree.topLevelCells.size());
  std::sort(made.begin(), made.end());
  for (std::size_t k = 0; k < order.size(); ++k) {
    EXPECT_EQ(order[k], k);
    EXPECT_EQ(made[k], k);
    // The bytes handed on are the packet's level-splats, as the result holds
    // them, and each cell's begin is its own within them.
    ASSERT_EQ(handed[k].size(), ls.topLevelBegin[k + 1] - ls.topLevelBegin[k]);
    EXPECT_EQ(std::memcmp(handed[k].data(), ls.splats.data() + ls.topLevelBegin[k],
                          handed[k].size() * sizeof(Splat)),
              0);
    const std::uint32_t root = tree.topLevelCells[k];
    for (std::size_t j = 0; j < madeBegin[k].size(); ++j)
      EXPECT_EQ(madeBegin[k][j] + ls.topLevelBegin[k], ls.cellBegin[root + j]);
  }

  // Without keeping them, the same tables and no array of all level-splats.
  hooks.keepSplats = false;
  order.clear();
  made.clear();
  const LevelSplats dropped = buildLevelSplats(tree, LevelSplatOptions{}, {}, 2, hooks);
  EXPECT_TRUE(dropped.splats.empty());
  EXPECT_EQ(dropped.cellBegin, ls.cellBegin);
  EXPECT_EQ(dropped.cellCount, ls.cellCount);
  EXPECT_EQ(dropped.topLevelBegin, ls.topLevelBegin);
  EXPECT_EQ(order.size(), tree.topLevelCells.size());

  // A callback that throws (a full disk) stops the build with its error.
  LevelSplatHooks failing;
  failing.handOn = [](const MadePacket& p) {
    if (p.k == 2) throw InputError("disk full");
  };
  EXPECT_THROW(buildLevelSplats(tree, LevelSplatOptions{}, {}, 2, failing), InputError);
  failing = {};
  failing.made = [](const MadePacket& p) {
    if (p.k == 5) throw InputError("no room");
  };
  EXPECT_THROW(buildLevelSplats(tree, LevelSplatOptions{}, {}, 2, failing), InputError);
}

}  // namespace
}  // namespace pointillist::preprocess
