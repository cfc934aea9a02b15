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

DatasetContent assembleDatasetContent(Octree tree, LevelSplats ls, const PreprocessOptions& options,
                                      std::vector<CellNormals>* normals) {
  const auto& cells = tree.cells;
  const std::size_t n = cells.size();
  const std::span<const Splat> points(tree.points);
  const std::span<const Splat> splats(ls.splats);
  DatasetContent content;
  content.cells.resize(n);

  // Bounds, radius and normal sum: own splats in parallel, then merged
  // bottom-up (children follow their parent in depth-first order).
  std::vector<Summary> summary(n);
  parallelFor(n, options.threads, [&](std::size_t i) {
    const BuildCell& c = cells[i];
    if (c.isLeaf())
      accumulate(summary[i], points.subspan(static_cast<std::size_t>(c.begin),
                                            static_cast<std::size_t>(c.end - c.begin)));
    accumulate(summary[i],
               splats.subspan(static_cast<std::size_t>(ls.cellBegin[i]), ls.cellCount[i]));
  });
  for (std::size_t i = n; i-- > 1;) merge(summary[cells[i].parent], summary[i]);

  // The cone's half angle needs every normal of the subtree against the axis.
  parallelFor(n, options.threads, [&](std::size_t i) {
    const BuildCell& c = cells[i];
    const Summary& s = summary[i];
    OctreeCell& out = content.cells[i];
    out = OctreeCell{};
    for (int a = 0; a < 3; ++a) {
      out.boundsMin[a] = s.lo[a];
      out.boundsMax[a] = s.hi[a];
    }
    out.maxSplatRadius = s.maxRadius;
    const Vec3d axis = normalized(s.normalSum);
    if (c.topLevel == kNoIndex) {
      // Above the top-level depth: from the children's cones, below.
    } else if (s.unknownNormal || length(axis) == 0.0) {
      clearNormalCone(out);
    } else {
      // The subtree's points are one range; its level-splats are each cell's
      // own (a packet is laid out by level).
      const auto pts = points.subspan(static_cast<std::size_t>(c.begin),
                                      static_cast<std::size_t>(c.end - c.begin));
      const ConeAxisQ q = quantizeConeAxis(axis);
      const Vec3d decoded = decodeConeAxis(q);
      double least = minDot(decoded, pts, 1.0);
      const std::size_t end = c.nextSibling == kNoIndex ? n : std::size_t{c.nextSibling};
      for (std::size_t j = i; j < end; ++j)
        least = minDot(decoded,
                       splats.subspan(static_cast<std::size_t>(ls.cellBegin[j]), ls.cellCount[j]),
                       least);
      encodeNormalCone(out, q, least);
    }
    out.nextSibling = c.nextSibling;
    out.topLevel = c.topLevel;
    out.level = c.level;
    out.depth = c.depth;
    out.childCount = c.childCount;
    out.flags = c.isLeaf() ? kCellFlagLeaf : 0;
    if (c.topLevel != kNoIndex) {
      const BuildCell& top = cells[tree.topLevelCells[c.topLevel]];
      const std::uint64_t packetSplats =
          ls.topLevelBegin[c.topLevel + 1] - ls.topLevelBegin[c.topLevel];
      out.pointsOffset = static_cast<std::uint32_t>(packetSplats + c.begin - top.begin);
      out.pointsCount = static_cast<std::uint32_t>(c.end - c.begin);
      out.splatsCount = ls.cellCount[i];
      // Level-splats come laid out as packets are (coarse first).
      out.splatsOffset =
          ls.cellCount[i] == 0
              ? 0
              : static_cast<std::uint32_t>(ls.cellBegin[i] - ls.topLevelBegin[c.topLevel]);
    }
  });

  // Children follow their parent, so from the back every child is done first.
  for (std::size_t i = n; i-- > 0;)
    if (cells[i].topLevel == kNoIndex)
      mergeChildCones(content.cells, i, {summary[i].normalSum, summary[i].unknownNormal});
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
                                     tree.cubeSize);
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
  LevelSplatPacketFn onPacket;
  if (options.packetSink) {
    if (options.instancing || options.statistical)
      throw Error(
          "internal error: packets are streamed only without --instanced and --statistical");
    onPacket = [&](std::size_t k, std::span<const Splat> levelSplats) {
      const BuildCell& top = tree.cells[tree.topLevelCells[k]];
      options.packetSink(levelSplats, std::span<const Splat>(tree.points)
                                          .subspan(static_cast<std::size_t>(top.begin),
                                                   static_cast<std::size_t>(top.end - top.begin)));
    };
  }
  LevelSplats ls =
      buildLevelSplats(tree, options.levelSplats, stage("level-splats"), options.threads, onPacket);
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
