// Seed 004 §7: the view-dependent cut -- conservative culling bounds, the stop
// rule, and tiles that add up to the whole frame's cut.
#include "common/statistical_cut.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <random>
#include <set>

#include "common/statistical_point_table.hpp"

namespace pointillist {
namespace {

constexpr float kPi = std::numbers::pi_v<float>;

// A complete binary hierarchy of `depth` levels over the square [-1, 1]^2 at
// z = 0 (halved along x, then y, ...), normals +z tilted a little per node.
StatisticalPacketView squareTree(std::uint32_t depth, std::uint64_t seed = 1) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<float> tilt(-0.2f, 0.2f);
  StatisticalPacketView view;
  struct Box {
    float lo[2], hi[2];
  };
  std::vector<Box> boxes{{{-1, -1}, {1, 1}}};
  const std::uint32_t count = (1u << depth) - 1;
  view.header.nodeCount = count;
  view.nodes.resize(count);
  std::uint32_t internal = 0;
  for (std::uint32_t i = 0; i < count; ++i) {
    StatisticalNode& n = view.nodes[i];
    n = StatisticalNode{};
    const Box b = boxes[i];
    const float w = b.hi[0] - b.lo[0], h = b.hi[1] - b.lo[1];
    n.mean[0] = 0.5f * (b.lo[0] + b.hi[0]);
    n.mean[1] = 0.5f * (b.lo[1] + b.hi[1]);
    n.mean[2] = 0.0f;
    const bool wide = w >= h;
    n.axes[0][wide ? 0 : 1] = 1;
    n.axes[1][wide ? 1 : 0] = 1;
    n.axes[2][2] = 1;
    n.sigma[0] = std::max(w, h) / std::sqrt(12.0f);
    n.sigma[1] = std::min(w, h) / std::sqrt(12.0f);
    n.sigma[2] = 0.001f;
    const float tx = tilt(rng), ty = tilt(rng);
    const float l = std::sqrt(1 + tx * tx + ty * ty);
    n.normalFrame[0][0] = 1;
    n.normalFrame[1][1] = 1;
    n.normalFrame[2][0] = tx / l;
    n.normalFrame[2][1] = ty / l;
    n.normalFrame[2][2] = 1 / l;
    n.sigmaNormal[0] = 0.05f;
    n.sigmaNormal[1] = 0.02f;
    if (i > 0) n.parent = (i - 1) / 2;
    if (2 * i + 2 < count) {
      n.firstChild = 2 * internal + 1;
      ++internal;
      Box left = b, right = b;
      const int axis = wide ? 0 : 1;
      const float mid = 0.5f * (b.lo[axis] + b.hi[axis]);
      left.hi[axis] = mid;
      right.lo[axis] = mid;
      boxes.push_back(left);
      boxes.push_back(right);
    }
  }
  return view;
}

float distance3(const float a[3], const float b[3]) {
  return std::sqrt((a[0] - b[0]) * (a[0] - b[0]) + (a[1] - b[1]) * (a[1] - b[1]) +
                   (a[2] - b[2]) * (a[2] - b[2]));
}
float angleBetween(const float a[3], const float b[3]) {
  const glm::vec3 u(a[0], a[1], a[2]), v(b[0], b[1], b[2]);
  return std::atan2(glm::length(glm::cross(u, v)), glm::dot(u, v));
}

TEST(StatisticalCut, ConeTestOnlyCullsWhatFacesAway) {
  std::mt19937_64 rng(17);
  std::normal_distribution<float> n;
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  int culled = 0;
  for (int trial = 0; trial < 4000; ++trial) {
    float axis[3] = {n(rng), n(rng), n(rng)};
    const float la = std::sqrt(axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]);
    for (float& v : axis) v /= la;
    const float angle = u(rng) * 1.2f;
    const float centre[3] = {n(rng), n(rng), n(rng)};
    const float radius = 0.5f * u(rng);
    const glm::vec3 eye(4 * n(rng), 4 * n(rng), 4 * n(rng));
    if (!coneFacesAway(axis, angle, centre, radius, eye)) continue;
    ++culled;
    for (int s = 0; s < 200; ++s) {
      // A point in the sphere and a normal in the cone (rim included).
      glm::vec3 d(n(rng), n(rng), n(rng));
      const glm::vec3 p =
          glm::vec3(centre[0], centre[1], centre[2]) + glm::normalize(d) * radius * u(rng);
      glm::vec3 a(axis[0], axis[1], axis[2]);
      glm::vec3 side = glm::normalize(glm::cross(a, glm::vec3(n(rng), n(rng), n(rng))));
      const float t = s % 4 == 0 ? angle : angle * u(rng);
      const glm::vec3 normal = std::cos(t) * a + std::sin(t) * side;
      EXPECT_LT(glm::dot(normal, eye - p), 1e-5f);
    }
  }
  EXPECT_GT(culled, 100);
}

TEST(StatisticalCut, SubtreeBoundsHoldEveryDescendant) {
  const auto view = squareTree(8);
  const StatisticalTrees trees(std::span<const StatisticalPacketView>(&view, 1), 10);
  const auto nodes = trees.nodes(0);
  ASSERT_EQ(nodes.size(), view.nodes.size());
  for (std::size_t i = 0; i < nodes.size(); ++i) {
    // Walk the subtree of i.
    std::vector<std::size_t> stack{i};
    while (!stack.empty()) {
      const std::size_t j = stack.back();
      stack.pop_back();
      EXPECT_LE(distance3(nodes[i].boundCentre, nodes[j].mean) + nodes[j].radius,
                nodes[i].boundRadius * (1 + 1e-4f) + 1e-6f);
      EXPECT_LE(angleBetween(nodes[i].boundAxis, nodes[j].normal) + nodes[j].coneAngle,
                nodes[i].boundAngle + 1e-4f);
      if (nodes[j].firstChild != 0) {
        stack.push_back(nodes[j].firstChild);
        stack.push_back(nodes[j].firstChild + 1);
      }
    }
  }
  // Levels: each depth's prefix holds its nodes.
  const auto ends = trees.levelEnds(0);
  ASSERT_EQ(ends.size(), 8u);
  for (std::uint32_t d = 0; d < 8; ++d) EXPECT_EQ(ends[d], statisticalPrefixRecords((2u << d) - 1));
  EXPECT_EQ(trees.packetId(0), 10u);
}

Camera cameraAt(float distance, std::uint32_t width = 640, std::uint32_t height = 480) {
  return makeCamera({0.3f, -0.2f, distance}, {0, 0, 0}, {0, 1, 0}, 45.0f, 0.01f, 100.0f, width,
                    height);
}

TEST(StatisticalCut, NodesStopAtTheScreenThresholdAndGetCloserDetailNearer) {
  const auto view = squareTree(14);
  const StatisticalTrees trees(std::span<const StatisticalPacketView>(&view, 1), 1);
  const StatisticalCutSettings settings;
  std::size_t previous = 0;
  for (const float distance : {40.0f, 10.0f, 3.0f}) {
    const Camera camera = cameraAt(distance);
    const StatisticalCut cut = cutStatistical(trees, camera, settings);
    ASSERT_FALSE(cut.nodes.empty());
    EXPECT_GT(cut.nodes.size(), previous);
    previous = cut.nodes.size();
    const double focal = focalLengthPixels(camera);
    const auto nodes = trees.nodes(0);
    std::uint64_t points = 0;
    for (const auto& entry : cut.nodes) {
      const CutNode& n = nodes[entry.node];
      const float depth = viewDepth(camera, {n.mean[0], n.mean[1], n.mean[2]});
      if (n.firstChild != 0) {
        EXPECT_LE(focal * double(n.radius) / double(depth),
                  double(kStatisticalCutPixels * settings.lodPixels) + 1e-4);
      }
      points += entry.points;
    }
    EXPECT_EQ(points, cut.points);
    // The cut covers the square: every leaf lies under exactly one cut node
    // (the camera sees all of it and nothing faces away).
    std::vector<int> covered(nodes.size(), 0);
    for (const auto& entry : cut.nodes) {
      std::vector<std::uint32_t> stack{entry.node};
      while (!stack.empty()) {
        const std::uint32_t j = stack.back();
        stack.pop_back();
        ++covered[j];
        if (nodes[j].firstChild != 0) {
          stack.push_back(nodes[j].firstChild);
          stack.push_back(nodes[j].firstChild + 1);
        }
      }
    }
    for (std::size_t j = 0; j < nodes.size(); ++j) {
      if (nodes[j].firstChild == 0) {
        EXPECT_EQ(covered[j], 1) << j;
      }
    }
  }
}

TEST(StatisticalCut, BackFacingHierarchiesAreCulled) {
  const auto view = squareTree(10);
  const StatisticalTrees trees(std::span<const StatisticalPacketView>(&view, 1), 1);
  const Camera below =
      makeCamera({0.1f, 0.2f, -5.0f}, {0, 0, 0}, {0, 1, 0}, 45.0f, 0.01f, 100.0f, 640, 480);
  const StatisticalCut cut = cutStatistical(trees, below, {});
  EXPECT_TRUE(cut.nodes.empty());
  EXPECT_GT(cut.culledBackface, 0u);
  StatisticalCutSettings noCull;
  noCull.backfaceCull = false;
  EXPECT_FALSE(cutStatistical(trees, below, noCull).nodes.empty());
}

TEST(StatisticalCut, ScreenRectanglesHoldTheirSpheres) {
  const auto view = squareTree(12);
  const StatisticalTrees trees(std::span<const StatisticalPacketView>(&view, 1), 0);
  std::mt19937_64 rng(23);
  std::normal_distribution<float> n;
  for (const float distance : {0.8f, 3.0f, 20.0f}) {
    const Camera camera = cameraAt(distance);
    const StatisticalCut cut = cutStatistical(trees, camera, {});
    ASSERT_FALSE(cut.nodes.empty());
    for (const auto& entry : cut.nodes) {
      const CutNode& c = trees.nodes(0)[entry.node];
      for (int s = 0; s < 20; ++s) {
        const glm::vec3 d = glm::normalize(glm::vec3(n(rng), n(rng), n(rng)));
        const glm::vec4 p =
            projectToWindow(camera, glm::vec3(c.mean[0], c.mean[1], c.mean[2]) + d * c.radius);
        if (p.w <= 0.0f) continue;
        EXPECT_GE(p.x, entry.low[0]);
        EXPECT_LE(p.x, entry.high[0]);
        EXPECT_GE(p.y, entry.low[1]);
        EXPECT_LE(p.y, entry.high[1]);
      }
    }
  }
}

TEST(StatisticalCut, TilesAddUpToTheFramesCut) {
  const auto a = squareTree(12, 1);
  auto b = squareTree(10, 2);
  for (auto& n : b.nodes) n.mean[0] += 1.5f;  // a second cell beside the first
  const StatisticalPacketView views[2] = {a, b};
  const StatisticalTrees trees(views, 2);
  const Camera camera = cameraAt(3.0f);
  const StatisticalCutSettings settings;
  const StatisticalCut cut = cutStatistical(trees, camera, settings);
  const StatisticalTile whole =
      statisticalTile(trees, cut, camera, fullFrameRect(camera), settings);
  std::set<std::pair<std::uint32_t, std::uint32_t>> inFrame, union_;
  for (const auto& r : whole.ranges)
    for (std::uint32_t k = 0; k < r.count; ++k) inFrame.insert({r.packet, r.first + k});
  EXPECT_EQ(inFrame.size(), cut.nodes.size());  // the cut already dropped what the frame misses
  std::uint64_t tileNodes = 0;
  for (std::uint32_t y = 0; y < 480; y += 96)
    for (std::uint32_t x = 0; x < 640; x += 128) {
      const StatisticalTile tile =
          statisticalTile(trees, cut, camera, makeTileRect(x, y, 128, 96), settings);
      tileNodes += tile.nodes;
      std::uint32_t previousPacket = 0, previousEnd = 0;
      for (const auto& r : tile.ranges) {
        // Sorted, merged, and every range within the prefix the tile needs.
        EXPECT_TRUE(r.packet > previousPacket || r.first > previousEnd ||
                    (r.packet == previousPacket && r.first >= previousEnd && previousEnd == 0));
        previousPacket = r.packet;
        previousEnd = r.first + r.count;
        for (std::uint32_t k = 0; k < r.count; ++k) union_.insert({r.packet, r.first + k});
        bool needed = false;
        for (const CellPrefix& need : tile.needs) {
          if (need.cell == r.packet)
            needed = statisticalNodesInRecords(need.splats, ~0u) >= r.first + r.count;
        }
        EXPECT_TRUE(needed);
      }
    }
  EXPECT_EQ(union_, inFrame);                  // no node of the frame is missing from every tile
  EXPECT_LT(tileNodes, 3 * cut.nodes.size());  // and tiles mostly take their own
}

}  // namespace
}  // namespace pointillist
