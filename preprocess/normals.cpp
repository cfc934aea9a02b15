#include "preprocess/normals.hpp"

#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <cmath>
#include <cstdint>
#include <limits>
#include <nanoflann.hpp>
#include <numeric>
#include <optional>
#include <span>
#include <thread>
#include <vector>

#include "common/errors.hpp"
#include "common/geometry.hpp"
#include "preprocess/cube_normals.hpp"
#include "preprocess/eigen_batch.hpp"
#include "preprocess/leaf_distances.hpp"
#include "preprocess/neighbour_grid.hpp"
#include "preprocess/parallel.hpp"
#include "preprocess/selection.hpp"
#include "preprocess/splat_kd_tree.hpp"

namespace pointillist::preprocess {

namespace {

using KdTree = SplatKdTree;

Vec3d position(const Splat& s) {
  return {s.position[0], s.position[1], s.position[2]};
}

bool hasRadius(const Splat& s) {
  return s.radius > 0.0f && std::isfinite(s.radius);
}

float dotNormals(const Splat& a, const Splat& b) {
  return a.normal[0] * b.normal[0] + a.normal[1] * b.normal[1] + a.normal[2] * b.normal[2];
}
void flip(Splat& s) {
  for (float& c : s.normal) c = -c;
}

// Normals across an edge closer than this to perpendicular do not pass their
// side on: at creases and where surfaces cross (a trunk through the ground)
// the sign would be a coin toss.
constexpr float kReliable = 0.5f;

// Prim's queue as buckets of weight (a bucket queue): O(1) a push and a pop
// where a binary heap over tens of millions of edges was half the stage.
// Edges within one bucket (1/2048 of the reliable range) go last in first out.
struct Edge {
  std::uint32_t to;
  std::uint32_t from;
};
class BucketQueue {
 public:
  static constexpr std::size_t kBuckets = 2048;
  static constexpr float kMaxWeight = 1.0f - kReliable;

  void push(float w, Edge e) {
    const auto b = std::min(kBuckets, static_cast<std::size_t>(w / kMaxWeight * kBuckets));
    buckets_[b].push_back(e);
    lowest_ = std::min(lowest_, b);
    ++size_;
  }
  bool empty() const { return size_ == 0; }
  Edge pop() {
    while (buckets_[lowest_].empty()) ++lowest_;
    const Edge e = buckets_[lowest_].back();
    buckets_[lowest_].pop_back();
    --size_;
    return e;
  }

 private:
  std::vector<std::vector<Edge>> buckets_ = std::vector<std::vector<Edge>>(kBuckets + 1);
  std::size_t lowest_ = kBuckets + 1;
  std::size_t size_ = 0;
};

// Consistent orientation (see normals.hpp), in blocks of orientBlockPoints
// consecutive points (spatial blocks: the points are in Morton order when
// a preprocess gets here), so the blocks run on all cores:
//  1. Each block alone: Prim's algorithm over the reliable edges inside it,
//     from the block's anchors, then from its highest unreached point, and so
//     on, each piece keeping the sign of where it started. The figures the
//     turning rules need are sums over a piece's points, so pieces combine.
//  2. The pieces as a graph, joined by every reliable edge between two of
//     them (across blocks, and inside one where a neighbour list named a
//     point its Prim did not reach): Prim's algorithm again, most parallel
//     edge first, from the anchored pieces, then from the highest unreached
//     piece, each whole component of pieces then turned by the rules.
// A cloud within one block is oriented as by one pass of Prim's algorithm.

// A block's piece: what the turning rules need, as sums over its points.
struct Piece {
  std::uint32_t seed = 0;  // its highest point (where it was grown from)
  bool anchored = false;   // reached from anchors: its side is fixed
  double size = 0.0, up = 0.0, flatness = 0.0;
  Vec3d offset{};              // sum of (position - centroid)
  Vec3d normals{};             // sum of normals
  double outward = 0.0;        // sum of (position - centroid) . normal
  double referenceVote = 0.0;  // points agreeing with their reference side, less those that do not
};

// Edges between pieces (both ways), with the dot product of the two normals
// as phase 1 left them.
struct PieceEdge {
  std::uint32_t from, to;
  float dot;
};

struct OrientContext {
  std::vector<Splat>& splats;
  const std::vector<std::uint8_t>& needNormal;
  const std::vector<std::uint8_t>& isAnchor;  // side fixed from the start
  std::span<const std::uint32_t> neighbours;
  std::size_t k;
  Vec3d centroid;
  const std::function<bool(const Splat&, float[3])>& sideReference;
};

// Phase 1 for points [begin, end): piece[i] = the block's piece index + 1.
// seeds: the block's points, highest first.
std::vector<Piece> orientBlock(const OrientContext& c, std::uint32_t begin, std::uint32_t end,
                               std::span<const std::uint32_t> seeds,
                               std::vector<std::uint32_t>& piece) {
  std::vector<Splat>& splats = c.splats;
  const std::size_t k = c.k;
  const auto inBlock = [&](std::uint32_t i) { return i >= begin && i < end; };
  std::vector<float> best(end - begin, std::numeric_limits<float>::infinity());
  BucketQueue heap;
  const auto offer = [&](std::uint32_t from, std::uint32_t to) {
    const float w = 1.0f - std::abs(dotNormals(splats[from], splats[to]));
    if (w <= BucketQueue::kMaxWeight && w < best[to - begin]) {
      best[to - begin] = w;
      // Its list is read when it leaves the queue: one miss fewer in the
      // chain of dependent loads that Prim's growth is.
      __builtin_prefetch(&c.neighbours[to * k]);
      heap.push(w, {to, from});
    }
  };
  const auto pushEdges = [&](std::uint32_t from) {
    if (!c.needNormal[from]) return;  // only estimated points have neighbour lists
    for (std::size_t j = 0; j < k; ++j) {
      const std::uint32_t to = c.neighbours[from * k + j];
      if (inBlock(to) && piece[to] == 0) offer(from, to);
    }
  };
  const auto grow = [&](std::uint32_t mark) {
    while (!heap.empty()) {
      const Edge e = heap.pop();
      if (piece[e.to] != 0) continue;
      if (dotNormals(splats[e.to], splats[e.from]) < 0.0f) flip(splats[e.to]);
      piece[e.to] = mark;
      pushEdges(e.to);
    }
  };

  std::vector<Piece> pieces;
  // Anchors first: they reach out through their own lists and through the
  // lists of points that name them (neighbour lists are not symmetric).
  bool anyAnchor = false;
  for (std::uint32_t i = begin; i < end; ++i) {
    if (c.isAnchor[i]) {
      piece[i] = 1;
      anyAnchor = true;
    }
  }
  if (anyAnchor) {
    pieces.push_back({});
    pieces.back().anchored = true;
    for (std::uint32_t i = begin; i < end; ++i) {
      if (piece[i] == 1) {
        pushEdges(i);
        continue;
      }
      for (std::size_t j = 0; c.needNormal[i] && j < k; ++j) {
        const std::uint32_t from = c.neighbours[i * k + j];
        if (inBlock(from) && piece[from] == 1) offer(from, i);
      }
    }
    grow(1);
  }
  for (const std::uint32_t seed : seeds) {
    if (piece[seed] != 0) continue;
    pieces.push_back({});
    pieces.back().seed = seed;
    const auto mark = static_cast<std::uint32_t>(pieces.size());
    piece[seed] = mark;
    pushEdges(seed);
    grow(mark);
  }
  for (std::uint32_t i = begin; i < end; ++i) {
    Piece& p = pieces[piece[i] - 1];
    const Splat& s = splats[i];
    const Vec3d offset = sub(position(s), c.centroid);
    const Vec3d normal = {s.normal[0], s.normal[1], s.normal[2]};
    p.size += 1.0;
    p.up += normal[2];
    p.flatness += std::abs(normal[2]);
    p.offset = add(p.offset, offset);
    p.normals = add(p.normals, normal);
    p.outward += dot(offset, normal);
    float reference[3];
    if (c.sideReference && c.sideReference(s, reference)) {
      const double agree = normal[0] * static_cast<double>(reference[0]) +
                           normal[1] * static_cast<double>(reference[1]) +
                           normal[2] * static_cast<double>(reference[2]);
      p.referenceVote += agree > 0.0 ? 1.0 : agree < 0.0 ? -1.0 : 0.0;
    }
  }
  return pieces;
}

void orient(std::vector<Splat>& splats, const std::vector<std::uint8_t>& needNormal,
            const std::vector<std::uint8_t>& anchored, bool recomputed,
            std::span<const std::uint32_t> neighbours, std::size_t k, const NormalOptions& options,
            std::uint64_t total) {
  const std::size_t n = splats.size();
  std::vector<std::uint8_t> isAnchor(n);
  // Recomputed normals already took the side of their old ones.
  for (std::size_t i = 0; i < n; ++i) isAnchor[i] = recomputed ? anchored[i] : !needNormal[i];
  Vec3d centroid{};
  for (const Splat& s : splats) centroid = add(centroid, position(s));
  centroid = scale(centroid, 1.0 / static_cast<double>(n));
  const OrientContext context{splats,   needNormal,           isAnchor, neighbours, k,
                              centroid, options.sideReference};

  // Seeds highest first, equal heights by index: a stable radix sort of
  // (z as an order-preserving integer, index) packed in 64 bits.
  const auto seedKey = [&](std::size_t i) {
    const float z = splats[i].position[2] == 0.0f ? 0.0f : splats[i].position[2];  // no -0
    const auto bits = std::bit_cast<std::uint32_t>(z);
    const std::uint32_t ascending = (bits & 0x80000000u) != 0 ? ~bits : bits | 0x80000000u;
    return std::uint64_t{~ascending} << 32 | i;
  };
  const std::size_t blockPoints = std::max<std::size_t>(1, options.orientBlockPoints);
  const std::size_t blocks = (n + blockPoints - 1) / blockPoints;

  // Phase 1, on all threads; progress from this thread.
  std::vector<std::uint32_t> piece(n, 0);
  std::vector<std::vector<Piece>> blockPieces(blocks);
  std::atomic<std::uint64_t> oriented{0};
  const auto caller = std::this_thread::get_id();
  parallelFor(
      blocks, options.threads,
      [&](std::size_t b) {
        const auto begin = static_cast<std::uint32_t>(b * blockPoints);
        const auto end = static_cast<std::uint32_t>(std::min(n, (b + 1) * blockPoints));
        // The block's seeds, sorted here: a sort of the whole cloud, then
        // dealt out to the blocks, ran mostly on one core.
        std::vector<std::uint64_t> order(end - begin);
        for (std::uint32_t i = begin; i < end; ++i) order[i - begin] = seedKey(i);
        radixSort(
            order, 32, 64, [](std::uint64_t item) { return item; }, {}, 1);
        std::vector<std::uint32_t> seeds(order.size());
        for (std::size_t j = 0; j < order.size(); ++j)
          seeds[j] = static_cast<std::uint32_t>(order[j]);
        order = {};
        blockPieces[b] = orientBlock(context, begin, end, seeds, piece);
        const std::uint64_t done = oriented += end - begin;
        if (options.progress && std::this_thread::get_id() == caller)
          options.progress(n + done * 9 / 10, total);
      },
      1);

  // Pieces numbered across blocks.
  std::vector<std::uint32_t> firstPiece(blocks + 1, 0);
  for (std::size_t b = 0; b < blocks; ++b)
    firstPiece[b + 1] = firstPiece[b] + static_cast<std::uint32_t>(blockPieces[b].size());
  std::vector<Piece> pieces;
  pieces.reserve(firstPiece[blocks]);
  for (auto& list : blockPieces) {
    pieces.insert(pieces.end(), list.begin(), list.end());
    list = {};
  }
  parallelFor(
      n, options.threads, [&](std::size_t i) { piece[i] += firstPiece[i / blockPoints] - 1; },
      std::size_t{1} << 16);

  // Reliable edges between pieces, per block on all threads, then both ways
  // in one list sorted by the piece they leave.
  std::vector<std::vector<PieceEdge>> blockEdges(blocks);
  parallelFor(
      blocks, options.threads,
      [&](std::size_t b) {
        const std::size_t end = std::min(n, (b + 1) * blockPoints);
        for (std::size_t i = b * blockPoints; i < end; ++i) {
          if (!needNormal[i]) continue;
          for (std::size_t j = 0; j < k; ++j) {
            const std::uint32_t to = neighbours[i * k + j];
            if (piece[to] == piece[i]) continue;
            const float d = dotNormals(splats[i], splats[to]);
            if (1.0f - std::abs(d) <= BucketQueue::kMaxWeight)
              blockEdges[b].push_back({piece[i], piece[to], d});
          }
        }
      },
      1);
  std::vector<std::uint32_t> edgeStart(pieces.size() + 1, 0);
  for (const auto& list : blockEdges)
    for (const PieceEdge& e : list) {
      ++edgeStart[e.from + 1];
      ++edgeStart[e.to + 1];
    }
  for (std::size_t p = 0; p < pieces.size(); ++p) edgeStart[p + 1] += edgeStart[p];
  std::vector<PieceEdge> edges(edgeStart.back());
  {
    std::vector<std::uint32_t> at(edgeStart.begin(), edgeStart.end() - 1);
    for (auto& list : blockEdges) {
      for (const PieceEdge& e : list) {
        edges[at[e.from]++] = e;
        edges[at[e.to]++] = {e.to, e.from, e.dot};
      }
      list = {};
    }
  }

  // Phase 2: Prim over the pieces. side[p]: +1 or -1 to phase 1's normals,
  // 0 while unreached.
  std::vector<std::int8_t> side(pieces.size(), 0);
  std::vector<float> best(pieces.size(), std::numeric_limits<float>::infinity());
  BucketQueue heap;
  std::vector<std::uint32_t> members;
  const auto pushPieceEdges = [&](std::uint32_t from) {
    for (std::uint32_t e = edgeStart[from]; e < edgeStart[from + 1]; ++e) {
      const std::uint32_t to = edges[e].to;
      const float w = 1.0f - std::abs(edges[e].dot);
      if (side[to] == 0 && w < best[to]) {
        best[to] = w;
        heap.push(w, {to, e});  // `from` holds the edge's index
      }
    }
  };
  const auto grow = [&] {
    while (!heap.empty()) {
      const Edge step = heap.pop();
      if (side[step.to] != 0) continue;
      const PieceEdge& e = edges[step.from];
      side[step.to] = static_cast<std::int8_t>(e.dot < 0.0f ? -side[e.from] : side[e.from]);
      members.push_back(step.to);
      pushPieceEdges(step.to);
    }
  };
  for (std::uint32_t p = 0; p < pieces.size(); ++p) {
    if (pieces[p].anchored) side[p] = 1;
  }
  for (std::uint32_t p = 0; p < pieces.size(); ++p) {
    if (pieces[p].anchored) pushPieceEdges(p);
  }
  grow();

  // The rest: components of pieces, each grown from its highest piece with
  // the sign phase 1 gave it, then turned as a whole:
  //  1. mostly horizontal and facing one way (terrain, floors, roofs): up
  //     (a closed surface, such as a flat torus, faces both ways: rule 2);
  //  2. else away from its own centre (closed objects get outward normals),
  //     for flat pieces away from the centre of the whole cloud.
  std::vector<std::uint32_t> byHeight;
  for (std::uint32_t p = 0; p < pieces.size(); ++p)
    if (!pieces[p].anchored) byHeight.push_back(p);
  std::sort(byHeight.begin(), byHeight.end(), [&](std::uint32_t a, std::uint32_t b) {
    return seedKey(pieces[a].seed) < seedKey(pieces[b].seed);
  });
  for (const std::uint32_t start : byHeight) {
    if (side[start] != 0) continue;
    side[start] = 1;
    members.assign(1, start);
    pushPieceEdges(start);
    grow();
    double size = 0.0, up = 0.0, flatness = 0.0, outward = 0.0, vote = 0.0;
    Vec3d offset{}, normals{};
    for (const std::uint32_t p : members) {
      const Piece& q = pieces[p];
      const double sign = side[p];
      vote += sign * q.referenceVote;
      size += q.size;
      up += sign * q.up;
      flatness += q.flatness;
      offset = add(offset, q.offset);
      normals = add(normals, scale(q.normals, sign));
      outward += sign * q.outward;
    }
    bool turn = false;
    if (vote != 0.0) {
      turn = vote < 0.0;  // 0. the side a reference gives, if any
    } else if (flatness > 0.6 * size && std::abs(up) > 0.5 * flatness) {
      turn = up < 0;
    } else {
      const Vec3d centre = scale(offset, 1.0 / size);  // from the cloud's centroid
      const double own = outward - dot(centre, normals);
      turn = std::abs(own) > 1e-9 * size ? own < 0 : outward < 0;
    }
    if (turn)
      for (const std::uint32_t p : members) side[p] = static_cast<std::int8_t>(-side[p]);
  }
  parallelFor(
      n, options.threads,
      [&](std::size_t i) {
        if (side[piece[i]] < 0) flip(splats[i]);
      },
      std::size_t{1} << 16);
  if (options.progress) options.progress(total, total);
}

// Points whose neighbours all coincide (or whose block spans no area) got
// radius 0: they take the median of the rest.
void fillZeroRadii(std::vector<Splat>& splats) {
  if (std::all_of(splats.begin(), splats.end(), [](const Splat& s) { return s.radius > 0.0f; }))
    return;
  std::vector<float> radii;
  for (const Splat& s : splats) {
    if (s.radius > 0.0f) radii.push_back(s.radius);
  }
  float fallback = 1.0f;
  if (!radii.empty()) {
    std::nth_element(radii.begin(), radii.begin() + static_cast<std::ptrdiff_t>(radii.size() / 2),
                     radii.end());
    fallback = radii[radii.size() / 2];
  }
  for (Splat& s : splats) {
    if (!(s.radius > 0.0f)) s.radius = fallback;
  }
}

// NormalMethod::Moments: each cube's block gives the normal and radius of
// the cube's points. The cubes, as points at their centroids, are oriented
// as points are (orient above, over their neighbour cubes nearest in the
// lattice); a cube mostly of points whose normal is kept is an anchor, on
// the side those normals take.
void orientedMomentNormals(std::vector<Splat>& splats, const std::vector<std::uint8_t>& needNormal,
                           const std::vector<std::uint8_t>& needRadius,
                           const std::vector<std::uint8_t>& anchored, bool anyNormal,
                           bool recomputed, const NormalOptions& options, std::uint64_t total) {
  const std::size_t n = splats.size();
  CubeLattice lattice = options.lattice;
  if (!(lattice.side > 0.0)) {
    const PointBounds bounds = pointBounds(splats, options.threads);
    const OctreeCube cube = boundingCube(bounds.lo, bounds.hi);
    lattice = chooseCubeLattice(splats, cube.min, cube.size);
  }
  // Six of the 26 cubes around (faces first): enough to join a surface's
  // cubes, and eight oriented the bunny, the building and the ball scans the
  // same at a third more cost.
  constexpr std::size_t kCubeNeighbours = 6;
  const CubeBlocks blocks(splats, lattice, kCubeNeighbours, options.threads);
  const std::size_t cubes = blocks.cubes();
  if (options.progress) options.progress(n, total);

  std::vector<Splat> representatives;
  if (anyNormal) {
    resizePopulated(representatives, cubes, options.threads);
    std::vector<std::uint8_t> everyCube(cubes, 1), anchoredCube(cubes, 0);
    parallelFor(
        cubes, options.threads,
        [&](std::size_t c) {
          Splat& r = representatives[c];
          for (std::size_t a = 0; a < 3; ++a) {
            r.position[a] = blocks.centroid(c)[a];
            r.normal[a] = blocks.blockNormal(c)[a];
          }
          // A cube is an anchor where kept normals are at least half its
          // points and agree with its own normal as an edge must to pass a
          // side on (within 60 degrees on average). Out of core, a cube on a
          // chunk's border holds the earlier chunk's points beside its own;
          // where a thin part (the bunny's ear) puts both its faces in one
          // cube, a few points of one face anchored the other: the 10 M
          // bunny scan in 6 chunks turned 2 % of its points the wrong way.
          double agree = 0.0;
          std::size_t anchors = 0, others = 0;
          for (const std::uint32_t i : blocks.pointsOf(c)) {
            if (!anchored[i]) {
              ++others;
              continue;
            }
            ++anchors;
            agree += static_cast<double>(dotNormals(r, splats[i]));
          }
          if (anchors == 0) return;
          if (agree < 0.0) flip(r);
          const bool agreeing =
              std::abs(agree) >= static_cast<double>(kReliable) * static_cast<double>(anchors);
          anchoredCube[c] = agreeing && anchors >= others ? 1 : 0;
        },
        4096);
    NormalOptions cubeOptions;
    cubeOptions.threads = options.threads;
    cubeOptions.orientBlockPoints = options.orientBlockPoints;
    if (options.sideReference) {
      // A cube's reference: the sum of its points' references.
      cubeOptions.sideReference = [&](const Splat& r, float normal[3]) {
        const auto c = static_cast<std::size_t>(&r - representatives.data());
        float sum[3] = {0.0f, 0.0f, 0.0f};
        bool any = false;
        for (const std::uint32_t i : blocks.pointsOf(c)) {
          float reference[3];
          if (!options.sideReference(splats[i], reference)) continue;
          any = true;
          for (int a = 0; a < 3; ++a) sum[a] += reference[a];
        }
        for (int a = 0; a < 3; ++a) normal[a] = sum[a];
        return any;
      };
    }
    if (options.progress) {
      // orient counts cubes from `cubes` to 2 * cubes; points from n to 2n here.
      cubeOptions.progress = [&](std::uint64_t done, std::uint64_t) {
        options.progress(done * n / std::max<std::size_t>(cubes, 1), total);
      };
    }
    orient(representatives, everyCube, anchoredCube, true, blocks.neighbours(), kCubeNeighbours,
           cubeOptions, 2 * static_cast<std::uint64_t>(cubes));
  }
  parallelFor(
      cubes, options.threads,
      [&](std::size_t c) {
        // The points' normal on the side the orientation gave the block's.
        Splat side{};
        if (anyNormal) {
          float agree = 0.0f;
          for (std::size_t a = 0; a < 3; ++a) {
            side.normal[a] = blocks.normal(c)[a];
            agree += side.normal[a] * representatives[c].normal[a];
          }
          if (agree < 0.0f) flip(side);
        }
        // Points in the octree's order, cubes in the lattice's: fetched ahead.
        if (c + 16 < cubes)
          for (const std::uint32_t i : blocks.pointsOf(c + 16)) __builtin_prefetch(&splats[i], 1);
        for (const std::uint32_t i : blocks.pointsOf(c)) {
          if (anyNormal && needNormal[i]) {
            // A recomputed normal keeps the side of the one it replaces.
            const bool turn = recomputed && anchored[i] && dotNormals(side, splats[i]) < 0.0f;
            for (int a = 0; a < 3; ++a)
              splats[i].normal[a] = turn ? -side.normal[a] : side.normal[a];
          }
          if (needRadius[i]) splats[i].radius = blocks.radius(c);
        }
      },
      4096);
}

}  // namespace

void estimateNormalsAndRadii(PointCloud& cloud, const NormalOptions& options) {
  std::vector<Splat>& splats = cloud.splats;
  const std::size_t n = splats.size();
  if (n == 0) return;
  if (!cloud.hasColors) {
    for (Splat& s : splats) {
      if ((s.color[0] | s.color[1] | s.color[2] | s.color[3]) == 0) {
        s.color[0] = s.color[1] = s.color[2] = kDefaultGrey;
        s.color[3] = 255;
      }
    }
  }
  if (n >= std::numeric_limits<std::uint32_t>::max()) {
    throw UsageError(cloud.source + ": too many points for normal estimation in one piece");
  }
  if (options.neighbours < 3) throw UsageError("normal estimation needs at least 3 neighbours");

  // On all threads, the flags' pages mapped first: one pass over the cloud
  // on one core held the other waiting.
  std::vector<std::uint8_t> needNormal, needRadius, anchored;
  for (auto* flags : {&needNormal, &needRadius, &anchored})
    resizePopulated(*flags, n, options.threads);
  constexpr std::size_t kFlagBlock = std::size_t{1} << 16;
  std::atomic<bool> anyNormalSeen{false}, anyRadiusSeen{false};
  parallelFor((n + kFlagBlock - 1) / kFlagBlock, options.threads,
              [&](std::size_t b) {
                bool normals = false, radii = false;
                for (std::size_t i = b * kFlagBlock; i < std::min(n, (b + 1) * kFlagBlock); ++i) {
                  needNormal[i] = !options.onlyWhereMissing || !hasNormal(splats[i]);
                  needRadius[i] = !options.onlyWhereMissing || !hasRadius(splats[i]);
                  anchored[i] = hasNormal(splats[i]);  // a normal we trust for orientation
                  normals = normals || needNormal[i];
                  radii = radii || needRadius[i];
                }
                if (normals) anyNormalSeen.store(true, std::memory_order_relaxed);
                if (radii) anyRadiusSeen.store(true, std::memory_order_relaxed);
              },
              1);
  const bool anyNormal = anyNormalSeen.load(), anyRadius = anyRadiusSeen.load();
  if (!anyNormal && !anyRadius) {
    cloud.hasNormals = cloud.hasRadii = true;
    return;
  }
  const std::uint64_t total = 2 * static_cast<std::uint64_t>(n);
  if (n == 1) {
    if (needNormal[0]) splats[0].normal[2] = 1.0f;
    if (needRadius[0]) splats[0].radius = 1.0f;
    cloud.hasNormals = cloud.hasRadii = true;
    if (options.progress) options.progress(total, total);
    return;
  }

  if (resolveNormalMethod(options.method, n) == NormalMethod::Moments) {
    if (options.progress) options.progress(0, total);
    orientedMomentNormals(splats, needNormal, needRadius, anchored, anyNormal,
                          !options.onlyWhereMissing, options, total);
    if (anyRadius) fillZeroRadii(splats);
    cloud.hasNormals = cloud.hasRadii = true;
    if (options.progress) options.progress(total, total);
    return;
  }

  if (options.progress) options.progress(0, total);  // the search tree's build is ours
  const std::size_t k = std::min(static_cast<std::size_t>(options.neighbours), n - 1);
  SplatCloudAdaptor adaptor{splats};
  std::optional<KdTree> tree;
  std::optional<NeighbourGrid> grid;
  if (options.search == NeighbourSearch::KdTree)
    tree.emplace(3, adaptor, nanoflann::KDTreeSingleIndexAdaptorParams(16));
  else
    grid.emplace(splats, 6.0, options.threads);

  // Neighbour lists (without the point itself) are kept for the orientation pass.
  std::vector<std::uint32_t> neighbours(anyNormal ? n * k : 0);
  std::vector<Splat> old(anyNormal && !options.onlyWhereMissing ? splats : std::vector<Splat>{});
  const float radiusFactor = std::sqrt(3.0f / static_cast<float>(k));
  std::atomic<std::uint64_t> done{0};

  // Covariances wait in blocks for their eigenvectors: one at a time, the
  // solve is a chain of divisions and roots; a block is solved in SIMD.
  struct PendingNormals {
    std::vector<std::uint32_t> points;
    std::vector<Sym3> covariances;
    std::vector<SmallestEigen3> eigen;
  };
  constexpr std::size_t kPendingNormals = 256;
  const auto finishNormals = [&](PendingNormals& pending) {
    pending.eigen.resize(pending.points.size());
    smallestEigen3Batch(pending.covariances, pending.eigen);
    for (std::size_t j = 0; j < pending.points.size(); ++j) {
      const std::uint32_t i = pending.points[j];
      const SmallestEigen3& eigen = pending.eigen[j];
      const Vec3d normal = eigen.values[2] > 0 ? eigen.vector : Vec3d{0, 0, 1};
      // Divided, not multiplied by a reciprocal as normalized() does: the
      // stored normals keep their exact bits.
      const double len = length(normal);
      for (std::size_t d = 0; d < 3; ++d) splats[i].normal[d] = static_cast<float>(normal[d] / len);
      // A recomputed normal keeps the side of the one it replaces.
      if (!old.empty() && hasNormal(old[i]) && dotNormals(splats[i], old[i]) < 0) flip(splats[i]);
    }
    pending.points.clear();
    pending.covariances.clear();
  };

  // One point with its m nearest (index, squared distance), nearest first.
  const auto handle = [&](PendingNormals& pending, std::size_t i, const std::uint32_t* index,
                          const float* distance, std::size_t m) {
    if (needRadius[i]) splats[i].radius = std::sqrt(distance[m - 1]) * radiusFactor;
    if (!needNormal[i]) return;
    // Two passes (mean, then centred products) rather than
    // CovarianceAccumulator: its one-pass sums would change the normals' bits.
    Vec3d mean = position(splats[i]);
    for (std::size_t j = 0; j < m; ++j) mean = add(mean, position(splats[index[j]]));
    for (double& c : mean) c /= static_cast<double>(m + 1);
    Sym3 cov{};
    addOuterProduct(cov, sub(position(splats[i]), mean));
    for (std::size_t j = 0; j < m; ++j) addOuterProduct(cov, sub(position(splats[index[j]]), mean));
    pending.points.push_back(static_cast<std::uint32_t>(i));
    pending.covariances.push_back(cov);
    if (pending.points.size() == kPendingNormals) finishNormals(pending);
    std::copy(index, index + m, neighbours.begin() + static_cast<std::ptrdiff_t>(i * k));
    if (m < k) {  // fewer neighbours than asked (tiny clouds): repeat the last
      std::fill(neighbours.begin() + static_cast<std::ptrdiff_t>(i * k + m),
                neighbours.begin() + static_cast<std::ptrdiff_t>((i + 1) * k), index[m - 1]);
    }
  };

  // Work items: cubes of the grid (their points share one gathering of
  // candidates), or points for the kd-tree.
  const std::size_t items = grid ? grid->occupiedCubes() : n;
  const auto work = [&](std::size_t begin, std::size_t end, bool reports) {
    std::vector<std::uint32_t> index(k + 1);
    std::vector<float> distance(k + 1);
    PendingNormals pending;
    std::uint64_t unreported = 0;
    for (std::size_t item = begin; item < end; ++item) {
      if (grid) {
        grid->nearestInCube(
            item, k, [&](std::size_t i, const std::uint32_t* idx, const float* d2, std::size_t m) {
              ++unreported;
              if (needNormal[i] || needRadius[i]) handle(pending, i, idx, d2, m);
            });
      } else {
        const std::size_t i = item;
        ++unreported;
        if (!needNormal[i] && !needRadius[i]) continue;
        const std::size_t found =
            tree->knnSearch(splats[i].position, k + 1, index.data(), distance.data());
        // Drop the point itself (with duplicates it need not come first).
        std::size_t self = found;
        for (std::size_t j = 0; j < found; ++j) {
          if (index[j] == i) self = j;
        }
        if (self == found) self = found - 1;
        std::size_t m = 0;
        for (std::size_t j = 0; j < found; ++j) {
          if (j == self) continue;
          index[m] = index[j];
          distance[m] = distance[j];
          ++m;
        }
        handle(pending, i, index.data(), distance.data(), m);
      }
      if (unreported >= 1024) {
        const std::uint64_t now = done.fetch_add(unreported) + unreported;
        unreported = 0;
        if (reports && options.progress) options.progress(now, total);
      }
    }
    finishNormals(pending);
    done += unreported;
  };

  std::size_t threads =
      options.threads > 0
          ? options.threads
          : std::max<std::size_t>(1, std::min<std::size_t>(8, std::thread::hardware_concurrency()));
  if (n < 20000) threads = 1;
  {
    // Blocks of items taken in turn: halves fixed up front left one core
    // idle while the other finished a denser half.
    constexpr std::size_t kBlockItems = 512;
    std::atomic<std::size_t> next{0};
    const auto worker = [&](bool reports) {
      for (std::size_t begin; (begin = next.fetch_add(kBlockItems)) < items;)
        work(begin, std::min(items, begin + kBlockItems), reports);
    };
    std::vector<std::jthread> pool;
    for (std::size_t t = 1; t < threads; ++t) pool.emplace_back(worker, false);
    worker(true);
  }
  if (options.progress) options.progress(n, total);

  if (anyRadius) fillZeroRadii(splats);

  if (anyNormal) orient(splats, needNormal, anchored, !old.empty(), neighbours, k, options, total);
  cloud.hasNormals = cloud.hasRadii = true;
  if (options.progress) options.progress(total, total);
}

namespace {

// sqrt(3 area / (pi n)) for the points, or 0 when they do not span an area
// (fewer than three, or collinear). A leaf's points span about
// 12 sqrt(l1 l2), l1 >= l2 the two largest eigenvalues of their covariance
// (exact for a uniformly sampled rectangle: l = side^2 / 12).
float densityRadius(std::span<const Splat> points) {
  if (points.size() < 3) return 0.0f;
  CovarianceAccumulator acc;
  for (const Splat& p : points) acc.add(position(p));
  const SmallestEigen3 eigen = smallestEigen3(acc.covariance());
  return static_cast<float>(
      radiusFromSpread(eigen.values[2], eigen.values[1], static_cast<double>(points.size())));
}

// sqrt(3 / k) times the median, over a few points spread through the leaf
// (by index), of the distance to the k-th nearest of the leaf's own points
// (the point itself, at distance 0, counts as the 0-th); 0 for leaves of at
// most k points.
float sampledRadius(std::span<const Splat> leaf, std::size_t k, float factor) {
  const std::size_t m = leaf.size();
  if (m <= k) return 0.0f;
  const std::size_t samples = std::min(m, kLeafRadiusSamples);
  // Leaves are many: buffers kept on the thread, no allocation each.
  thread_local std::vector<float> distances, spare;
  thread_local LeafColumns columns;
  const bool ranked = m <= LeafColumns::kMaxPoints;
  if (ranked) {
    columns.assign(leaf);
  } else {
    distances.resize(m);
    spare.resize(m);
  }
  // Only the distances within twice the last sample's k-th distance (this
  // thread's previous leaf's for the first: its neighbour in Morton order)
  // are ranked when more than k pass: about 4k of them on a surface, a
  // quarter of the compares in a leaf of 8k points.
  thread_local float lastKth = std::numeric_limits<float>::infinity();
  std::array<float, kLeafRadiusSamples> sampled{};
  for (std::size_t s = 0; s < samples; ++s) {
    const auto& p = leaf[(2 * s + 1) * m / (2 * samples)].position;
    if (ranked) {
      const float kth = columns.kthSmallestSquaredDistance(p, k, 4.0f * lastKth);
      lastKth = kth;
      sampled[s] = std::sqrt(kth) * factor;
      continue;
    }
    for (std::size_t i = 0; i < m; ++i) {
      const auto& q = leaf[i].position;
      const float dx = q[0] - p[0], dy = q[1] - p[1], dz = q[2] - p[2];
      distances[i] = dx * dx + dy * dy + dz * dz;
    }
    sampled[s] = std::sqrt(kthSmallest(distances.data(), spare.data(), m, k)) * factor;
  }
  const auto middle = sampled.begin() + static_cast<std::ptrdiff_t>(samples / 2);
  std::nth_element(sampled.begin(), middle, sampled.begin() + static_cast<std::ptrdiff_t>(samples));
  return *middle;
}

}  // namespace

void estimateRadiiInLeaves(Octree& tree, int neighbours, unsigned threads,
                           const ProgressFn& progress) {
  if (neighbours < 3) throw UsageError("radius estimation needs at least 3 neighbours");
  const auto k = static_cast<std::size_t>(neighbours);
  const float factor = std::sqrt(3.0f / static_cast<float>(k));
  const std::span<Splat> points(tree.points);
  const auto& cells = tree.cells;
  const auto range = [&](const BuildCell& c) {
    return points.subspan(static_cast<std::size_t>(c.begin),
                          static_cast<std::size_t>(c.end - c.begin));
  };
  const std::uint64_t total = points.size();
  if (progress) progress(0, total);
  std::vector<float> radius(cells.size(), 0.0f);
  parallelFor(
      cells.size(), threads,
      [&](std::size_t i) {
        if (cells[i].isLeaf()) radius[i] = sampledRadius(range(cells[i]), k, factor);
      },
      64);
  // Leaves with at most k points take the mean of their measured sibling
  // leaves, else their parent's density (a parent holds more than a leaf's worth).
  std::vector<double> siblingSum(cells.size(), 0.0);
  std::vector<std::uint32_t> siblingCount(cells.size(), 0);
  for (std::size_t i = 1; i < cells.size(); ++i) {
    if (cells[i].isLeaf() && radius[i] > 0.0f) {
      siblingSum[cells[i].parent] += static_cast<double>(radius[i]);
      ++siblingCount[cells[i].parent];
    }
  }
  for (std::size_t i = 0; i < cells.size(); ++i)
    if (siblingCount[i] > 0)
      radius[i] = static_cast<float>(siblingSum[i] / static_cast<double>(siblingCount[i]));
  // Leaves still without a figure (small, and no measured sibling): the
  // nearest ancestor's, measured by density once, up the tree.
  std::vector<std::uint8_t> measured(cells.size(), 0);
  for (std::size_t i = 0; i < cells.size(); ++i) {
    if (!cells[i].isLeaf() || radius[i] > 0.0f) continue;
    float r = 0.0f;
    // Not above the leaf's top-level cell: its points are all at hand even when
    // the cloud is built chunk by chunk (out of core).
    for (std::uint32_t up = cells[i].parent;
         r == 0.0f && up != kNoIndex && cells[up].topLevel == cells[i].topLevel;
         up = cells[up].parent) {
      if (radius[up] == 0.0f && !measured[up]) {
        radius[up] = densityRadius(range(cells[up]));
        measured[up] = 1;
      }
      r = radius[up];
    }
    // Points that all coincide with their neighbours: the leaf's density.
    if (r == 0.0f) r = densityRadius(range(cells[i]));
    radius[i] = r > 0.0f ? r : 1.0f;
  }
  parallelFor(
      cells.size(), threads,
      [&](std::size_t i) {
        if (!cells[i].isLeaf()) return;
        for (Splat& p : range(cells[i]))
          if (!hasRadius(p)) p.radius = radius[i];
      },
      256);
  if (progress) progress(total, total);
}

}  // namespace pointillist::preprocess
