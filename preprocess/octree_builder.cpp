#include "preprocess/octree_builder.hpp"

#include "common/uninitialized_allocator.hpp"

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <limits>
#include <string>

#if defined(__x86_64__)
#include <cpuid.h>
#include <immintrin.h>
#endif

#include "common/errors.hpp"
#include "preprocess/parallel.hpp"

namespace pointillist::preprocess {

namespace {

struct Keyed {
  std::uint64_t code;
  std::uint64_t index;
};
// Written in full by the threads that fill them: zeroing them first would be
// a pass over hundreds of megabytes on one thread.
using KeyedVector = std::vector<Keyed, UninitializedAllocator<Keyed>>;

// Orders points by Morton code. Only the top 8 levels are radix sorted (two
// passes of 12 bits, which move a third fewer bytes than three of 8); a run
// sharing that prefix is sorted further only if it holds more than a leaf's
// worth of points (otherwise it is one leaf and its inner order is free).
// Ties keep input order, so the result is deterministic.
void mortonSort(KeyedVector& items, unsigned totalBits, std::uint32_t leafPoints,
                const ProgressFn& progress, unsigned threads) {
  const unsigned lowBit = totalBits > 24 ? totalBits - 24 : 0;
  radixSort<12>(
      items, lowBit, totalBits, [](const Keyed& k) { return k.code; }, progress, threads);
  if (lowBit == 0) return;
  // The runs to sort, found on one thread, sorted on all.
  std::vector<std::pair<std::size_t, std::size_t>> runs;
  for (std::size_t b = 0; b < items.size();) {
    const std::uint64_t prefix = items[b].code >> lowBit;
    std::size_t e = b + 1;
    while (e < items.size() && (items[e].code >> lowBit) == prefix) ++e;
    if (e - b > leafPoints) runs.emplace_back(b, e);
    b = e;
  }
  // A run is in input order (the passes above are stable), so a stable radix
  // sort on the bits its codes differ in orders it by (code, index): std::sort
  // there was 8 % of an out-of-core build, whose chunks share their top levels
  // and leave runs of tens of thousands of points.
  const auto code = [](const Keyed& k) { return k.code; };
  parallelFor(
      runs.size(), threads,
      [&](std::size_t r) {
        thread_local KeyedVector scratch;
        Keyed* const first = items.data() + runs[r].first;
        const std::size_t m = runs[r].second - runs[r].first;
        std::uint64_t differ = 0;
        for (std::size_t i = 1; i < m; ++i) differ |= first[i].code ^ first[0].code;
        if (differ == 0) return;
        if (scratch.size() < m) scratch.resize(m);
        const Keyed* sorted = detail::radixPasses<11>(
            first, scratch.data(), m, static_cast<unsigned>(std::countr_zero(differ)),
            static_cast<unsigned>(std::bit_width(differ)), code);
        if (sorted != first) std::copy(sorted, sorted + m, first);
      },
      16);
}

// Codes of points[first, last): the bits interleaved by BMI2's pdep where the
// processor runs it in hardware (one instruction an axis against fifteen),
// else by spreadBits.
#if defined(__x86_64__)
// AMD before Zen 3 (family 0x19) runs pdep as microcode, a cycle or more per
// set bit of the mask: on a Zen 1 EPYC the coding was 8 % of an XYZ
// preprocess's CPU, 3-4 times spreadBits' cost.
bool hasFastPdep() {
  if (__builtin_cpu_supports("bmi2") == 0) return false;
  unsigned eax = 0, ebx = 0, ecx = 0, edx = 0;
  if (__get_cpuid(0, &eax, &ebx, &ecx, &edx) == 0) return false;
  // "AuthenticAMD": ebx "Auth", edx "enti", ecx "cAMD".
  const bool amd = ebx == 0x68747541u && edx == 0x69746e65u && ecx == 0x444d4163u;
  if (!amd) return true;
  if (__get_cpuid(1, &eax, &ebx, &ecx, &edx) == 0) return false;
  unsigned family = (eax >> 8) & 0xFu;
  if (family == 0xFu) family += (eax >> 20) & 0xFFu;
  return family >= 0x19u;
}

__attribute__((target("bmi2"))) void codePointsWithPdep(const MortonCoder& morton,
                                                        const Splat* points, Keyed* keyed,
                                                        std::size_t first, std::size_t last) {
  for (std::size_t i = first; i < last; ++i) {
    std::uint64_t q[3];
    morton.quantize(points[i].position, q);
    keyed[i] = {_pdep_u64(q[0], 0x4924924924924924ull) | _pdep_u64(q[1], 0x2492492492492492ull) |
                    _pdep_u64(q[2], 0x1249249249249249ull),
                i};
  }
}
#endif

void codePoints(const MortonCoder& morton, const Splat* points, Keyed* keyed, std::size_t first,
                std::size_t last) {
#if defined(__x86_64__)
  static const bool hasPdep = hasFastPdep();
  if (hasPdep) {
    codePointsWithPdep(morton, points, keyed, first, last);
    return;
  }
#endif
  for (std::size_t i = first; i < last; ++i) keyed[i] = {morton(points[i].position), i};
}

class TreeBuilder {
 public:
  TreeBuilder(Octree& tree, std::span<const Keyed> sorted, const OctreeOptions& o,
              const OctreeFrame* frame)
      : tree_(tree), sorted_(sorted), options_(o), frame_(frame) {}

  std::uint32_t build(std::uint64_t begin, std::uint64_t end, unsigned depth,
                      std::uint32_t parent) {
    const auto index = static_cast<std::uint32_t>(tree_.cells.size());
    {
      BuildCell cell;
      cell.begin = begin;
      cell.end = end;
      cell.parent = parent;
      cell.depth = static_cast<std::uint8_t>(depth);
      tree_.cells.push_back(cell);
    }
    tree_.treeDepth = std::max(tree_.treeDepth, depth);
    if ((end - begin <= options_.leafPoints && !forcedSplit(begin, depth)) ||
        depth >= options_.maxDepth) {
      return index;  // a leaf: its bounds come after, on all threads
    }
    const unsigned shift = 3 * (options_.maxDepth - 1 - depth);
    const Keyed* first = sorted_.data();
    std::uint64_t cur = begin;
    unsigned children = 0;
    for (std::uint64_t octant = 0; octant < 8 && cur < end; ++octant) {
      const Keyed* split = std::partition_point(first + cur, first + end, [&](const Keyed& k) {
        return ((k.code >> shift) & 7u) <= octant;
      });
      const auto childEnd = static_cast<std::uint64_t>(split - first);
      if (childEnd > cur) {
        build(cur, childEnd, depth + 1, index);
        ++children;
        cur = childEnd;
      }
    }
    tree_.cells[index].childCount = static_cast<std::uint8_t>(children);
    return index;
  }

 private:
  bool forcedSplit(std::uint64_t begin, unsigned depth) const {
    if (frame_ == nullptr || depth >= frame_->splitCells.size()) return false;
    const auto& split = frame_->splitCells[depth];
    const std::uint64_t prefix = sorted_[begin].code >> (3 * (options_.maxDepth - depth));
    return std::binary_search(split.begin(), split.end(), prefix);
  }

 public:
  void computeLeafBounds(BuildCell& cell) const {
    float lo[3], hi[3];
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::numeric_limits<float>::infinity();
      hi[a] = -std::numeric_limits<float>::infinity();
    }
    for (std::uint64_t i = cell.begin; i < cell.end; ++i) {
      const Splat& s = tree_.points[i];
      for (int a = 0; a < 3; ++a) {
        lo[a] = std::min(lo[a], s.position[a]);
        hi[a] = std::max(hi[a], s.position[a]);
      }
    }
    for (int a = 0; a < 3; ++a) {
      cell.boundsMin[a] = lo[a];
      cell.boundsMax[a] = hi[a];
    }
  }

 private:
  Octree& tree_;
  std::span<const Keyed> sorted_;  // Morton codes in point order
  const OctreeOptions& options_;
  const OctreeFrame* frame_;
};

}  // namespace

PointBounds pointBounds(std::span<const Splat> points, unsigned threads) {
  PointBounds result;
  for (int a = 0; a < 3; ++a) {
    result.lo[a] = std::numeric_limits<double>::infinity();
    result.hi[a] = -std::numeric_limits<double>::infinity();
  }
  constexpr std::size_t kBlock = std::size_t{1} << 18;
  const std::size_t blocks = (points.size() + kBlock - 1) / kBlock;
  struct Block {
    float lo[3], hi[3];
    bool finite = true;
  };
  std::vector<Block> block(blocks);
  parallelFor(
      blocks, threads,
      [&](std::size_t b) {
        Block& r = block[b];
        for (int a = 0; a < 3; ++a) r.lo[a] = r.hi[a] = points[b * kBlock].position[a];
        bool finite = true;
        for (std::size_t i = b * kBlock; i < std::min(points.size(), (b + 1) * kBlock); ++i)
          for (int a = 0; a < 3; ++a) {
            const float v = points[i].position[a];
            finite = finite && std::isfinite(v);
            r.lo[a] = std::min(r.lo[a], v);
            r.hi[a] = std::max(r.hi[a], v);
          }
        r.finite = finite;
      },
      1);
  for (std::size_t b = 0; b < blocks; ++b) {
    if (!block[b].finite) {
      for (std::size_t i = b * kBlock;; ++i) {  // the first offender, for messages
        const float* v = points[i].position;
        if (!std::isfinite(v[0]) || !std::isfinite(v[1]) || !std::isfinite(v[2])) {
          result.firstNonFinite = i;
          return result;
        }
      }
    }
    for (int a = 0; a < 3; ++a) {
      result.lo[a] = std::min(result.lo[a], static_cast<double>(block[b].lo[a]));
      result.hi[a] = std::max(result.hi[a], static_cast<double>(block[b].hi[a]));
    }
  }
  return result;
}

OctreeCube boundingCube(const double lo[3], const double hi[3]) {
  OctreeCube cube;
  double size = std::max({hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]});
  // A little slack so the maximum coordinate does not sit on the cube's face.
  cube.size = size > 0 ? size * (1.0 + 1e-6) : 1.0;
  for (int a = 0; a < 3; ++a) cube.min[a] = lo[a];
  return cube;
}

std::uint64_t mortonCode(const float position[3], const OctreeCube& cube, unsigned maxDepth) {
  return MortonCoder(cube, maxDepth)(position);
}

Octree buildOctree(std::vector<Splat> points, const OctreeOptions& options,
                   const ProgressFn& progress, const OctreeFrame* frame) {
  if (options.maxDepth < 1 || options.maxDepth > 21)
    throw UsageError("octree max depth must be 1..21, got " + std::to_string(options.maxDepth));
  if (options.leafPoints < 1) throw UsageError("leaf points must be at least 1");
  if (points.empty()) throw InputError("empty point cloud: nothing to preprocess");
  if (points.size() >= kNoIndex)
    throw InputError("too many points (" + std::to_string(points.size()) + "); at most " +
                     std::to_string(kNoIndex - 1));

  if (progress) progress(0, points.size());
  Octree tree;
  OctreeCube cube;
  if (frame != nullptr) {
    cube = frame->cube;
  } else {
    const PointBounds bounds = pointBounds(points, options.threads);
    if (bounds.firstNonFinite != PointBounds::kAllFinite)
      throw InputError("point " + std::to_string(bounds.firstNonFinite) +
                       " has a non-finite coordinate");
    const double* lo = bounds.lo;
    const double* hi = bounds.hi;
    cube = boundingCube(lo, hi);
  }
  for (int a = 0; a < 3; ++a) tree.cubeMin[a] = cube.min[a];
  tree.cubeSize = cube.size;

  // Codes and the gather on all threads: the gather's reads are scattered,
  // so it waits on memory, and two cores wait in parallel.
  constexpr std::size_t kChunk = std::size_t{1} << 16;
  KeyedVector keyed;
  resizePopulated(keyed, points.size(), options.threads);
  const MortonCoder morton(cube, options.maxDepth);
  parallelFor((points.size() + kChunk - 1) / kChunk, options.threads,
              [&](std::size_t chunk) {
                codePoints(morton, points.data(), keyed.data(), chunk * kChunk,
                           std::min(points.size(), (chunk + 1) * kChunk));
              },
              1);
  mortonSort(keyed, 3 * options.maxDepth, options.leafPoints, progress, options.threads);

  // Gathered on all threads into a buffer that is not zeroed first, then
  // copied back into the input's own (already touched) memory: a new
  // std::vector would be zeroed on one thread, taking every page fault there.
  std::vector<Splat, UninitializedAllocator<Splat>> sorted;
  resizePopulated(sorted, points.size(), options.threads);
  parallelFor(
      keyed.size(), options.threads, [&](std::size_t i) { sorted[i] = points[keyed[i].index]; },
      kChunk);
  if (points.capacity() >= points.size() + options.spareCapacity) {
    parallelCopy(sorted.data(), sorted.size(), points.data(), options.threads);
    tree.points = std::move(points);
  } else {
    tree.points.reserve(points.size() + options.spareCapacity);
    tree.points.assign(sorted.begin(), sorted.end());
    points = {};
  }
  sorted = {};

  // The codes stay in `keyed` (sorted with the points) until the cells are cut.
  TreeBuilder builder(tree, keyed, options, frame);
  builder.build(0, tree.points.size(), 0, kNoIndex);
  keyed = {};
  if (tree.cells.size() >= kNoIndex) throw InputError("octree too large for 32-bit cell indices");
  parallelFor(
      tree.cells.size(), options.threads,
      [&](std::size_t i) {
        if (tree.cells[i].childCount == 0) builder.computeLeafBounds(tree.cells[i]);
      },
      256);

  // Bottom-up: inner bounds are the union of their children's; levels.
  auto& cells = tree.cells;
  for (std::size_t i = cells.size(); i-- > 1;) {
    BuildCell& c = cells[i];
    if (c.isLeaf()) c.level = 1;
    BuildCell& p = cells[c.parent];
    if (p.level == 0) {  // first child seen (from the back)
      for (int a = 0; a < 3; ++a) {
        p.boundsMin[a] = c.boundsMin[a];
        p.boundsMax[a] = c.boundsMax[a];
      }
    } else {
      for (int a = 0; a < 3; ++a) {
        p.boundsMin[a] = std::min(p.boundsMin[a], c.boundsMin[a]);
        p.boundsMax[a] = std::max(p.boundsMax[a], c.boundsMax[a]);
      }
    }
    p.level = static_cast<std::uint8_t>(std::max<unsigned>(p.level, c.level + 1u));
  }
  if (cells[0].isLeaf()) cells[0].level = 1;

  linkNextSiblings(std::span<BuildCell>(cells));
  return tree;
}

std::size_t countTopLevelCells(const Octree& tree, unsigned depth) {
  std::size_t n = 0;
  for (const BuildCell& c : tree.cells)
    if (c.depth == depth || (c.isLeaf() && c.depth < depth)) ++n;
  return n;
}

unsigned chooseTopLevelDepth(const Octree& tree, std::uint64_t targetPacketBytes) {
  // Histogram once: cells at each depth and leaves at each depth.
  std::vector<std::size_t> atDepth(tree.treeDepth + 1, 0), leavesAt(tree.treeDepth + 1, 0);
  for (const BuildCell& c : tree.cells) {
    ++atDepth[c.depth];
    if (c.isLeaf()) ++leavesAt[c.depth];
  }
  return chooseTopLevelDepth(atDepth, leavesAt, tree.points.size(), targetPacketBytes);
}

unsigned chooseTopLevelDepth(const std::vector<std::size_t>& atDepth,
                             const std::vector<std::size_t>& leavesAt, std::uint64_t pointCount,
                             std::uint64_t targetPacketBytes) {
  const auto treeDepth = static_cast<unsigned>(atDepth.size() - 1);
  const unsigned minDepth = std::min(3u, treeDepth);
  const double packetBytes = static_cast<double>(pointCount) * sizeof(Splat) * (4.0 / 3.0);
  std::size_t leavesAbove = 0;
  for (unsigned d = 0; d <= treeDepth; ++d) {
    const std::size_t count = atDepth[d] + leavesAbove;
    leavesAbove += leavesAt[d];
    if (d < minDepth) continue;
    if (packetBytes / static_cast<double>(count) <= static_cast<double>(targetPacketBytes))
      return d;
  }
  return treeDepth;
}

void assignTopLevelCells(Octree& tree, unsigned depth) {
  depth = std::min(depth, tree.treeDepth);
  tree.topLevelDepth = depth;
  tree.topLevelCells.clear();
  for (std::size_t i = 0; i < tree.cells.size(); ++i) {
    BuildCell& c = tree.cells[i];
    if (c.depth > depth) {
      c.topLevel = tree.cells[c.parent].topLevel;
    } else if (c.depth == depth || c.isLeaf()) {
      c.topLevel = static_cast<std::uint32_t>(tree.topLevelCells.size());
      tree.topLevelCells.push_back(static_cast<std::uint32_t>(i));
    } else {
      c.topLevel = kNoIndex;
    }
  }
}

}  // namespace pointillist::preprocess
