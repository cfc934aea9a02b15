#include "preprocess/neighbour_grid.hpp"

#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <limits>
#include <utility>

#include "preprocess/neighbour_filter.hpp"
#include "preprocess/octree_builder.hpp"
#include "preprocess/parallel.hpp"
#include "preprocess/selection.hpp"

namespace pointillist::preprocess {

namespace {

constexpr unsigned kCodeLevels = 16;
constexpr std::size_t kNotFound = std::numeric_limits<std::size_t>::max();
// A query's candidates within the bound are sorted whole up to this many
// (n^2 compares); beyond, the nearest are selected first.
constexpr std::size_t kSortAllUpTo = 48;
// A query first keeps the candidates within this many times the previous
// query's squared k-th distance (about 1.6 times k of them on a surface),
// and only if too few pass, those within the bound that is sure to hold
// enough: twice as many on average.
constexpr double kTightBound = 1.6;

std::uint64_t interleave(const std::int64_t q[3]) {
  std::uint64_t code = 0;
  for (int a = 0; a < 3; ++a) code |= spreadBits(static_cast<std::uint64_t>(q[a])) << (2 - a);
  return code;
}

// A cube's first slot in the table. The key's low bits (16 consecutive
// Morton keys, a brick of 2x2x4 cubes) stay the slot's low bits, so a cube's
// neighbours are mostly found in a few cache lines, and the next cube's in
// the same ones; the rest is hashed, as an axis-aligned plane would pile up
// if slots were plain Morton keys.
constexpr unsigned kBrickBits = 4;
std::uint64_t firstSlot(std::uint64_t key, std::uint64_t mask) {
  const std::uint64_t brick = (key >> kBrickBits) * 0x9E3779B97F4A7C15ull >> 32;
  return (brick << kBrickBits | (key & ((1u << kBrickBits) - 1))) & mask;
}

}  // namespace

NeighbourGrid::NeighbourGrid(std::span<const Splat> points, double pointsPerCube, unsigned threads)
    : n_(points.size()) {
  if (n_ == 0) return;
  const PointBounds bounds = pointBounds(points, threads);
  const OctreeCube cube = boundingCube(bounds.lo, bounds.hi);
  // Blocks of points on all threads: codes and whether they are already in
  // order (a preprocess hands them over in Morton order, sorted down to its
  // octree's leaves).
  constexpr std::size_t kBlock = std::size_t{1} << 16;
  const std::size_t blocks = (n_ + kBlock - 1) / kBlock;
  const auto blockEnd = [&](std::size_t b) { return std::min(n_, (b + 1) * kBlock); };
  struct BlockFigures {
    int disorder = -1;  // the highest bit where a code falls below the one before
    std::array<std::size_t, kCodeLevels + 1> parts{};
  };
  std::vector<BlockFigures> figures(blocks);
  const MortonCoder morton(cube, kCodeLevels);
  struct Keyed {
    std::uint64_t code;
    std::uint32_t index;
    bool operator<(const Keyed& o) const {
      return code != o.code ? code < o.code : index < o.index;
    }
  };
  std::vector<Keyed, UninitializedAllocator<Keyed>> keyed(n_);
  const auto disorderBetween = [&](std::size_t i) {  // keyed[i - 1] and keyed[i]
    const std::uint64_t a = keyed[i - 1].code, b = keyed[i].code;
    return a <= b ? -1 : 63 - std::countl_zero(a ^ b);
  };
  parallelFor(
      blocks, threads,
      [&](std::size_t b) {
        int disorder = -1;
        for (std::size_t i = b * kBlock; i < blockEnd(b); ++i) {
          keyed[i] = {morton(points[i].position), static_cast<std::uint32_t>(i)};
          if (i > b * kBlock) disorder = std::max(disorder, disorderBetween(i));
        }
        figures[b].disorder = disorder;
      },
      1);
  int disorder = -1;
  for (std::size_t b = 0; b < blocks; ++b) {
    disorder = std::max(disorder, figures[b].disorder);
    if (b > 0) disorder = std::max(disorder, disorderBetween(b * kBlock));
  }
  if (disorder >= 0) {
    // Codes only fall at bit `disorder` or below: the points are already in
    // order of the bits above it (a preprocess hands them over sorted down
    // to its octree's leaves), so only runs that share those bits are sorted
    // (the same order a sort of the whole gives).
    const unsigned shift = static_cast<unsigned>(disorder) + 1;
    // Fewer than 6 levels in order (a cloud in file order): runs too long
    // for one thread each, so the whole is sorted on all threads.
    if (shift > 3 * (kCodeLevels - 6)) {
      parallelSort(keyed.begin(), keyed.end(), threads, std::less<Keyed>());
    } else {
      // The runs that start in each block, found before any is sorted (a
      // run may reach into the next block).
      std::vector<std::vector<std::pair<std::size_t, std::size_t>>> runs(blocks);
      parallelFor(
          blocks, threads,
          [&](std::size_t b) {
            const auto prefix = [&](std::size_t i) { return keyed[i].code >> shift; };
            std::size_t i = b * kBlock;
            while (i > 0 && i < blockEnd(b) && prefix(i - 1) == prefix(i)) ++i;
            while (i < blockEnd(b)) {
              std::size_t end = i + 1;
              while (end < n_ && prefix(end) == prefix(i)) ++end;
              if (end - i > 1) runs[b].emplace_back(i, end);
              i = end;
            }
          },
          1);
      parallelFor(
          blocks, threads,
          [&](std::size_t b) {
            for (const auto& [first, last] : runs[b])
              std::sort(keyed.begin() + static_cast<std::ptrdiff_t>(first),
                        keyed.begin() + static_cast<std::ptrdiff_t>(last), std::less<Keyed>());
          },
          1);
    }
  }

  // Occupied cubes at every level from where neighbours in that order part.
  parallelFor(
      blocks, threads,
      [&](std::size_t b) {
        auto& parts = figures[b].parts;
        for (std::size_t i = std::max<std::size_t>(1, b * kBlock); i < blockEnd(b); ++i) {
          const std::uint64_t x = keyed[i - 1].code ^ keyed[i].code;
          if (x == 0) continue;
          const unsigned highBit = 63u - static_cast<unsigned>(std::countl_zero(x));
          ++parts[kCodeLevels - highBit / 3];
        }
      },
      1);
  std::size_t occupied = 1;
  for (unsigned d = 0; d <= kCodeLevels; ++d) {
    for (const BlockFigures& f : figures) occupied += f.parts[d];
    if (static_cast<double>(n_) / static_cast<double>(occupied) < pointsPerCube) break;
    level_ = d;
  }

  for (int a = 0; a < 3; ++a) min_[a] = cube.min[a];
  scale_ = std::ldexp(1.0, static_cast<int>(level_)) / cube.size;
  const unsigned shift = 3 * (kCodeLevels - level_);
  xyz_.resize(3 * n_);
  original_.resize(n_);
  slot_.resize(n_);
  parallelFor(
      n_, threads,
      [&](std::size_t j) {
        const std::uint32_t i = keyed[j].index;
        for (int a = 0; a < 3; ++a)
          xyz_[3 * j + static_cast<std::size_t>(a)] = points[i].position[a];
        original_[j] = i;
        slot_[i] = static_cast<std::uint32_t>(j);
      },
      kBlock);
  for (std::size_t j = 0; j < n_; ++j) {
    const std::uint64_t key = keyed[j].code >> shift;
    if (cubeKey_.empty() || cubeKey_.back() != key) {
      cubeKey_.push_back(key);
      cubeStart_.push_back(static_cast<std::uint32_t>(j));
    }
  }
  cubeStart_.push_back(static_cast<std::uint32_t>(n_));
  const std::size_t tableSize = std::bit_ceil(2 * cubeKey_.size() + 1);
  table_.assign(tableSize, 0);
  tableMask_ = tableSize - 1;
  for (std::size_t c = 0; c < cubeKey_.size(); ++c) {
    std::uint64_t at = firstSlot(cubeKey_[c], tableMask_);
    while (table_[at] != 0) at = (at + 1) & tableMask_;
    table_[at] = static_cast<std::uint32_t>(c + 1);
  }
}

std::size_t NeighbourGrid::findCube(std::uint64_t key) const {
  for (std::uint64_t at = firstSlot(key, tableMask_);; at = (at + 1) & tableMask_) {
    const std::uint32_t c = table_[at];
    if (c == 0) return kNotFound;
    if (cubeKey_[c - 1] == key) return c - 1;
  }
}

void NeighbourGrid::nearestInCube(std::size_t cube, std::size_t k, const NeighboursFn& fn) const {
  const std::size_t want = std::min(k, n_ == 0 ? 0 : n_ - 1);
  const std::int64_t cubes = std::int64_t{1} << level_;
  std::int64_t c[3];
  for (int a = 0; a < 3; ++a)
    c[a] = static_cast<std::int64_t>(compactBits(cubeKey_[cube] >> (2 - a)));
  // The points of the block of 3x3x3 cubes around, as columns for the SIMD
  // filter.
  thread_local std::vector<float> cx, cy, cz, passedDistance;
  thread_local std::vector<std::uint32_t> cid, passedId;
  thread_local std::vector<std::uint32_t> index;
  thread_local std::vector<float> distance2;
  // A neighbour as one key: its squared distance (never negative, so its bits
  // order as the value does) above its index, which breaks ties. The k
  // nearest are the k smallest keys.
  thread_local std::vector<std::uint64_t> keys, spareKeys;
  index.resize(want + 1);
  distance2.resize(want + 1);
  // The occupied cubes around first (their lookups independent of each
  // other), then their points copied in one sized pass.
  std::array<std::size_t, 27> around;
  std::size_t cubesAround = 0, n = 0;  // the queries themselves among the n
  std::int64_t q[3];
  for (std::int64_t dx = -1; dx <= 1; ++dx)
    for (std::int64_t dy = -1; dy <= 1; ++dy)
      for (std::int64_t dz = -1; dz <= 1; ++dz) {
        q[0] = c[0] + dx;
        q[1] = c[1] + dy;
        q[2] = c[2] + dz;
        if (q[0] < 0 || q[1] < 0 || q[2] < 0 || q[0] >= cubes || q[1] >= cubes || q[2] >= cubes)
          continue;
        const std::size_t other = dx == 0 && dy == 0 && dz == 0 ? cube : findCube(interleave(q));
        if (other == kNotFound) continue;
        around[cubesAround++] = other;
        n += cubeStart_[other + 1] - cubeStart_[other];
      }
  cx.resize(n);
  cy.resize(n);
  cz.resize(n);
  cid.resize(n);
  std::size_t at = 0;
  for (std::size_t a = 0; a < cubesAround; ++a) {
    for (std::uint32_t j = cubeStart_[around[a]]; j < cubeStart_[around[a] + 1]; ++j, ++at) {
      cx[at] = xyz_[3 * j];
      cy[at] = xyz_[3 * j + 1];
      cz[at] = xyz_[3 * j + 2];
      cid[at] = original_[j];
    }
  }
  passedDistance.resize(n);
  passedId.resize(n);
  keys.resize(n + kSortKeysPad);
  spareKeys.resize(n + kSortKeysPad);
  // The previous query's k-th distance bounds this one's: its k nearest and
  // itself lie within that distance plus the step between the two. Kept
  // from the previous cube (the next one in Morton order, mostly a
  // neighbour): a cube's first query had no bound and passed every candidate.
  thread_local double previousKth = std::numeric_limits<double>::infinity();
  thread_local float previous[3] = {0.0f, 0.0f, 0.0f};
  for (std::uint32_t self = cubeStart_[cube]; self < cubeStart_[cube + 1]; ++self) {
    const float p[3] = {xyz_[3 * self], xyz_[3 * self + 1], xyz_[3 * self + 2]};
    const std::uint64_t selfKey = original_[self];  // at distance 0
    std::size_t found = std::min(want, n - 1);
    if (found > 0) {
      double step = 0.0;
      for (int a = 0; a < 3; ++a) {
        const double t = static_cast<double>(p[a]) - static_cast<double>(previous[a]);
        step += t * t;
      }
      const double reach = std::sqrt(previousKth) + std::sqrt(step);
      // A margin for the rounding of float distances. Any bound gives the
      // exact neighbours as long as the query and `found` others pass it.
      const auto bound = static_cast<float>(reach * reach * (1.0 + 1e-4));
      const auto tight = static_cast<float>(std::min(reach * reach, previousKth * kTightBound));
      std::size_t passed = candidatesWithin(cx.data(), cy.data(), cz.data(), cid.data(), n, p,
                                            tight, passedDistance.data(), passedId.data());
      if (passed <= found)
        passed = candidatesWithin(cx.data(), cy.data(), cz.data(), cid.data(), n, p, bound,
                                  passedDistance.data(), passedId.data());
      if (passed <= found) {
        passed = candidatesWithin(cx.data(), cy.data(), cz.data(), cid.data(), n, p,
                                  std::numeric_limits<float>::infinity(), passedDistance.data(),
                                  passedId.data());
      }
      const auto keyOf = [&](std::size_t j) {
        return std::uint64_t{std::bit_cast<std::uint32_t>(passedDistance[j])} << 32 | passedId[j];
      };
      for (std::size_t j = 0; j < passed; ++j) keys[j] = keyOf(j);
      // The found + 1 smallest keys are the query's own and its neighbours
      // (the query's own is not among them only where more than `found`
      // points coincide with it).
      if (passed <= kSortAllUpTo) {
        sortDistinctKeys(keys.data(), passed, spareKeys.data());
        std::size_t kept = 0;
        for (std::size_t j = 0; j <= found && j < passed; ++j) {
          keys[kept] = spareKeys[j];
          kept += spareKeys[j] != selfKey;
        }
        found = std::min(found, kept);
      } else {
        // The keys are distinct, so exactly those are at most the last.
        const std::uint64_t last = kthSmallest(keys.data(), spareKeys.data(), passed, found);
        std::size_t kept = 0;
        for (std::size_t j = 0; j < passed; ++j) {
          const std::uint64_t key = keyOf(j);
          keys[kept] = key;
          kept += (key <= last) & (key != selfKey);
        }
        // Where the query's own is not among them, the found + 1 kept in
        // candidate order: all sorted, so the `found` nearest come first.
        std::sort(keys.begin(), keys.begin() + static_cast<std::ptrdiff_t>(kept));
        found = std::min(found, kept);
      }
    }
    for (std::size_t j = 0; j < found; ++j) {
      distance2[j] = std::bit_cast<float>(static_cast<std::uint32_t>(keys[j] >> 32));
      index[j] = static_cast<std::uint32_t>(keys[j]);
    }
    previousKth = found == want && want > 0 ? static_cast<double>(distance2[want - 1])
                                            : std::numeric_limits<double>::infinity();
    for (int a = 0; a < 3; ++a) previous[a] = p[a];
    // Exact when the k-th is nearer than anything outside the block.
    double bound = std::numeric_limits<double>::infinity();
    for (int a = 0; a < 3; ++a) {
      const double x = (static_cast<double>(p[a]) - min_[a]) * scale_;
      if (c[a] - 1 > 0) bound = std::min(bound, x - static_cast<double>(c[a] - 1));
      if (c[a] + 1 < cubes - 1) bound = std::min(bound, static_cast<double>(c[a] + 2) - x);
    }
    bound /= scale_;
    const bool exact =
        bound == std::numeric_limits<double>::infinity() ||
        (found == want && static_cast<double>(distance2[want - 1]) * (1.0 + 1e-5) < bound * bound);
    if (want == 0 || exact) {
      fn(original_[self], index.data(), distance2.data(), found);
    } else {
      found = nearest(original_[self], k, index.data(), distance2.data());
      fn(original_[self], index.data(), distance2.data(), found);
    }
  }
}

std::size_t NeighbourGrid::nearest(std::size_t i, std::size_t k, std::uint32_t* index,
                                   float* distance2) const {
  const std::size_t want = std::min(k, n_ == 0 ? 0 : n_ - 1);
  if (want == 0) return 0;
  const std::size_t self = slot_[i];
  const float p[3] = {xyz_[3 * self], xyz_[3 * self + 1], xyz_[3 * self + 2]};
  const std::int64_t cubes = std::int64_t{1} << level_;
  std::int64_t c[3];
  for (int a = 0; a < 3; ++a) {
    const double t = (static_cast<double>(p[a]) - min_[a]) * scale_;
    c[a] = std::clamp<std::int64_t>(static_cast<std::int64_t>(t < 0.0 ? 0.0 : t), 0, cubes - 1);
  }
  std::size_t found = 0;
  const auto consider = [&](std::size_t cube) {
    for (std::size_t j = cubeStart_[cube]; j < cubeStart_[cube + 1]; ++j) {
      if (j == self) continue;
      const float dx = xyz_[3 * j] - p[0], dy = xyz_[3 * j + 1] - p[1], dz = xyz_[3 * j + 2] - p[2];
      const float d = dx * dx + dy * dy + dz * dz;
      const std::uint32_t id = original_[j];
      if (found == want &&
          (d > distance2[want - 1] || (d == distance2[want - 1] && id > index[want - 1])))
        continue;
      // Insertion into the sorted list (distance, then index).
      std::size_t at = found < want ? found++ : want - 1;
      while (at > 0 && (distance2[at - 1] > d || (distance2[at - 1] == d && index[at - 1] > id))) {
        distance2[at] = distance2[at - 1];
        index[at] = index[at - 1];
        --at;
      }
      distance2[at] = d;
      index[at] = id;
    }
  };
  for (std::int64_t r = 0;; ++r) {
    std::int64_t q[3];
    for (std::int64_t dx = -r; dx <= r; ++dx) {
      q[0] = c[0] + dx;
      if (q[0] < 0 || q[0] >= cubes) continue;
      for (std::int64_t dy = -r; dy <= r; ++dy) {
        q[1] = c[1] + dy;
        if (q[1] < 0 || q[1] >= cubes) continue;
        const bool innerXY = std::abs(dx) < r && std::abs(dy) < r;
        for (std::int64_t dz = -r; dz <= r; dz += (innerXY ? 2 * r : 1)) {
          q[2] = c[2] + dz;
          if (q[2] >= 0 && q[2] < cubes) {
            const std::size_t cube = findCube(interleave(q));
            if (cube != kNotFound) consider(cube);
          }
          if (r == 0) break;
        }
      }
    }
    // Anything not yet seen lies outside the block of cubes [c - r, c + r]:
    // at least this far away (sides at the grid's edge hold nothing beyond).
    double bound = std::numeric_limits<double>::infinity();
    for (int a = 0; a < 3; ++a) {
      const double x = (static_cast<double>(p[a]) - min_[a]) * scale_;
      if (c[a] - r > 0) bound = std::min(bound, x - static_cast<double>(c[a] - r));
      if (c[a] + r < cubes - 1) bound = std::min(bound, static_cast<double>(c[a] + r + 1) - x);
    }
    if (bound == std::numeric_limits<double>::infinity()) break;  // every cube seen
    bound /= scale_;
    // A little margin for float rounding of the distances.
    if (found == want && static_cast<double>(distance2[want - 1]) * (1.0 + 1e-5) < bound * bound)
      break;
    // Far from everything (an outlier): shells would grow as r^3; go through
    // the occupied cubes beyond this block instead, nearest box first not needed.
    const double nextShell = static_cast<double>(2 * r + 3);
    if (nextShell * nextShell * nextShell > 8.0 * static_cast<double>(cubeKey_.size()) + 64.0) {
      for (std::size_t cube = 0; cube < cubeKey_.size(); ++cube) {
        double gap2 = 0.0;
        bool inside = true;
        for (int a = 0; a < 3; ++a) {
          const auto at = static_cast<std::int64_t>(compactBits(cubeKey_[cube] >> (2 - a)));
          inside = inside && std::abs(at - c[a]) <= r;
          const double x = (static_cast<double>(p[a]) - min_[a]) * scale_;
          const double gap =
              std::max({0.0, static_cast<double>(at) - x, x - static_cast<double>(at + 1)});
          gap2 += gap * gap;
        }
        if (inside) continue;  // seen in the shells
        if (found == want &&
            gap2 / (scale_ * scale_) > static_cast<double>(distance2[want - 1]) * (1.0 + 1e-5))
          continue;
        consider(cube);
      }
      break;
    }
  }
  return found;
}

}  // namespace pointillist::preprocess
