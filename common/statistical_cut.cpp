#include "common/statistical_cut.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>

#include "common/dataset.hpp"
#include "common/errors.hpp"
#include "common/statistical_point_table.hpp"

namespace pointillist {

namespace {

constexpr float kPi = std::numbers::pi_v<float>;

glm::vec3 vec(const float v[3]) {
  return {v[0], v[1], v[2]};
}
void store(const glm::vec3& v, float out[3]) {
  out[0] = v.x;
  out[1] = v.y;
  out[2] = v.z;
}

// The smallest sphere holding both; grown by a hair so rounding never makes it
// smaller than what it must hold.
void mergeSphere(glm::vec3& c1, float& r1, const glm::vec3& c2, float r2) {
  const float d = glm::length(c2 - c1);
  if (d + r2 <= r1) return;
  if (d + r1 <= r2) {
    c1 = c2;
    r1 = r2;
    return;
  }
  const float r = 0.5f * (d + r1 + r2);
  c1 += (c2 - c1) * ((r - r1) / d);
  r1 = r * (1.0f + 1e-5f) + 1e-30f;
}

// The narrowest cone holding both (axes unit, angles in [0, pi]).
void mergeCone(glm::vec3& a1, float& angle1, const glm::vec3& a2, float angle2) {
  if (angle1 >= kPi) return;
  if (angle2 >= kPi) {
    angle1 = kPi;
    return;
  }
  // atan2 keeps small angles exact where acos of a float dot would not.
  const float theta = std::atan2(glm::length(glm::cross(a1, a2)), glm::dot(a1, a2));
  if (theta + angle2 <= angle1) return;
  if (theta + angle1 <= angle2) {
    a1 = a2;
    angle1 = angle2;
    return;
  }
  const float angle = 0.5f * (theta + angle1 + angle2);
  if (angle >= kPi || theta < 1e-6f) {
    angle1 = std::min(kPi, std::max(angle, std::max(angle1, angle2)) + 1e-5f);
    return;
  }
  // Rotate a1 towards a2 by angle - angle1 (slerp).
  const float t = (angle - angle1) / theta;
  const float s = std::sin(theta);
  const glm::vec3 axis = (std::sin((1 - t) * theta) * a1 + std::sin(t * theta) * a2) / s;
  const float length = glm::length(axis);
  a1 = length > 0 ? axis / length : a1;
  angle1 = std::min(kPi, angle + 1e-5f);
}

}  // namespace

namespace {

// coneFacesAway from the cone's cosine and sine: the half angle of the view
// directions onto the sphere enters through its sine r / d, so the sum of the
// angles needs no asin.
bool facesAway(const float axis[3], const float cosSin[2], const float centre[3], float radius,
               const glm::vec3& eye) {
  const glm::vec3 d = eye - vec(centre);
  const float along = glm::dot(vec(axis), d);
  if (along >= 0.0f) return false;  // the axis itself faces the eye (most nodes)
  // With distance L, sin(view) = r / L and cos(view) = sqrt(L^2 - r^2) / L;
  // both sides below are multiplied by L.
  const float squared = glm::dot(d, d) - radius * radius;
  if (!(squared > 0.0f)) return false;  // the eye is inside the sphere
  const float tangent = std::sqrt(squared);
  // cos(angle + view) <= 0: the normals and view directions reach 90 degrees.
  if (cosSin[0] * tangent - cosSin[1] * radius <= 0.0f) return false;
  return along < -(cosSin[1] * tangent + cosSin[0] * radius);
}

}  // namespace

bool coneFacesAway(const float axis[3], float angle, const float centre[3], float radius,
                   const glm::vec3& eye) {
  const float cosSin[2] = {std::cos(angle), std::sin(angle)};
  return facesAway(axis, cosSin, centre, radius, eye);
}

StatisticalTrees::StatisticalTrees(std::span<const StatisticalPacketView> packets,
                                   std::uint32_t firstPacketId)
    : firstPacketId_(firstPacketId) {
  first_.push_back(0);
  firstLevel_.push_back(0);
  for (const StatisticalPacketView& packet : packets) addPacket(packet);
}

void StatisticalTrees::addPacket(const StatisticalPacketView& packet) {
  const auto& in = packet.nodes;
  if (in.size() != packet.header.nodeCount)
    throw Error("internal error: the cut needs whole statistical packets");
  const std::size_t base = nodes_.size();
  nodes_.resize(base + in.size());
  CutNode* out = nodes_.data() + base;
  for (std::size_t i = 0; i < in.size(); ++i) {
    const StatisticalNode& n = in[i];
    CutNode& c = out[i];
    std::copy(n.mean, n.mean + 3, c.mean);
    c.radius = kStatisticalGamma * n.sigma[0];
    c.minorRadius = kStatisticalGamma * n.sigma[1];
    std::copy(n.normalFrame[2], n.normalFrame[2] + 3, c.normal);
    c.coneAngle = std::min(kPi, kStatisticalGamma * n.sigmaNormal[0]);
    c.firstChild = n.firstChild;
  }
  // Bounds bottom-up: children come after their parent.
  for (std::size_t i = in.size(); i-- > 0;) {
    CutNode& c = out[i];
    glm::vec3 centre = vec(c.mean), axis = vec(c.normal);
    float radius = c.radius, angle = c.coneAngle;
    if (c.firstChild != 0) {
      for (std::uint32_t k = 0; k < 2; ++k) {
        const CutNode& child = out[c.firstChild + k];
        mergeSphere(centre, radius, vec(child.boundCentre), child.boundRadius);
        mergeCone(axis, angle, vec(child.boundAxis), child.boundAngle);
      }
    }
    store(centre, c.boundCentre);
    c.boundRadius = radius;
    store(axis, c.boundAxis);
    c.boundAngle = angle;
    c.coneCosSin[0] = std::cos(c.coneAngle);
    c.coneCosSin[1] = std::sin(c.coneAngle);
    c.boundCosSin[0] = std::cos(angle);
    c.boundCosSin[1] = std::sin(angle);
  }
  // Breadth-first order: depths never decrease, so each depth ends once.
  std::vector<std::uint32_t> depth(in.size(), 0);
  for (std::size_t i = 1; i < in.size(); ++i) depth[i] = depth[in[i].parent] + 1;
  for (std::size_t i = 0; i < in.size(); ++i)
    if (i + 1 == in.size() || depth[i + 1] != depth[i])
      levelEnds_.push_back(statisticalPrefixRecords(static_cast<std::uint32_t>(i + 1)));
  first_.push_back(nodes_.size());
  firstLevel_.push_back(levelEnds_.size());
}

std::shared_ptr<const StatisticalTrees> StatisticalTrees::load(const Dataset& dataset) {
  if (!dataset.hasStatistical())
    throw UsageError("--mode statistical: dataset " + dataset.path().string() +
                     " has no statistical hierarchy; build it with pointillist-preprocess "
                     "--statistical");
  const ClassTables classes = dataset.readStatisticalClasses();
  const std::vector<std::byte> bytes = dataset.readFile(kStatisticalPacketsKey);
  const std::string where = (dataset.path() / kStatisticalPacketsName).string();
  const auto entries = dataset.statisticalPackets();
  // One packet decoded at a time: the decoded form is ten times the stored one.
  auto trees = std::make_shared<StatisticalTrees>(std::span<const StatisticalPacketView>{},
                                                  dataset.statisticalPacketId(0));
  for (std::size_t t = 0; t < entries.size(); ++t) {
    const auto packet = std::span<const std::byte>(bytes).subspan(
        static_cast<std::size_t>(entries[t].byteOffset), std::size_t{entries[t].records} * 32);
    const StatisticalPacketView view =
        decodeStatisticalPacket(packet, classes, where + ": top-level cell " + std::to_string(t));
    trees->addPacket(view);
  }
  return trees;
}

std::span<const CutNode> StatisticalTrees::nodes(std::uint32_t cell) const {
  return std::span<const CutNode>(nodes_).subspan(
      static_cast<std::size_t>(first_.at(cell)),
      static_cast<std::size_t>(first_.at(cell + 1) - first_[cell]));
}

std::span<const std::uint32_t> StatisticalTrees::levelEnds(std::uint32_t cell) const {
  return std::span<const std::uint32_t>(levelEnds_)
      .subspan(static_cast<std::size_t>(firstLevel_.at(cell)),
               static_cast<std::size_t>(firstLevel_.at(cell + 1) - firstLevel_[cell]));
}

namespace {

// Generated points reach this far beyond a node's sphere, in pixels: half the
// widest point the budget gives, the rounding pixel and the caller's margin.
float reachPixels(float marginPixels) {
  return marginPixels + 0.5f * kStatisticalMaxPointPixels + 0.5f;
}

// The window rectangle of the corners of the cube around the node's sphere:
// a perspective projection maps the cube's hull to its corners' hull, which
// holds the sphere's image. Everything when a corner is not in front of the eye.
void screenBounds(const glm::mat4& viewProjection, const Camera& camera, const CutNode& n,
                  StatisticalCut::Node& entry) {
  constexpr float kEverywhere = 1e30f;
  entry.low[0] = entry.low[1] = kEverywhere;
  entry.high[0] = entry.high[1] = -kEverywhere;
  const float w = static_cast<float>(camera.image_width());
  const float h = static_cast<float>(camera.image_height());
  for (int corner = 0; corner < 8; ++corner) {
    const glm::vec4 p(n.mean[0] + ((corner & 1) ? n.radius : -n.radius),
                      n.mean[1] + ((corner & 2) ? n.radius : -n.radius),
                      n.mean[2] + ((corner & 4) ? n.radius : -n.radius), 1.0f);
    const glm::vec4 clip = viewProjection * p;
    if (!(clip.w > 1e-6f)) {
      entry.low[0] = entry.low[1] = -kEverywhere;
      entry.high[0] = entry.high[1] = kEverywhere;
      return;
    }
    const float x = (clip.x / clip.w * 0.5f + 0.5f) * w;
    const float y = (clip.y / clip.w * 0.5f + 0.5f) * h;
    entry.low[0] = std::min(entry.low[0], x);
    entry.low[1] = std::min(entry.low[1], y);
    entry.high[0] = std::max(entry.high[0], x);
    entry.high[1] = std::max(entry.high[1], y);
  }
  // A pixel of slack for the rounding of the projection.
  entry.low[0] -= 1.0f;
  entry.low[1] -= 1.0f;
  entry.high[0] += 1.0f;
  entry.high[1] += 1.0f;
}

}  // namespace

StatisticalCut cutStatistical(const StatisticalTrees& trees, const Camera& camera,
                              const StatisticalCutSettings& settings) {
  StatisticalCut cut;
  const FrustumPlanes frame =
      tilePlanes(camera, fullFrameRect(camera), reachPixels(settings.marginPixels));
  const glm::vec3 eye = cameraEye(camera);
  const glm::vec3 forward = glm::normalize(cameraTarget(camera) - eye);
  const double focal = focalLengthPixels(camera);
  const float threshold = kStatisticalCutPixels * settings.lodPixels;
  const glm::mat4 viewProjection = viewProjectionMatrix(camera);
  std::vector<std::uint32_t> stack;
  for (std::uint32_t cell = 0; cell < trees.cellCount(); ++cell) {
    const auto nodes = trees.nodes(cell);
    if (nodes.empty()) continue;
    const std::size_t begin = cut.nodes.size();
    stack.assign(1, 0);
    while (!stack.empty()) {
      const std::uint32_t i = stack.back();
      stack.pop_back();
      const CutNode& n = nodes[i];
      ++cut.visited;
      if (sphereOutside(frame, vec(n.boundCentre), n.boundRadius)) {
        ++cut.culledFrustum;
        continue;
      }
      if (settings.backfaceCull &&
          facesAway(n.boundAxis, n.boundCosSin, n.boundCentre, n.boundRadius, eye)) {
        ++cut.culledBackface;
        continue;
      }
      const float depth = glm::dot(vec(n.mean) - eye, forward);
      const bool near = !(depth > n.radius);
      const float major =
          near ? 0.0f : static_cast<float>(focal * double(n.radius) / double(depth));
      if (n.firstChild != 0 && (near || major > threshold)) {
        stack.push_back(n.firstChild + 1);  // the left child first
        stack.push_back(n.firstChild);
        continue;
      }
      if (sphereOutside(frame, vec(n.mean), n.radius)) {
        ++cut.culledFrustum;
        continue;
      }
      if (settings.backfaceCull && facesAway(n.normal, n.coneCosSin, n.mean, n.radius, eye)) {
        ++cut.culledBackface;
        continue;
      }
      NodeFootprint footprint;
      if (!near) {
        footprint.major = major;
        footprint.minor = static_cast<float>(focal * double(n.minorRadius) / double(depth));
      } else {
        footprint.major = footprint.minor = static_cast<float>(camera.image_height());
      }
      const std::uint32_t points = statisticalPointBudget(coverageEllipse(footprint)).count;
      StatisticalCut::Node entry{cell, i, points, {0, 0}, {0, 0}};
      screenBounds(viewProjection, camera, n, entry);
      cut.nodes.push_back(entry);
      cut.points += points;
    }
    std::sort(cut.nodes.begin() + static_cast<std::ptrdiff_t>(begin), cut.nodes.end(),
              [](const StatisticalCut::Node& a, const StatisticalCut::Node& b) {
                return a.node < b.node;
              });
  }
  return cut;
}

StatisticalTile statisticalTile(const StatisticalTrees& trees, const StatisticalCut& cut,
                                const Camera& camera, const TileRect& rect,
                                const StatisticalCutSettings& settings) {
  StatisticalTile tile;
  const FrustumPlanes planes = tilePlanes(camera, rect, reachPixels(settings.marginPixels));
  const float reach = reachPixels(settings.marginPixels);
  const float low[2] = {static_cast<float>(rect.x()) - reach, static_cast<float>(rect.y()) - reach};
  const float high[2] = {static_cast<float>(rect.x() + rect.width()) + reach,
                         static_cast<float>(rect.y() + rect.height()) + reach};
  for (const StatisticalCut::Node& entry : cut.nodes) {
    // Most of a frame's nodes lie far from a tile: their rectangles say so
    // before the sphere test does.
    if (entry.high[0] < low[0] || entry.low[0] > high[0] || entry.high[1] < low[1] ||
        entry.low[1] > high[1])
      continue;
    const CutNode& n = trees.nodes(entry.cell)[entry.node];
    if (sphereOutside(planes, vec(n.mean), n.radius)) continue;
    const std::uint32_t packet = trees.packetId(entry.cell);
    if (!tile.ranges.empty() && tile.ranges.back().packet == packet &&
        tile.ranges.back().first + tile.ranges.back().count == entry.node) {
      ++tile.ranges.back().count;
    } else {
      tile.ranges.push_back({packet, entry.node, 1});
    }
    const std::uint32_t records = statisticalPrefixRecords(entry.node + 1);
    if (!tile.needs.empty() && tile.needs.back().cell == packet)
      tile.needs.back().splats = std::max(tile.needs.back().splats, records);
    else
      tile.needs.push_back({packet, records});
    tile.points += entry.points;
    ++tile.nodes;
  }
  return tile;
}

}  // namespace pointillist
