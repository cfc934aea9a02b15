#pragma once
// Seed 003 §4.1.1, step one: an axis-aligned octree over the points'
// bounding cube, with the point-array sorted so that every cell (leaf or not)
// owns one contiguous range of it, and the cells listed depth-first.
#include <algorithm>
#include <array>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <span>
#include <thread>
#include <vector>

#include "common/octree_cell.hpp"
#include "common/splat.hpp"
#include "preprocess/parallel.hpp"
#include "preprocess/point_cloud.hpp"

namespace pointillist::preprocess {

struct OctreeOptions {
  // Recursion limit. Also the resolution of the Morton sort (3 bits a level,
  // so at most 21). 16 levels resolve 1/65536 of the bounding cube, finer than
  // any scan we expect; deeper subdivision only adds cells.
  unsigned maxDepth = 16;
  // A cell with more points than this is split (unless at maxDepth). 128 keeps
  // the cell array at roughly 1/40 of the points (traverse memory) while leaves
  // stay small enough for fine culling and level of detail.
  std::uint32_t leafPoints = 128;
  unsigned threads = 0;  // for the Morton codes, their sort and the gather; 0: all cores
  // Room for this many more points after the tree's (PreprocessOptions::
  // neighbourAnchors are appended there without moving the points).
  std::size_t spareCapacity = 0;
};

// One cell while preprocessing, in depth-first (pre-order) position.
struct BuildCell {
  std::uint64_t begin = 0;  // subtree points: Octree::points[begin, end)
  std::uint64_t end = 0;
  std::uint32_t parent = kNoIndex;
  std::uint32_t nextSibling = kNoIndex;  // next sibling, else nearest ancestor's, else kNoIndex
  std::uint32_t topLevel = kNoIndex;     // set by assignTopLevelCells
  std::uint8_t depth = 0;
  std::uint8_t childCount = 0;
  std::uint8_t level = 0;          // leaves 1, others 1 + max(children)
  float boundsMin[3] = {0, 0, 0};  // tight bounds of the subtree's point centres
  float boundsMax[3] = {0, 0, 0};

  bool isLeaf() const { return childCount == 0; }
};

struct Octree {
  std::vector<Splat> points;      // sorted by cell (Morton order)
  std::vector<BuildCell> cells;   // depth-first; cells[0] is the root
  unsigned treeDepth = 0;         // deepest cell
  double cubeMin[3] = {0, 0, 0};  // the subdivided bounding cube
  double cubeSize = 0;
  // After assignTopLevelCells: the top-level cells' indices, depth-first.
  unsigned topLevelDepth = 0;
  std::vector<std::uint32_t> topLevelCells;
};

// The cube the octree subdivides: the bounding box's largest side (with a
// little slack so the maximum does not sit on a face), from its minimum corner.
struct OctreeCube {
  double min[3] = {0, 0, 0};
  double size = 1;
};
// lo/hi: the bounds of the point positions (as doubles of the stored floats).
OctreeCube boundingCube(const double lo[3], const double hi[3]);

// The points' bounds, in blocks on `threads` threads (0: all cores).
// firstNonFinite: the first point with a NaN or infinite coordinate (the
// bounds then mean nothing), or kAllFinite.
struct PointBounds {
  static constexpr std::size_t kAllFinite = static_cast<std::size_t>(-1);
  double lo[3], hi[3];
  std::size_t firstNonFinite = kAllFinite;
};
PointBounds pointBounds(std::span<const Splat> points, unsigned threads);
// Morton code of a position at maxDepth resolution; x is the most significant
// of each triple, so a cell's octant is 4x + 2y + z. The prefix of a cell at
// depth d is code >> 3 * (maxDepth - d).
std::uint64_t mortonCode(const float position[3], const OctreeCube& cube, unsigned maxDepth);

// Morton bit spreading: the low 21 bits of v with bit k moved to bit 3k, and
// back (compactBits takes every third bit from bit 0).
inline std::uint64_t spreadBits(std::uint64_t v) {
  v &= 0x1fffff;
  v = (v | v << 32) & 0x1f00000000ffffull;
  v = (v | v << 16) & 0x1f0000ff0000ffull;
  v = (v | v << 8) & 0x100f00f00f00f00full;
  v = (v | v << 4) & 0x10c30c30c30c30c3ull;
  v = (v | v << 2) & 0x1249249249249249ull;
  return v;
}
inline std::uint64_t compactBits(std::uint64_t v) {
  v &= 0x1249249249249249ull;
  v = (v | v >> 2) & 0x10c30c30c30c30c3ull;
  v = (v | v >> 4) & 0x100f00f00f00f00full;
  v = (v | v >> 8) & 0x1f0000ff0000ffull;
  v = (v | v >> 16) & 0x1f00000000ffffull;
  v = (v | v >> 32) & 0x1fffff;
  return v;
}

// The Morton key of cell coordinates q (each below 2^21), x most significant.
inline std::uint64_t mortonInterleave(const std::uint64_t q[3]) {
  return spreadBits(q[0]) << 2 | spreadBits(q[1]) << 1 | spreadBits(q[2]);
}

// The same for many positions: the scale worked out once, all inline.
class MortonCoder {
 public:
  MortonCoder(const OctreeCube& cube, unsigned maxDepth)
      : min_{cube.min[0], cube.min[1], cube.min[2]},
        scale_(static_cast<double>(std::uint64_t{1} << maxDepth) / cube.size),
        maxCoord_(static_cast<double>((std::uint64_t{1} << maxDepth) - 1)) {}

  std::uint64_t operator()(const float position[3]) const {
    std::uint64_t q[3];
    quantize(position, q);
    return mortonInterleave(q);
  }
  // The position's cell coordinates at maxDepth, each below 2^maxDepth.
  void quantize(const float position[3], std::uint64_t q[3]) const {
    for (int a = 0; a < 3; ++a) {
      const double t = (static_cast<double>(position[a]) - min_[a]) * scale_;
      // Clamped as a double first: a cast of an out-of-range double is undefined.
      q[a] = static_cast<std::uint64_t>(t < 0.0 ? 0.0 : (t > maxCoord_ ? maxCoord_ : t));
    }
  }

 private:
  double min_[3];
  double scale_;
  double maxCoord_;
};

// For building one spatial chunk of a larger cloud (the out-of-core
// preprocess): the whole cloud's cube, and the cells above the chunk that the
// whole cloud splits, which must split here too although the chunk alone may
// hold fewer points in them. splitCells[d]: sorted Morton prefixes at depth d.
struct OctreeFrame {
  OctreeCube cube;
  std::vector<std::vector<std::uint64_t>> splitCells;
};

namespace detail {

// Stable LSD passes, kDigitBits bits each, over bits [lowBit, highBit) of
// key(item) for the n items at `from`, between `from` and `other` (n items
// each) on one thread. Returns where the sorted items lie: `from` or `other`.
template <unsigned kDigitBits, class Item, class KeyFn>
Item* radixPasses(Item* from, Item* other, std::size_t n, unsigned lowBit, unsigned highBit,
                  KeyFn& key) {
  // A few dozen items: a stable insertion sort beats the digit counts.
  constexpr std::size_t kInsertionItems = 48;
  const std::uint64_t lowMask =
      highBit - lowBit >= 64 ? ~std::uint64_t{0} : (std::uint64_t{1} << (highBit - lowBit)) - 1;
  if (n <= kInsertionItems) {
    const auto bits = [&](const Item& item) { return (key(item) >> lowBit) & lowMask; };
    for (std::size_t i = 1; i < n; ++i) {
      const Item item = from[i];
      const std::uint64_t k = bits(item);
      std::size_t j = i;
      for (; j > 0 && bits(from[j - 1]) > k; --j) from[j] = from[j - 1];
      from[j] = item;
    }
    return from;
  }
  constexpr std::size_t kDigits = std::size_t{1} << kDigitBits;
  std::array<std::uint32_t, kDigits> count;
  for (unsigned shift = lowBit; shift < highBit; shift += kDigitBits) {
    const std::uint64_t mask =
        shift + kDigitBits <= highBit ? kDigits - 1 : (std::uint64_t{1} << (highBit - shift)) - 1;
    count.fill(0);
    for (std::size_t i = 0; i < n; ++i) ++count[(key(from[i]) >> shift) & mask];
    std::uint32_t at = 0;
    bool oneDigit = false;
    for (std::size_t d = 0; d <= mask; ++d) {
      const std::uint32_t c = count[d];
      oneDigit = oneDigit || c == n;
      count[d] = at;
      at += c;
    }
    if (oneDigit) continue;  // every key shares this digit
    for (std::size_t i = 0; i < n; ++i) other[count[(key(from[i]) >> shift) & mask]++] = from[i];
    std::swap(from, other);
  }
  return from;
}

// Stable LSD radix sort of the n items at `items` on `threads` threads, with
// `scratch` (n items) beside them: each thread counts and scatters its own
// contiguous share, in share order, so the sort stays stable. Returns where
// the sorted items lie: `items` or `scratch`.
template <unsigned kDigitBits, class Item, class KeyFn>
Item* parallelRadixPasses(Item* items, Item* scratch, std::size_t n, unsigned lowBit,
                          unsigned highBit, KeyFn& key, unsigned threads,
                          const std::function<void(unsigned, unsigned)>& passDone = {}) {
  // Below a few blocks a thread costs more than it saves.
  const std::size_t shares = std::clamp<std::size_t>(n >> 18, 1, threads);
  constexpr std::size_t kDigits = std::size_t{1} << kDigitBits;
  std::vector<std::array<std::size_t, kDigits>> count(shares);
  const auto shareBegin = [&](std::size_t s) { return n * s / shares; };
  const unsigned passes = (highBit - lowBit + kDigitBits - 1) / kDigitBits;
  for (unsigned pass = 0; pass < passes; ++pass) {
    const unsigned shift = lowBit + pass * kDigitBits;
    const std::uint64_t mask =
        shift + kDigitBits <= highBit ? kDigits - 1 : (std::uint64_t{1} << (highBit - shift)) - 1;
    const auto digit = [&](const Item& item) {
      return static_cast<std::size_t>((key(item) >> shift) & mask);
    };
    parallelFor(
        shares, threads,
        [&](std::size_t s) {
          count[s].fill(0);
          for (std::size_t i = shareBegin(s); i < shareBegin(s + 1); ++i)
            ++count[s][digit(items[i])];
        },
        1);
    // Where each share's run of each digit starts: digit-major, share-minor.
    std::size_t at = 0;
    bool oneDigit = false;
    for (std::size_t d = 0; d < kDigits; ++d) {
      std::size_t total = 0;
      for (std::size_t s = 0; s < shares; ++s) {
        const std::size_t c = count[s][d];
        count[s][d] = at;
        at += c;
        total += c;
      }
      oneDigit = oneDigit || total == n;
    }
    if (!oneDigit) {  // else every key shares this digit
      parallelFor(
          shares, threads,
          [&](std::size_t s) {
            auto& next = count[s];
            for (std::size_t i = shareBegin(s); i < shareBegin(s + 1); ++i)
              scratch[next[digit(items[i])]++] = items[i];
          },
          1);
      std::swap(items, scratch);
    }
    if (passDone) passDone(pass + 1, passes);
  }
  return items;
}

}  // namespace detail

// Stable radix sort on bits [lowBit, highBit) of key(item), kDigitBits bits
// a digit: equal keys keep their order, on any number of `threads` (0: all
// cores). Where one digit does not cover the bits, the highest digit's pass
// deals the items into buckets on all threads and each bucket is then sorted
// on the lower bits on one thread, from cache: each pass over the whole
// array scattered to thousands of places (the cube moments' sort of 10 M
// keys, three passes: 0.14-0.19 -> 0.10-0.13 s). A bucket of more than an
// eighth of the items is sorted on all threads instead. Reports progress as
// a share of the items.
template <unsigned kDigitBits = 8, class Item, class Allocator, class KeyFn>
void radixSort(std::vector<Item, Allocator>& items, unsigned lowBit, unsigned highBit, KeyFn key,
               const ProgressFn& progress = {}, unsigned threads = 1) {
  if (threads == 0) threads = std::max(1u, std::thread::hardware_concurrency());
  const std::size_t n = items.size();
  if (n < 2 || highBit <= lowBit) return;
  std::vector<Item, Allocator> tmp;
  resizePopulated(tmp, n, threads);  // its writes are scattered
  const unsigned passes = (highBit - lowBit + kDigitBits - 1) / kDigitBits;
  const auto report = [&](unsigned done, unsigned of) {
    if (progress) progress(n * done / (of + 1), n);
  };
  // Small arrays and one digit: passes over the whole array.
  if (passes < 2 || n < (std::size_t{1} << 16)) {
    if (detail::parallelRadixPasses<kDigitBits>(items.data(), tmp.data(), n, lowBit, highBit, key,
                                                threads, report) != items.data())
      items.swap(tmp);
    return;
  }
  // The top digit: items into tmp by bucket.
  const unsigned topShift = highBit - kDigitBits;
  if (detail::parallelRadixPasses<kDigitBits>(items.data(), tmp.data(), n, topShift, highBit, key,
                                              threads) == items.data())
    items.swap(tmp);  // one bucket: the items stayed where they were
  report(1, passes);
  // Now tmp's items lie in bucket order; each bucket is sorted back into items.
  constexpr std::size_t kDigits = std::size_t{1} << kDigitBits;
  std::vector<std::size_t> bucketStart;
  bucketStart.reserve(kDigits + 1);
  {
    std::size_t begin = 0;
    bucketStart.push_back(0);
    while (begin < n) {
      const std::uint64_t digit = (key(tmp[begin]) >> topShift) & (kDigits - 1);
      std::size_t end = begin + 1;
      // Buckets are runs of one digit: found by galloping, then halving.
      std::size_t step = 1;
      while (end + step < n && ((key(tmp[end + step - 1]) >> topShift) & (kDigits - 1)) == digit)
        step *= 2;
      std::size_t lo = end, hi = std::min(n, end + step);
      while (lo < hi) {
        const std::size_t mid = lo + (hi - lo) / 2;
        if (((key(tmp[mid]) >> topShift) & (kDigits - 1)) == digit)
          lo = mid + 1;
        else
          hi = mid;
      }
      begin = lo;
      bucketStart.push_back(begin);
    }
  }
  const std::size_t buckets = bucketStart.size() - 1;
  const std::size_t large = std::max<std::size_t>(n / 8, std::size_t{1} << 16);
  const auto sortBucket = [&](std::size_t b, unsigned bucketThreads) {
    const std::size_t first = bucketStart[b], m = bucketStart[b + 1] - first;
    Item* sorted =
        bucketThreads > 1
            ? detail::parallelRadixPasses<kDigitBits>(tmp.data() + first, items.data() + first, m,
                                                      lowBit, topShift, key, bucketThreads)
            : detail::radixPasses<kDigitBits>(tmp.data() + first, items.data() + first, m, lowBit,
                                              topShift, key);
    if (sorted != items.data() + first) std::copy(sorted, sorted + m, items.data() + first);
  };
  for (std::size_t b = 0; b < buckets; ++b)
    if (bucketStart[b + 1] - bucketStart[b] > large) sortBucket(b, threads);
  parallelFor(
      buckets, threads,
      [&](std::size_t b) {
        if (bucketStart[b + 1] - bucketStart[b] <= large) sortBucket(b, 1);
      },
      4);
  report(passes, passes);
}

// Sorts `points` along a Morton curve at maxDepth resolution and builds the
// tree. Throws InputError for an empty or non-finite cloud, UsageError for
// options out of range. Deterministic: equal input gives an equal tree.
// Without a frame the cube is boundingCube of the points.
Octree buildOctree(std::vector<Splat> points, const OctreeOptions& options,
                   const ProgressFn& progress = {}, const OctreeFrame* frame = nullptr);

// Sets every cell's nextSibling in a depth-first cell array from the depths
// alone: the first later cell that is not deeper (ends the subtree), else
// kNoIndex. For BuildCell and OctreeCell.
template <class Cell>
void linkNextSiblings(std::span<Cell> cells) {
  std::vector<std::uint32_t> open;
  for (std::size_t i = 0; i < cells.size(); ++i) {
    while (!open.empty() && cells[open.back()].depth >= cells[i].depth) {
      cells[open.back()].nextSibling = static_cast<std::uint32_t>(i);
      open.pop_back();
    }
    open.push_back(static_cast<std::uint32_t>(i));
  }
  for (const std::uint32_t i : open) cells[i].nextSibling = kNoIndex;
}

// How many top-level cells a top-level depth gives: the cells at that depth
// plus the leaves above it (a branch that ends early is its own top-level cell).
std::size_t countTopLevelCells(const Octree& tree, unsigned depth);

// Default top-level depth: the smallest depth (at least 3, the paper's lower
// end, where the tree is that deep) at which the average packet -- points plus
// about a third more in level-splats -- fits in targetPacketBytes. With the
// 256 KiB default this gives depth 3 for ~0.3M and 5 for ~10M surface points,
// the paper's range.
inline constexpr std::uint64_t kDefaultPacketBytes = 256 * 1024;
unsigned chooseTopLevelDepth(const Octree& tree,
                             std::uint64_t targetPacketBytes = kDefaultPacketBytes);
// The same from the tree's shape: cells and leaves at each depth (index =
// depth, up to the tree depth) and its point count.
unsigned chooseTopLevelDepth(const std::vector<std::size_t>& cellsAtDepth,
                             const std::vector<std::size_t>& leavesAtDepth,
                             std::uint64_t pointCount,
                             std::uint64_t targetPacketBytes = kDefaultPacketBytes);

// Marks the top-level cells for `depth` (clamped to the tree depth): every
// cell at that depth and every leaf above it; cells beneath inherit the index,
// cells above get kNoIndex.
void assignTopLevelCells(Octree& tree, unsigned depth);

}  // namespace pointillist::preprocess
