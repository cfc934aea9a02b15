#pragma once
// Seed 004 §7: the view-dependent cut through every top-level cell's
// statistical hierarchy. From the root down, a node's subtree is dropped when
// its bounding sphere lies outside the frame or its normal cone faces away
// from the eye; a node is drawn once it projects to at most
// kStatisticalCutPixels * lodPixels (the radius of its gamma ellipsoid, at its
// mean's depth) or is a leaf. The cut depends on the camera only, never on a
// tile: a tile then takes the cut's nodes whose points may reach it, so tiles
// add up to the whole frame exactly as the reference draws it.
//
// Traverse processes (the paper's server) and the reference renderer both run
// it; render processes generate each node's points (common/statistical_point_table.hpp).
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "common/camera.hpp"
#include "common/cell_prefix.hpp"
#include "common/statistical_node.hpp"

namespace pointillist {

class Dataset;

// The paper splits a node while its screen size is above 2 pixels.
inline constexpr float kStatisticalCutPixels = 2.0f;

// What the cut needs of a node, decoded once per run.
struct CutNode {
  float mean[3];
  float radius;          // gamma * sigma_1: the sphere holding the node's own points
  float minorRadius;     // gamma * sigma_2
  float normal[3];       // the mean normal
  float coneAngle;       // half angle holding the generated normals (>= pi/2: never culled)
  float boundCentre[3];  // a sphere holding the points of the node and every descendant
  float boundRadius;
  float boundAxis[3];  // a cone holding their normals
  float boundAngle;
  // Cosine and sine of coneAngle and boundAngle: the walk's cone tests take
  // no trigonometry.
  float coneCosSin[2];
  float boundCosSin[2];
  std::uint32_t firstChild;  // 0: leaf
};

// Every top-level cell's hierarchy, and where its levels end in its packet.
class StatisticalTrees {
 public:
  // `packets[t]` is top-level cell t's whole decoded packet; its packet id is
  // firstPacketId + t.
  StatisticalTrees(std::span<const StatisticalPacketView> packets, std::uint32_t firstPacketId);
  // Reads statistical.bin and the class tables. Throws UsageError for a
  // dataset built without --statistical (naming the option that builds it).
  static std::shared_ptr<const StatisticalTrees> load(const Dataset& dataset);

  std::uint32_t cellCount() const { return static_cast<std::uint32_t>(first_.size() - 1); }
  std::uint32_t packetId(std::uint32_t cell) const { return firstPacketId_ + cell; }
  std::uint32_t firstPacketId() const { return firstPacketId_; }
  std::span<const CutNode> nodes(std::uint32_t cell) const;
  // Per depth, the packet prefix (records) holding every node down to it.
  std::span<const std::uint32_t> levelEnds(std::uint32_t cell) const;
  std::uint64_t nodeCount() const { return nodes_.size(); }
  // Adds the next top-level cell's whole decoded packet.
  void addPacket(const StatisticalPacketView& packet);

 private:
  std::uint32_t firstPacketId_;
  std::vector<CutNode> nodes_;
  std::vector<std::uint64_t> first_;  // per cell, its first node; plus one entry
  std::vector<std::uint32_t> levelEnds_;
  std::vector<std::uint64_t> firstLevel_;
};

struct StatisticalCutSettings {
  float lodPixels = 1.0f;  // multiplies kStatisticalCutPixels
  bool backfaceCull = true;
  // Pixels added around a tile beyond a generated point's own half width.
  float marginPixels = 1.0f;
};

struct StatisticalCut {
  struct Node {
    std::uint32_t cell;
    std::uint32_t node;
    std::uint32_t points;  // estimated generated points (the cost function's workload)
    // Full-frame pixels holding the node's sphere (conservative; the whole
    // plane when it reaches behind the eye): tiles test this first.
    float low[2];
    float high[2];
  };
  std::vector<Node> nodes;  // sorted by (cell, node)
  std::uint64_t points = 0;
  std::uint64_t visited = 0;
  std::uint64_t culledFrustum = 0;
  std::uint64_t culledBackface = 0;
};
StatisticalCut cutStatistical(const StatisticalTrees& trees, const Camera& camera,
                              const StatisticalCutSettings& settings);

// The cut's nodes that may draw into `rect`: ranges of node indices per
// packet (packet id, first node, count), merged where consecutive, and each
// packet's prefix holding its last node.
struct StatisticalTile {
  struct Range {
    std::uint32_t packet;
    std::uint32_t first;
    std::uint32_t count;
  };
  std::vector<Range> ranges;      // sorted by (packet, first)
  std::vector<CellPrefix> needs;  // packet ids ascending; prefixes in records
  std::uint64_t points = 0;
  std::uint64_t nodes = 0;
};
StatisticalTile statisticalTile(const StatisticalTrees& trees, const StatisticalCut& cut,
                                const Camera& camera, const TileRect& rect,
                                const StatisticalCutSettings& settings);

// Seed 004 §7: the cone test shared by the cut and its tests. True when every
// normal within `angle` of `axis` faces away from every direction from the
// sphere (centre, radius) to the eye.
bool coneFacesAway(const float axis[3], float angle, const float centre[3], float radius,
                   const glm::vec3& eye);

}  // namespace pointillist
