#include "preprocess/dataset_builder.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "common/errors.hpp"
#include "common/geometry.hpp"
#include "preprocess/normals.hpp"
#include "preprocess/parallel.hpp"

namespace pointillist::preprocess {

namespace {

struct Summary {
  float lo[3] = {std::numeric_limits<float>::infinity(), std::numeric_limits<float>::infinity(),
                 std::numeric_limits<float>::infinity()};
  float hi[3] = {-std::numeric_limits<float>::infinity(), -std::numeric_limits<float>::infinity(),
                 -std::numeric_limits<float>::infinity()};
  float maxRadius = 0.0f;
  Vec3d normalSum{};
  bool unknownNormal = false;
};

// Stored normals are unit up to float rounding; skip the square root then.
Vec3d unitNormal(const Splat& p) {
  const Vec3d n = {p.normal[0], p.normal[1], p.normal[2]};
  const double len2 = dot(n, n);
  return std::abs(len2 - 1.0) < 1e-6 ? n : normalized(n);
}

void accumulate(Summary& s, std::span<const Splat> splats) {
  for (const Splat& p : splats) {
    for (int a = 0; a < 3; ++a) {
      s.lo[a] = std::min(s.lo[a], p.position[a]);
      s.hi[a] = std::max(s.hi[a], p.position[a]);
    }
    s.maxRadius = std::max(s.maxRadius, p.radius);
    const Vec3d n = {p.normal[0], p.normal[1], p.normal[2]};
    if (dot(n, n) > 0.25)
      s.normalSum = add(s.normalSum, unitNormal(p));
    else
      s.unknownNormal = true;
  }
}

void merge(Summary& into, const Summary& s) {
  for (int a = 0; a < 3; ++a) {
    into.lo[a] = std::min(into.lo[a], s.lo[a]);
    into.hi[a] = std::max(into.hi[a], s.hi[a]);
  }
  into.maxRadius = std::max(into.maxRadius, s.maxRadius);
  into.normalSum = add(into.normalSum, s.normalSum);
  into.unknownNormal = into.unknownNormal || s.unknownNormal;
}

double minDot(const Vec3d& axis, std::span<const Splat> splats, double current) {
  for (const Splat& p : splats) current = std::min(current, dot(axis, unitNormal(p)));
  return current;
}

}  // namespace

void mergeChildCones(std::span<OctreeCell> cells, std::size_t index, const CellNormals& normals) {
  OctreeCell& out = cells[index];
  const Vec3d axis = normalized(normals.sum);
  if (normals.unknown || length(axis) == 0.0 || out.childCount == 0) {
    clearNormalCone(out);
    return;
  }
  const ConeAxisQ q = quantizeConeAxis(axis);
  const Vec3d decoded = decodeConeAxis(q);
  const std::size_t end = out.nextSibling == kNoIndex ? cells.size() : out.nextSibling;
  double minDot = 1.0;
  for (std::size_t j = index + 1; j < end;
       j = cells[j].nextSibling == kNoIndex ? end : std::size_t{cells[j].nextSibling}) {
    const NormalCone child = decodeNormalCone(cells[j]);
    if (!child.valid) {
      clearNormalCone(out);
      return;
    }
    // The child's normals lie within its half angle of its axis.
    const double between = std::acos(std::clamp(dot(decoded, child.axis), -1.0, 1.0));
    const double half = std::acos(std::clamp(child.cosHalfAngle, -1.0, 1.0));
    minDot = std::min(minDot, std::cos(std::min(between + half, 3.141592653589793)));
  }
  encodeNormalCone(out, q, minDot);
}

namespace {

// The record of cell c from its subtree's summary; the cone and the offsets
// are the caller's.
void describeCell(const BuildCell& c, const Summary& s, OctreeCell& out) {
  out = OctreeCell{};
  for (int a = 0; a < 3; ++a) {
    out.boundsMin[a] = s.lo[a];
    out.boundsMax[a] = s.hi[a];
  }
  out.maxSplatRadius = s.maxRadius;
  out.nextSibling = c.nextSibling;
  out.topLevel = c.topLevel;
  out.level = c.level;
  out.depth = c.depth;
  out.childCount = c.childCount;
  out.flags = c.isLeaf() ? kCellFlagLeaf : 0;
}

// The records and summaries of the cells of one packet's subtree, from its
// points and its level-splats (laid out coarse first). Bounds, radius and
// normal sum: each cell's own splats, then merged bottom-up (children follow
// their parent in depth-first order); the cone's half angle needs every
// normal of the subtree against the axis.
void describePacket(const Octree& tree, const MadePacket& packet, std::span<OctreeCell> records,
                    std::span<Summary> summary) {
  const auto& cells = tree.cells;
  const std::span<const Splat> points(tree.points);
  const std::uint32_t root = tree.topLevelCells[packet.k];
  const std::size_t end =
      cells[root].nextSibling == kNoIndex ? cells.size() : std::size_t{cells[root].nextSibling};
  const auto own = [&](std::size_t i) {
    return packet.levelSplats.subspan(packet.cellBegin[i - root], packet.cellCount[i - root]);
  };
  const auto pointsOf = [&](const BuildCell& c) {
    return points.subspan(static_cast<std::size_t>(c.begin),
                          static_cast<std::size_t>(c.end - c.begin));
  };
  for (std::size_t i = root; i < end; ++i) {
    summary[i] = Summary{};
    if (cells[i].isLeaf()) accumulate(summary[i], pointsOf(cells[i]));
    accumulate(summary[i], own(i));
  }
  for (std::size_t i = end; i-- > root + 1;) merge(summary[cells[i].parent], summary[i]);

  const BuildCell& top = cells[root];
  for (std::size_t i = root; i < end; ++i) {
    const BuildCell& c = cells[i];
    const Summary& s = summary[i];
    OctreeCell& out = records[i];
    describeCell(c, s, out);
    const Vec3d axis = normalized(s.normalSum);
    if (s.unknownNormal || length(axis) == 0.0) {
      clearNormalCone(out);
    } else {
      // The subtree's points are one range; its level-splats are each cell's own.
      const ConeAxisQ q = quantizeConeAxis(axis);
      const Vec3d decoded = decodeConeAxis(q);
      double least = minDot(decoded, pointsOf(c), 1.0);
      const std::size_t subtreeEnd = c.nextSibling == kNoIndex ? end : std::size_t{c.nextSibling};
      for (std::size_t j = i; j < subtreeEnd; ++j) least = minDot(decoded, own(j), least);
      encodeNormalCone(out, q, least);
    }
    out.pointsOffset = static_cast<std::uint32_t>(packet.levelSplats.size() + c.begin - top.begin);
    out.pointsCount = static_cast<std::uint32_t>(c.end - c.begin);
    out.splatsCount = packet.cellCount[i - root];
    out.splatsOffset = out.splatsCount == 0 ? 0 : packet.cellBegin[i - root];
  }
}

// What is left once every packet is described: the cells above the top-level
// depth (their summaries merged from their children's, their cones from the
// children's cones), the top-level table and the manifest.
void finishDescription(const Octree& tree, const LevelSplats& ls, std::vector<Summary>& summary,
                       const PreprocessOptions& options, std::vector<CellNormals>* normals,
                       DatasetContent& content) {
  const auto& cells = tree.cells;
  const std::size_t n = cells.size();
  // From the back every child is done first.
  for (std::size_t i = n; i-- > 1;)
    if (cells[cells[i].parent].topLevel == kNoIndex) merge(summary[cells[i].parent], summary[i]);
  for (std::size_t i = n; i-- > 0;)
    if (cells[i].topLevel == kNoIndex) {
      describeCell(cells[i], summary[i], content.cells[i]);
      mergeChildCones(content.cells, i, {summary[i].normalSum, summary[i].unknownNormal});
    }
  if (normals != nullptr) {
    normals->resize(n);
    for (std::size_t i = 0; i < n; ++i)
      (*normals)[i] = {summary[i].normalSum, summary[i].unknownNormal};
  }

  content.topLevel.resize(tree.topLevelCells.size());
  for (std::size_t k = 0; k < tree.topLevelCells.size(); ++k) {
    const BuildCell& top = cells[tree.topLevelCells[k]];
    const std::uint64_t p = top.end - top.begin;
    const std::uint64_t l = ls.topLevelBegin[k + 1] - ls.topLevelBegin[k];
    if (p + l > std::numeric_limits<std::uint32_t>::max())
      throw UsageError("top-level cell " + std::to_string(k) + " holds " + std::to_string(p + l) +
                       " splats, more than 32-bit offsets address; use a deeper --top-level-depth");
    TopLevelCell& t = content.topLevel[k];
    t = TopLevelCell{};
    t.cellIndex = tree.topLevelCells[k];
    t.pointCount = static_cast<std::uint32_t>(p);
    t.levelSplatCount = static_cast<std::uint32_t>(l);
  }

  DatasetManifest& m = content.manifest;
  m.source = options.source;
  m.createdBy = "pointillist-preprocess";
  m.topLevelDepth = tree.topLevelDepth;
  m.maxDepth = options.octree.maxDepth;
  m.leafPoints = options.octree.leafPoints;
  m.levelSplatReduction = options.levelSplats.reduction;
}

}  // namespace

DatasetContent assembleDatasetContent(Octree tree, LevelSplats ls, const PreprocessOptions& options,
                                      std::vector<CellNormals>* normals) {
  const std::size_t n = tree.cells.size();
  DatasetContent content;
  content.cells.resize(n);
  std::vector<Summary> summary(n);
  parallelFor(
      tree.topLevelCells.size(), options.threads,
      [&](std::size_t k) {
        const std::uint32_t root = tree.topLevelCells[k];
        const std::size_t end = tree.cells[root].nextSibling == kNoIndex
                                    ? n
                                    : std::size_t{tree.cells[root].nextSibling};
        thread_local std::vector<std::uint32_t> begin;
        begin.resize(end - root);
        for (std::size_t i = root; i < end; ++i)
          begin[i - root] = static_cast<std::uint32_t>(ls.cellBegin[i] - ls.topLevelBegin[k]);
        const MadePacket packet{
            k,
            std::span<const Splat>(ls.splats).subspan(
                ls.topLevelBegin[k], ls.topLevelBegin[k + 1] - ls.topLevelBegin[k]),
            begin, std::span<const std::uint32_t>(ls.cellCount).subspan(root, end - root)};
        describePacket(tree, packet, content.cells, summary);
      },
      4);
  finishDescription(tree, ls, summary, options, normals, content);
  content.points = std::move(tree.points);
  content.levelSplats = std::move(ls.splats);
  return content;
}

DatasetContent buildDatasetContent(std::vector<Splat> points, const PreprocessOptions& options,
                                   const StageProgressFn& progress, const OctreeFrame* frame,
                                   std::vector<CellNormals>* normals) {
  auto stage = [&](const char* name) -> ProgressFn {
    if (!progress) return {};
    return
        [&progress, name](std::uint64_t done, std::uint64_t total) { progress(name, done, total); };
  };
  const std::uint64_t total = points.size();
  OctreeOptions octree = options.octree;
  octree.threads = options.threads;
  if (options.estimateNormals) octree.spareCapacity = options.neighbourAnchors.size();
  Octree tree = buildOctree(std::move(points), octree, stage("octree"), frame);
  if (options.estimateNormals) {
    PointCloud cloud;
    const std::size_t own = tree.points.size();
    cloud.splats = std::move(tree.points);
    // Into the room the octree left: moving the points would hold them twice.
    cloud.splats.insert(cloud.splats.end(), options.neighbourAnchors.begin(),
                        options.neighbourAnchors.end());
    cloud.hasColors = true;  // readers gave colourless points their grey already
    NormalOptions no;
    no.neighbours = options.radiusNeighbours;
    no.search = options.neighbourSearch;
    no.method = resolveNormalMethod(options.normalMethod, own);
    no.lattice = options.cubeLattice;
    if (no.method == NormalMethod::Moments && !(no.lattice.side > 0.0))
      no.lattice = chooseCubeLattice(std::span<const Splat>(cloud.splats.data(), own), tree.cubeMin,
                                     tree.cubeSize, options.cubePoints);
    no.onlyWhereMissing = true;
    no.threads = options.threads;
    no.sideReference = options.sideReference;
    no.progress = stage("normals and radii");
    estimateNormalsAndRadii(cloud, no);
    cloud.splats.resize(own);
    tree.points = std::move(cloud.splats);
  }
  const unsigned depth = options.topLevelDepth >= 0
                             ? static_cast<unsigned>(options.topLevelDepth)
                             : chooseTopLevelDepth(tree, options.targetPacketBytes);
  assignTopLevelCells(tree, depth);
  // After the top-level cells: a leaf's radius never looks above its own.
  if (options.radiiInLeaves)
    estimateRadiiInLeaves(tree, options.radiusNeighbours, options.threads, stage("radii"));
  if (options.packetSink) {
    // Each packet is described by the worker that made it and written by
    // this thread as soon as the ones before it are: no second pass over all
    // points and level-splats, and no array of all level-splats.
    if (options.instancing || options.statistical)
      throw Error(
          "internal error: packets are streamed only without --instanced and --statistical");
    DatasetContent content;
    content.cells.resize(tree.cells.size());
    std::vector<Summary> summary(tree.cells.size());
    LevelSplatHooks hooks;
    hooks.made = [&](const MadePacket& packet) {
      describePacket(tree, packet, content.cells, summary);
    };
    hooks.handOn = [&](const MadePacket& packet) {
      const BuildCell& top = tree.cells[tree.topLevelCells[packet.k]];
      options.packetSink(packet.levelSplats,
                         std::span<const Splat>(tree.points)
                             .subspan(static_cast<std::size_t>(top.begin),
                                      static_cast<std::size_t>(top.end - top.begin)));
    };
    hooks.keepSplats = false;
    const LevelSplats ls =
        buildLevelSplats(tree, options.levelSplats, stage("level-splats"), options.threads, hooks);
    if (progress) progress("cells", 0, total);
    finishDescription(tree, ls, summary, options, normals, content);
    content.points = std::move(tree.points);
    if (progress) progress("cells", total, total);
    return content;
  }
  LevelSplats ls =
      buildLevelSplats(tree, options.levelSplats, stage("level-splats"), options.threads);
  if (progress) progress("cells", 0, total);
  DatasetContent content = assembleDatasetContent(std::move(tree), std::move(ls), options, normals);
  if (progress) progress("cells", total, total);
  if (options.instancing) {
    const InstancingStats stats =
        addInstancedSections(content, *options.instancing, options.threads, stage("instancing"));
    if (options.instancingStats != nullptr) options.instancingStats->merge(stats);
  }
  if (options.statistical) {
    StatisticalOptions statistical = *options.statistical;
    statistical.threads = options.threads;
    const StatisticalStats stats =
        addStatisticalPackets(content, statistical, stage("statistical hierarchy"));
    if (options.statisticalStats != nullptr) *options.statisticalStats = stats;
  }
  return content;
}

}  // namespace pointillist::preprocess
