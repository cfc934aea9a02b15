// Octree (seed 003 §4.1.1): point-array order, depth-first cell array with
// sibling skips, levels, top-level cells and packets, cones and bounds.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <functional>
#include <limits>
#include <random>
#include <vector>

#include "common/dataset.hpp"
#include "common/errors.hpp"
#include "common/geometry.hpp"
#include "preprocess/dataset_builder.hpp"
#include "preprocess/level_splats.hpp"
#include "preprocess/octree_builder.hpp"

namespace pointillist::preprocess {
namespace {

// Points on a unit sphere (outward normals) plus a dense blob and a few far
// points, so the tree has deep, shallow and uneven branches.
std::vector<Splat> testCloud(std::size_t n, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<float> gauss(0.0f, 1.0f);
  std::uniform_int_distribution<int> byte(0, 255);
  std::vector<Splat> out;
  for (std::size_t i = 0; i < n; ++i) {
    float v[3] = {gauss(rng), gauss(rng), gauss(rng)};
    const float len = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    Splat s{};
    for (int a = 0; a < 3; ++a) {
      s.normal[a] = v[a] / len;
      s.position[a] = s.normal[a];
    }
    if (i % 7 == 0)  // blob near one pole: dense region
      for (int a = 0; a < 3; ++a) s.position[a] = 0.05f * s.normal[a] + (a == 2 ? 0.9f : 0.0f);
    s.radius = 0.02f;
    s.color[0] = static_cast<std::uint8_t>(byte(rng));
    s.color[1] = static_cast<std::uint8_t>(byte(rng));
    s.color[2] = 200;
    s.color[3] = 255;
    out.push_back(s);
  }
  Splat far{};
  far.position[0] = 3.0f;
  far.position[1] = 3.0f;
  far.position[2] = 3.0f;
  far.normal[0] = 1.0f;
  far.radius = 0.1f;
  out.push_back(far);
  return out;
}

PreprocessOptions smallOptions() {
  PreprocessOptions o;
  o.octree.maxDepth = 10;
  o.octree.leafPoints = 16;
  o.topLevelDepth = 3;
  o.threads = 2;
  return o;
}

struct Built {
  std::vector<Splat> input;
  Octree tree;  // before assembly (points sorted, build cells)
  DatasetContent content;
};

Built build(std::size_t n, const PreprocessOptions& o, std::uint32_t seed = 1) {
  Built b;
  b.input = testCloud(n, seed);
  b.tree = buildOctree(b.input, o.octree);
  assignTopLevelCells(b.tree, static_cast<unsigned>(o.topLevelDepth));
  LevelSplats ls = buildLevelSplats(b.tree, o.levelSplats, {}, o.threads);
  b.content = assembleDatasetContent(b.tree, std::move(ls), o);
  finalizeDatasetContent(b.content);
  return b;
}

std::vector<std::vector<std::uint32_t>> childLists(const Octree& t) {
  std::vector<std::vector<std::uint32_t>> children(t.cells.size());
  for (std::uint32_t i = 1; i < t.cells.size(); ++i) children[t.cells[i].parent].push_back(i);
  return children;
}

bool sameBytes(const Splat& a, const Splat& b) {
  return std::memcmp(&a, &b, sizeof(Splat)) == 0;
}
bool lessBytes(const Splat& a, const Splat& b) {
  return std::memcmp(&a, &b, sizeof(Splat)) < 0;
}

// All splats of cell i's subtree, via the cell array and packets only.
std::vector<Splat> subtreeSplats(const DatasetContent& c, std::uint32_t i) {
  std::vector<std::uint64_t> pointBase(c.topLevel.size()), splatBase(c.topLevel.size());
  std::uint64_t p = 0, s = 0;
  for (std::size_t k = 0; k < c.topLevel.size(); ++k) {
    pointBase[k] = p;
    splatBase[k] = s;
    p += c.topLevel[k].pointCount;
    s += c.topLevel[k].levelSplatCount;
  }
  std::vector<Splat> out;
  const std::uint32_t end = c.cells[i].nextSibling == kNoIndex
                                ? static_cast<std::uint32_t>(c.cells.size())
                                : c.cells[i].nextSibling;
  for (std::uint32_t j = i; j < end; ++j) {
    const OctreeCell& cell = c.cells[j];
    if (cell.topLevel == kNoIndex) continue;
    // Layered packets: the level-splats come first, then the points.
    const std::uint64_t L = c.topLevel[cell.topLevel].levelSplatCount;
    if (cell.isLeaf())
      for (std::uint32_t q = 0; q < cell.pointsCount; ++q)
        out.push_back(c.points[pointBase[cell.topLevel] + cell.pointsOffset - L + q]);
    for (std::uint32_t q = 0; q < cell.splatsCount; ++q)
      out.push_back(c.levelSplats[splatBase[cell.topLevel] + cell.splatsOffset + q]);
  }
  return out;
}

TEST(Octree, EveryPointInExactlyOneLeaf) {
  const Built b = build(6000, smallOptions());
  const Octree& t = b.tree;
  // The point-array is a permutation of the input.
  auto sortedIn = b.input, sortedOut = t.points;
  std::sort(sortedIn.begin(), sortedIn.end(), lessBytes);
  std::sort(sortedOut.begin(), sortedOut.end(), lessBytes);
  ASSERT_EQ(sortedIn.size(), sortedOut.size());
  EXPECT_TRUE(std::equal(sortedIn.begin(), sortedIn.end(), sortedOut.begin(), sameBytes));
  // Leaves, depth-first, tile [0, N) exactly; each holds its points in its bounds.
  std::uint64_t next = 0;
  std::size_t leaves = 0;
  for (const BuildCell& c : t.cells) {
    if (!c.isLeaf()) continue;
    ++leaves;
    EXPECT_EQ(c.begin, next);
    EXPECT_GT(c.end, c.begin);
    EXPECT_TRUE(c.end - c.begin <= 16 || c.depth == 10);
    for (std::uint64_t i = c.begin; i < c.end; ++i)
      for (int a = 0; a < 3; ++a) {
        EXPECT_GE(t.points[i].position[a], c.boundsMin[a]);
        EXPECT_LE(t.points[i].position[a], c.boundsMax[a]);
      }
    next = c.end;
  }
  EXPECT_EQ(next, t.points.size());
  EXPECT_GT(leaves, 100u);
  // ... and inside its top-level cell's point range.
  for (const OctreeCell& c : b.content.cells) {
    if (!c.isLeaf()) continue;
    ASSERT_NE(c.topLevel, kNoIndex);
    const TopLevelCell& top = b.content.topLevel[c.topLevel];
    EXPECT_GE(c.pointsOffset, top.levelSplatCount);
    EXPECT_LE(std::uint64_t{c.pointsOffset} + c.pointsCount,
              std::uint64_t{top.levelSplatCount} + top.pointCount);
  }
}

TEST(Octree, ChildrenAreTheOctantsOfTheirParentsCube) {
  const Built b = build(4000, smallOptions());
  const Octree& t = b.tree;
  const auto children = childLists(t);
  const unsigned maxDepth = 10;
  auto octant = [&](const Splat& s, unsigned depth) {
    unsigned o = 0;
    for (int a = 0; a < 3; ++a) {
      const double u = (static_cast<double>(s.position[a]) - t.cubeMin[a]) / t.cubeSize;
      const auto q = static_cast<std::uint64_t>(std::clamp(std::floor(u * 1024.0), 0.0, 1023.0));
      o = o * 2 + static_cast<unsigned>((q >> (maxDepth - 1 - depth)) & 1u);
    }
    return o;
  };
  for (std::uint32_t i = 0; i < t.cells.size(); ++i) {
    const BuildCell& c = t.cells[i];
    EXPECT_EQ(c.childCount, children[i].size());
    unsigned previous = 0;
    for (std::size_t k = 0; k < children[i].size(); ++k) {
      const BuildCell& ch = t.cells[children[i][k]];
      EXPECT_EQ(ch.depth, c.depth + 1);
      const unsigned o = octant(t.points[ch.begin], c.depth);
      if (k > 0) {
        EXPECT_GT(o, previous);  // distinct octants, in order
      }
      previous = o;
      for (std::uint64_t p = ch.begin; p < ch.end; ++p) ASSERT_EQ(octant(t.points[p], c.depth), o);
    }
    if (!children[i].empty()) {
      EXPECT_EQ(t.cells[children[i].front()].begin, c.begin);
      EXPECT_EQ(t.cells[children[i].back()].end, c.end);
    }
  }
}

// The sort's codes (BMI2's pdep where the processor has it) order the points
// as the scalar coder's do: the top 24 bits never fall, and a run sharing them
// that is longer than a leaf is in full code order. Also spreadBits' layout.
TEST(Octree, PointsFollowTheScalarCodersMortonCurve) {
  for (const unsigned maxDepth : {10u, 16u, 21u}) {
    OctreeOptions options;
    options.maxDepth = maxDepth;
    options.leafPoints = 16;
    options.threads = 2;
    const Octree tree = buildOctree(testCloud(20000, 3), options);
    OctreeCube cube;
    for (int a = 0; a < 3; ++a) cube.min[a] = tree.cubeMin[a];
    cube.size = tree.cubeSize;
    const unsigned lowBit = 3 * maxDepth - 24;
    std::vector<std::uint64_t> codes;
    for (const Splat& p : tree.points) codes.push_back(mortonCode(p.position, cube, maxDepth));
    std::size_t runStart = 0, longRuns = 0;
    for (std::size_t i = 1; i <= codes.size(); ++i) {
      if (i < codes.size()) {
        ASSERT_LE(codes[i - 1] >> lowBit, codes[i] >> lowBit) << i;
      }
      if (i < codes.size() && codes[i] >> lowBit == codes[runStart] >> lowBit) continue;
      if (i - runStart > options.leafPoints) {
        ++longRuns;
        for (std::size_t j = runStart + 1; j < i; ++j) ASSERT_LE(codes[j - 1], codes[j]) << j;
      }
      runStart = i;
    }
    EXPECT_GT(longRuns, 0u) << maxDepth;  // the dense blob
  }
  for (const std::uint64_t v : {0ull, 1ull, 0x1fffffull, 0x15555ull, 0x123456789ull}) {
    const std::uint64_t spread = spreadBits(v);
    EXPECT_EQ(compactBits(spread), v & 0x1fffff);
    EXPECT_EQ(spread & ~0x1249249249249249ull, 0u);
    for (unsigned k = 0; k < 21; ++k) EXPECT_EQ((spread >> (3 * k)) & 1u, (v >> k) & 1u);
  }
}

// Runs that share the radix-sorted top levels and hold more than a leaf are
// sorted by code, equal codes in input order: the order an in-memory build
// gives, which an out-of-core chunk (whose points share their top levels, so
// its runs are long) must repeat for the same dataset.
TEST(Octree, LongRunsFollowTheCodeThenTheInputOrder) {
  constexpr unsigned kMaxDepth = 21;
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> blob(0.0f, 1e-3f);
  std::vector<Splat> input;
  const auto add = [&](float x, float y, float z) {
    Splat s{};
    s.position[0] = x;
    s.position[1] = y;
    s.position[2] = z;
    s.normal[2] = 1.0f;
    s.radius = static_cast<float>(input.size() + 1);  // the input order, exactly
    s.color[3] = 255;
    input.push_back(s);
  };
  add(0.0f, 0.0f, 0.0f);
  add(1.0f, 1.0f, 1.0f);
  // A dense blob (one run under 8 levels), a third of it repeated positions.
  for (int i = 0; i < 30000; ++i) {
    if (i % 3 == 2) {
      // One of the last 40 points (the two corners are not among them).
      const std::size_t back = std::min<std::size_t>(40, input.size() - 2);
      const Splat earlier = input[input.size() - 1 - static_cast<std::size_t>(rng() % back)];
      add(earlier.position[0], earlier.position[1], earlier.position[2]);
    } else {
      add(0.5f + blob(rng), 0.5f + blob(rng), 0.5f + blob(rng));
    }
  }
  OctreeOptions options;
  options.maxDepth = kMaxDepth;
  options.leafPoints = 16;
  options.threads = 2;
  const Octree tree = buildOctree(input, options);
  OctreeCube cube;
  for (int a = 0; a < 3; ++a) cube.min[a] = tree.cubeMin[a];
  cube.size = tree.cubeSize;
  const unsigned lowBit = 3 * kMaxDepth - 24;
  std::size_t runStart = 0, longest = 0, ties = 0;
  for (std::size_t i = 1; i <= tree.points.size(); ++i) {
    const auto code = [&](std::size_t j) {
      return mortonCode(tree.points[j].position, cube, kMaxDepth);
    };
    if (i < tree.points.size() && code(i) >> lowBit == code(runStart) >> lowBit) continue;
    if (i - runStart > options.leafPoints) {
      longest = std::max(longest, i - runStart);
      for (std::size_t j = runStart + 1; j < i; ++j) {
        ASSERT_LE(code(j - 1), code(j)) << j;
        if (code(j - 1) == code(j)) {
          ++ties;
          ASSERT_LT(tree.points[j - 1].radius, tree.points[j].radius) << j;
        }
      }
    }
    runStart = i;
  }
  EXPECT_GT(longest, 20000u);
  EXPECT_GT(ties, 5000u);
}

TEST(Octree, NextSiblingAndLevelsFollowTheRules) {
  const Built b = build(5000, smallOptions());
  const Octree& t = b.tree;
  const auto children = childLists(t);
  const auto& cells = b.content.cells;
  // Recursive definitions, independent of the builder's stack pass.
  std::vector<std::uint32_t> next(cells.size(), kNoIndex);
  std::function<void(std::uint32_t, std::uint32_t)> assign = [&](std::uint32_t i,
                                                                 std::uint32_t after) {
    next[i] = after;
    for (std::size_t k = 0; k < children[i].size(); ++k)
      assign(children[i][k], k + 1 < children[i].size() ? children[i][k + 1] : after);
  };
  assign(0, kNoIndex);
  std::function<unsigned(std::uint32_t)> level = [&](std::uint32_t i) {
    unsigned m = 0;
    for (auto c : children[i]) m = std::max(m, level(c));
    return children[i].empty() ? 1u : 1u + m;
  };
  for (std::uint32_t i = 0; i < cells.size(); ++i) {
    EXPECT_EQ(cells[i].nextSibling, next[i]) << i;
    EXPECT_EQ(cells[i].level, level(i)) << i;
    EXPECT_EQ(cells[i].isLeaf(), children[i].empty());
    EXPECT_EQ(cells[i].childCount, children[i].size());
    if (!children[i].empty()) {
      EXPECT_EQ(children[i][0], i + 1);  // depth-first: the first child follows
    }
  }
}

TEST(Octree, SiblingSkipWalkVisitsExactlyTheRecursiveWalk) {
  const Built b = build(5000, smallOptions());
  const auto children = childLists(b.tree);
  const auto& cells = b.content.cells;
  // Seed 003 §4.3: visit index, then index + 1 to descend or nextSibling to skip.
  auto skipWalk = [&](const std::function<bool(std::uint32_t)>& descend) {
    std::vector<std::uint32_t> visited;
    std::uint32_t index = 0;
    do {
      visited.push_back(index);
      index = (!cells[index].isLeaf() && descend(index)) ? index + 1 : cells[index].nextSibling;
    } while (index != kNoIndex);
    return visited;
  };
  auto recursiveWalk = [&](const std::function<bool(std::uint32_t)>& descend) {
    std::vector<std::uint32_t> visited;
    std::function<void(std::uint32_t)> rec = [&](std::uint32_t i) {
      visited.push_back(i);
      if (!descend(i)) return;
      for (auto c : children[i]) rec(c);
    };
    rec(0);
    return visited;
  };
  auto always = [](std::uint32_t) { return true; };
  const auto all = skipWalk(always);
  EXPECT_EQ(all, recursiveWalk(always));
  ASSERT_EQ(all.size(), cells.size());
  for (std::uint32_t i = 0; i < all.size(); ++i) EXPECT_EQ(all[i], i);
  for (std::uint32_t seed = 1; seed <= 5; ++seed) {
    auto cull = [seed](std::uint32_t i) {  // a random but fixed predicate per cell
      std::uint32_t h = (i + 1) * 2654435761u ^ seed * 40503u;
      h ^= h >> 13;
      return (h % 10) < 8;
    };
    const auto visited = skipWalk(cull);
    EXPECT_EQ(visited, recursiveWalk(cull)) << "seed " << seed;
    EXPECT_LT(visited.size(), cells.size());
  }
}

TEST(Octree, TopLevelCellsPartitionThePointArray) {
  const Built b = build(8000, smallOptions());
  const DatasetContent& c = b.content;
  const unsigned depth = c.manifest.topLevelDepth;
  EXPECT_EQ(depth, 3u);
  // Packets are contiguous, disjoint and cover the point-array.
  std::uint64_t offset = 0, points = 0;
  for (const TopLevelCell& t : c.topLevel) {
    EXPECT_EQ(t.byteOffset, offset);
    EXPECT_EQ(t.byteSize, (std::uint64_t{t.pointCount} + t.levelSplatCount) * sizeof(Splat));
    offset += t.byteSize;
    points += t.pointCount;
    const OctreeCell& cell = c.cells[t.cellIndex];
    EXPECT_TRUE(cell.depth == depth || (cell.isLeaf() && cell.depth < depth));
    EXPECT_EQ(cell.pointsOffset, t.levelSplatCount);  // layered: level-splats first
    EXPECT_EQ(cell.pointsCount, t.pointCount);
  }
  EXPECT_EQ(points, c.points.size());
  EXPECT_EQ(offset, (c.points.size() + c.levelSplats.size()) * sizeof(Splat));
  // Every point index is claimed by exactly one leaf, through its packet.
  std::vector<int> claimed(c.points.size(), 0);
  std::vector<std::uint64_t> base(c.topLevel.size(), 0);
  for (std::size_t k = 1; k < base.size(); ++k)
    base[k] = base[k - 1] + c.topLevel[k - 1].pointCount;
  for (const OctreeCell& cell : c.cells) {
    if (cell.topLevel == kNoIndex) {
      EXPECT_LT(cell.depth, depth);
      EXPECT_FALSE(cell.isLeaf());
      EXPECT_EQ(cell.pointsCount + cell.splatsCount, 0u);
      continue;
    }
    const TopLevelCell& t = c.topLevel[cell.topLevel];
    EXPECT_GE(cell.pointsOffset, t.levelSplatCount);
    EXPECT_LE(std::uint64_t{cell.pointsOffset} + cell.pointsCount,
              std::uint64_t{t.levelSplatCount} + t.pointCount);
    EXPECT_LE(std::uint64_t{cell.splatsOffset} + cell.splatsCount, t.levelSplatCount);
    EXPECT_GE(cell.splatsCount, 1u);
    if (cell.isLeaf())
      for (std::uint32_t q = 0; q < cell.pointsCount; ++q)
        ++claimed[base[cell.topLevel] + cell.pointsOffset - t.levelSplatCount + q];
  }
  EXPECT_TRUE(std::all_of(claimed.begin(), claimed.end(), [](int n) { return n == 1; }));
  EXPECT_NO_THROW(validateDatasetStructure(c.manifest, c.cells, c.topLevel, "test"));
}

TEST(Octree, ShallowBranchLeafIsItsOwnTopLevelCell) {
  // A dense cluster in one corner and three points in the opposite one: that
  // octant is a leaf at depth 1, above the top-level depth 3.
  std::vector<Splat> pts = testCloud(3000, 3);
  for (auto& s : pts)
    for (int a = 0; a < 3; ++a) s.position[a] = s.position[a] * 0.1f - 1.0f;
  for (int i = 0; i < 3; ++i) {
    Splat s{};
    s.position[0] = s.position[1] = s.position[2] = 1.0f - 0.01f * static_cast<float>(i);
    s.normal[1] = 1.0f;
    s.radius = 0.01f;
    pts.push_back(s);
  }
  PreprocessOptions o = smallOptions();
  DatasetContent c = buildDatasetContent(pts, o);
  finalizeDatasetContent(c);
  bool found = false;
  for (const TopLevelCell& t : c.topLevel) {
    const OctreeCell& cell = c.cells[t.cellIndex];
    if (cell.depth == 1 && cell.isLeaf()) {
      found = true;
      EXPECT_EQ(t.pointCount, 3u);
    }
  }
  EXPECT_TRUE(found);
}

TEST(Octree, TopLevelDepthIsChosenFromDataSizeAndCanBeOverridden) {
  PreprocessOptions o = smallOptions();
  Octree t = buildOctree(testCloud(20000, 5), o.octree);
  // 20k points (~850 KiB of packets) fit in few packets: the paper's minimum 3.
  EXPECT_EQ(chooseTopLevelDepth(t), 3u);
  // Small packets force a deeper top level, with more top-level cells.
  const unsigned deeper = chooseTopLevelDepth(t, 8 * 1024);
  EXPECT_GT(deeper, 3u);
  EXPECT_GT(countTopLevelCells(t, deeper), countTopLevelCells(t, 3));
  const double perPacket =
      20001.0 * 32 * 4 / 3 / static_cast<double>(countTopLevelCells(t, deeper));
  EXPECT_LE(perPacket, 8 * 1024.0);
  o.topLevelDepth = 2;
  EXPECT_EQ(buildDatasetContent(testCloud(2000, 5), o).manifest.topLevelDepth, 2u);
  o.topLevelDepth = 50;  // deeper than the tree: clamped, every leaf is a top-level cell
  DatasetContent c = buildDatasetContent(testCloud(2000, 5), o);
  std::size_t leaves = 0;
  for (const auto& cell : c.cells) leaves += cell.isLeaf() ? 1u : 0u;
  EXPECT_EQ(c.topLevel.size(), leaves);
}

TEST(Octree, NormalConeContainsAllNormalsOfTheSubtree) {
  const Built b = build(6000, smallOptions());
  const auto& cells = b.content.cells;
  std::size_t leaves = 0, tightLeaves = 0;
  for (std::uint32_t i = 0; i < cells.size(); ++i) {
    const NormalCone cone = decodeNormalCone(cells[i]);
    if (cells[i].isLeaf()) {
      ++leaves;
      if (cone.valid && cone.cosHalfAngle > 0.5) ++tightLeaves;
    }
    if (!cone.valid) continue;
    for (const Splat& s : subtreeSplats(b.content, i)) {
      const Vec3d n = normalized({s.normal[0], s.normal[1], s.normal[2]});
      // In float, as a traverse would compute it.
      const float d = static_cast<float>(cone.axis[0]) * static_cast<float>(n[0]) +
                      static_cast<float>(cone.axis[1]) * static_cast<float>(n[1]) +
                      static_cast<float>(cone.axis[2]) * static_cast<float>(n[2]);
      ASSERT_GE(static_cast<double>(d), cone.cosHalfAngle) << "cell " << i;
    }
  }
  // On a sphere, leaf cones are narrow: the cone is useful, not just valid.
  EXPECT_GT(tightLeaves * 10, leaves * 9);
}

TEST(Octree, BoundsAndRadiusAreConservativeForTheSubtree) {
  const Built b = build(5000, smallOptions());
  const auto& cells = b.content.cells;
  for (std::uint32_t i = 0; i < cells.size(); ++i) {
    for (const Splat& s : subtreeSplats(b.content, i)) {
      for (int a = 0; a < 3; ++a) {
        ASSERT_GE(s.position[a], cells[i].boundsMin[a]) << i;
        ASSERT_LE(s.position[a], cells[i].boundsMax[a]) << i;
      }
      ASSERT_LE(s.radius, cells[i].maxSplatRadius) << i;
    }
  }
}

TEST(Octree, IsDeterministic) {
  const Built a = build(3000, smallOptions(), 9);
  const Built b = build(3000, smallOptions(), 9);
  ASSERT_EQ(a.content.cells.size(), b.content.cells.size());
  EXPECT_EQ(
      std::memcmp(a.content.cells.data(), b.content.cells.data(), a.content.cells.size() * 64), 0);
  ASSERT_EQ(a.content.levelSplats.size(), b.content.levelSplats.size());
  EXPECT_EQ(std::memcmp(a.content.levelSplats.data(), b.content.levelSplats.data(),
                        a.content.levelSplats.size() * 32),
            0);
}

TEST(Octree, IdenticalPointsStopAtMaxDepth) {
  std::vector<Splat> pts(500, testCloud(1, 1)[0]);
  pts.push_back(testCloud(1, 2)[1]);  // one other point so the cube is not degenerate
  PreprocessOptions o = smallOptions();
  o.octree.maxDepth = 6;
  DatasetContent c = buildDatasetContent(pts, o);
  EXPECT_NO_THROW(finalizeDatasetContent(c));
  std::uint32_t biggest = 0;
  for (const auto& cell : c.cells)
    if (cell.isLeaf()) {
      EXPECT_LE(cell.depth, 6);
      biggest = std::max(biggest, cell.pointsCount);
    }
  EXPECT_EQ(biggest, 500u);
}

TEST(Octree, RefusesBadInputAndOptions) {
  OctreeOptions o;
  EXPECT_THROW(buildOctree({}, o), InputError);
  auto pts = testCloud(10, 1);
  pts[3].position[1] = std::numeric_limits<float>::quiet_NaN();
  EXPECT_THROW(buildOctree(pts, o), InputError);
  o.maxDepth = 22;
  EXPECT_THROW(buildOctree(testCloud(10, 1), o), UsageError);
  o.maxDepth = 0;
  EXPECT_THROW(buildOctree(testCloud(10, 1), o), UsageError);
}

TEST(Octree, SinglePointDatasetIsValid) {
  DatasetContent c = buildDatasetContent(testCloud(0, 1), smallOptions());  // just the far point
  finalizeDatasetContent(c);
  ASSERT_EQ(c.cells.size(), 1u);
  EXPECT_EQ(c.topLevel.size(), 1u);
  EXPECT_EQ(c.cells[0].level, 1);
  EXPECT_EQ(c.levelSplats.size(), 1u);
}

// The octree's Morton sort and the orientation's seed order rely on it: only
// the chosen bits order the items, and equal keys keep their input order, on
// one thread and when each thread sorts its share (enough items for three).
TEST(RadixSort, OrdersByTheChosenBitsAndIsStable) {
  for (const unsigned threads : {1u, 3u}) {
    std::mt19937_64 random(7);
    std::vector<std::uint64_t> items(800000);
    for (std::size_t i = 0; i < items.size(); ++i)
      items[i] = (random() & 0x3ff00ull) | (i & 0xff);  // 1024 keys: many ties
    std::vector<std::uint64_t> expected = items;
    const auto keyBits = [](std::uint64_t v) { return (v >> 8) & 0xfff; };
    std::stable_sort(expected.begin(), expected.end(),
                     [&](std::uint64_t a, std::uint64_t b) { return keyBits(a) < keyBits(b); });
    std::vector<std::uint64_t> wide = items;
    radixSort(
        items, 8, 20, [](std::uint64_t v) { return v; }, {}, threads);
    EXPECT_EQ(items, expected) << threads << " threads";
    // 11-bit digits (the cube moments' sort): two passes, the second partial.
    radixSort<11>(
        wide, 8, 20, [](std::uint64_t v) { return v; }, {}, threads);
    EXPECT_EQ(wide, expected) << threads << " threads, 11-bit digits";
  }
}

// The top digit deals the items into buckets, each then sorted on the lower
// bits alone: one bucket holding most items (sorted on all threads), buckets
// of a few items (insertion-sorted), empty buckets, a top digit all items
// share, and keys up to the 64th bit all give the stable order.
TEST(RadixSort, BucketsOfEverySizeGiveTheStableOrder) {
  std::mt19937_64 random(11);
  const auto check = [](std::vector<std::uint64_t> items, unsigned low, unsigned high,
                        unsigned threads, const char* what) {
    const std::uint64_t mask =
        high - low >= 64 ? ~std::uint64_t{0} : (std::uint64_t{1} << (high - low)) - 1;
    const auto bits = [&](std::uint64_t v) { return (v >> low) & mask; };
    std::vector<std::uint64_t> expected = items;
    std::stable_sort(expected.begin(), expected.end(),
                     [&](std::uint64_t a, std::uint64_t b) { return bits(a) < bits(b); });
    std::vector<std::uint64_t> eight = items;
    radixSort(
        eight, low, high, [](std::uint64_t v) { return v; }, {}, threads);
    EXPECT_EQ(eight, expected) << what << ", 8-bit digits, " << threads << " threads";
    radixSort<11>(
        items, low, high, [](std::uint64_t v) { return v; }, {}, threads);
    EXPECT_EQ(items, expected) << what << ", 11-bit digits, " << threads << " threads";
  };
  for (const unsigned threads : {1u, 2u, 3u}) {
    std::vector<std::uint64_t> skewed(300000);
    for (std::uint64_t& v : skewed) {
      // Nine in ten keys in one top-digit bucket; the index bits below 8 tie.
      const std::uint64_t top = random() % 10 == 0 ? random() % 256 : 17;
      v = top << 32 | (random() & 0xffffff00ull) | (random() & 0xff);
    }
    check(skewed, 8, 40, threads, "one bucket holds most");
    // About 34 items a bucket of the 11-bit top digit, their keys below it
    // one of 16 (many ties, told apart by the bits below `low`).
    std::vector<std::uint64_t> small(70000);
    for (std::size_t i = 0; i < small.size(); ++i)
      small[i] = (random() & 0x7ffull) << 40 | (random() % 16) << 20 | i;
    check(small, 20, 51, threads, "buckets of a few dozen items");
    std::vector<std::uint64_t> wide(100000);
    for (std::uint64_t& v : wide) v = random();
    check(wide, 20, 64, threads, "keys to the 64th bit");
    std::vector<std::uint64_t> shared(100000);
    for (std::uint64_t& v : shared) v = std::uint64_t{5} << 30 | (random() & 0x3fffffffull);
    check(shared, 0, 36, threads, "every item in one bucket");
  }
}

}  // namespace
}  // namespace pointillist::preprocess
