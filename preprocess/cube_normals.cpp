#include "preprocess/cube_normals.hpp"

#include <algorithm>
#include <cmath>

#include "common/geometry.hpp"
#include "preprocess/eigen_batch.hpp"
#include "preprocess/octree_builder.hpp"
#include "preprocess/parallel.hpp"

namespace pointillist::preprocess {

namespace {

constexpr unsigned kCoordinateBits = 21;  // per axis, as spreadBits takes them
constexpr std::uint64_t kMaxCoordinate = (std::uint64_t{1} << kCoordinateBits) - 1;
constexpr std::size_t kNotFound = static_cast<std::size_t>(-1);
// The sample's cubes are taken as the whole cloud's where each holds at least
// this many sample points: nearly every cube the cloud occupies has one then.
constexpr double kReliableSamplePoints = 8.0;

// A cube's sums, relative to its centre (small numbers: floats suffice).
struct CubeSums {
  float count;
  float sum[3];
  float square[6];  // xx xy xz yy yz zz
};

}  // namespace

std::uint64_t latticeSampleEvery(std::uint64_t points) {
  constexpr std::uint64_t kSamplePoints = std::uint64_t{1} << 16;
  return std::max<std::uint64_t>(1, (points + kSamplePoints - 1) / kSamplePoints);
}

CubeLattice chooseCubeLattice(std::span<const Splat> sample, std::uint64_t every,
                              const double origin[3], double extent, double pointsPerCube) {
  CubeLattice lattice;
  for (int a = 0; a < 3; ++a) lattice.origin[a] = origin[a];
  if (!(extent > 0.0) || !std::isfinite(extent)) extent = 1.0;
  const double finest = std::ldexp(extent, -static_cast<int>(kCoordinateBits));
  lattice.side = extent;
  if (sample.size() < 2) return lattice;
  std::vector<std::uint64_t> codes;
  codes.reserve(sample.size());
  const double scale = std::ldexp(1.0, static_cast<int>(kCoordinateBits)) / extent;
  for (const Splat& s : sample) {
    std::uint64_t q[3];
    for (int a = 0; a < 3; ++a) {
      const double c = std::floor((static_cast<double>(s.position[a]) - origin[a]) * scale);
      q[a] = c > 0.0 ? std::min<std::uint64_t>(static_cast<std::uint64_t>(c), kMaxCoordinate) : 0;
    }
    codes.push_back(mortonInterleave(q));
  }
  std::sort(codes.begin(), codes.end());
  // Occupied cubes of side extent / 2^level, per level.
  std::array<double, kCoordinateBits + 1> cubes{};
  for (unsigned level = 0; level <= kCoordinateBits; ++level) {
    const unsigned shift = 3 * (kCoordinateBits - level);
    std::size_t distinct = 1;
    for (std::size_t i = 1; i < codes.size(); ++i)
      distinct += (codes[i] >> shift) != (codes[i - 1] >> shift) ? 1u : 0u;
    cubes[level] = static_cast<double>(distinct);
  }
  const auto n = static_cast<double>(codes.size());
  unsigned reliable = 0;
  while (reliable < kCoordinateBits && n / cubes[reliable + 1] >= kReliableSamplePoints) ++reliable;
  // How the cube count grew with the last halving there: 4 on a surface,
  // 2 along a line, 8 through a volume.
  const double growth =
      reliable > 0 ? std::clamp(cubes[reliable] / cubes[reliable - 1], 2.0, 8.0) : 4.0;
  const double occupancy = static_cast<double>(every) * n / cubes[reliable];
  const double side = std::ldexp(extent, -static_cast<int>(reliable)) *
                      std::pow(pointsPerCube / occupancy, 1.0 / std::log2(growth));
  lattice.side = std::clamp(side, finest, extent);
  return lattice;
}

void appendHashSample(std::span<const Splat> points, std::uint64_t every,
                      std::vector<Splat>& sample) {
  constexpr std::size_t kBlock = std::size_t{1} << 15;
  std::vector<std::vector<Splat>> picked((points.size() + kBlock - 1) / kBlock);
  parallelFor(
      picked.size(), 0,
      [&](std::size_t b) {
        for (const Splat& s :
             points.subspan(b * kBlock, std::min(kBlock, points.size() - b * kBlock)))
          if (inHashSample(s, every)) picked[b].push_back(s);
      },
      1);
  for (const auto& block : picked) sample.insert(sample.end(), block.begin(), block.end());
}

CubeLattice chooseCubeLattice(std::span<const Splat> points, const double origin[3], double extent,
                              double pointsPerCube) {
  const std::uint64_t every = latticeSampleEvery(points.size());
  std::vector<Splat> sample;
  appendHashSample(points, every, sample);
  return chooseCubeLattice(sample, every, origin, extent, pointsPerCube);
}

CubeBlocks::CubeBlocks(std::span<const Splat> points, const CubeLattice& lattice,
                       std::size_t neighbours, unsigned threads)
    : k_(neighbours) {
  const std::size_t n = points.size();
  cubeStart_.assign(1, 0);
  if (n == 0) return;
  const double side = lattice.side > 0.0 ? lattice.side : 1.0;
  const double inverse = 1.0 / side;
  const auto coordinate = [&](float p, std::size_t a) -> std::uint64_t {
    const double c = std::floor((static_cast<double>(p) - lattice.origin[a]) * inverse);
    return c > 0.0 ? std::min<std::uint64_t>(static_cast<std::uint64_t>(c), kMaxCoordinate) : 0;
  };

  // Points sorted by cube (stable: by index within one). Key and index
  // packed in one word where they fit (half the bytes to sort).
  constexpr std::size_t kBlock = std::size_t{1} << 16;
  const std::size_t blocks = (n + kBlock - 1) / kBlock;
  Filled<std::uint64_t> keys(n);
  std::vector<std::uint64_t> blockHighest(blocks, 0);
  parallelFor(
      blocks, threads,
      [&](std::size_t b) {
        std::uint64_t highest = 0;
        for (std::size_t i = b * kBlock; i < std::min(n, (b + 1) * kBlock); ++i) {
          std::uint64_t q[3];
          for (std::size_t a = 0; a < 3; ++a) q[a] = coordinate(points[i].position[a], a);
          keys[i] = mortonInterleave(q);
          highest = std::max(highest, keys[i]);
        }
        blockHighest[b] = highest;
      },
      1);
  const auto keyBits = static_cast<unsigned>(
      std::bit_width(*std::max_element(blockHighest.begin(), blockHighest.end())));
  const auto indexBits = static_cast<unsigned>(std::bit_width(n - 1));
  std::vector<std::uint64_t> cubeKey;
  order_.resize(n);
  // The sorted points' keys and indices to the cubes: each block of them
  // finds where cubes start in it, then the blocks' finds are joined.
  const auto scan = [&](const auto& keyAt, const auto& indexAt) {
    std::vector<std::vector<std::uint32_t>> starts(blocks);
    parallelFor(
        blocks, threads,
        [&](std::size_t b) {
          for (std::size_t j = b * kBlock; j < std::min(n, (b + 1) * kBlock); ++j) {
            order_[j] = indexAt(j);
            if (j == 0 || keyAt(j) != keyAt(j - 1))
              starts[b].push_back(static_cast<std::uint32_t>(j));
          }
        },
        1);
    cubeStart_.clear();
    for (const auto& list : starts) cubeStart_.insert(cubeStart_.end(), list.begin(), list.end());
    cubeKey.resize(cubeStart_.size());
    parallelFor(
        cubeStart_.size(), threads, [&](std::size_t c) { cubeKey[c] = keyAt(cubeStart_[c]); },
        kBlock);
    cubeStart_.push_back(static_cast<std::uint32_t>(n));
  };
  if (keyBits + indexBits <= 64) {
    parallelFor(
        n, threads, [&](std::size_t i) { keys[i] = keys[i] << indexBits | i; }, kBlock);
    radixSort<11>(
        keys, indexBits, indexBits + keyBits, [](std::uint64_t item) { return item; }, {}, threads);
    const std::uint64_t indexMask = (std::uint64_t{1} << indexBits) - 1;
    scan([&](std::size_t j) { return keys[j] >> indexBits; },
         [&](std::size_t j) { return static_cast<std::uint32_t>(keys[j] & indexMask); });
  } else {
    struct Keyed {
      std::uint64_t key;
      std::uint32_t index;
    };
    Filled<Keyed> keyed(n);
    parallelFor(
        n, threads,
        [&](std::size_t i) {
          keyed[i] = {keys[i], static_cast<std::uint32_t>(i)};
        },
        kBlock);
    keys = {};
    radixSort(
        keyed, 0, keyBits, [](const Keyed& k) { return k.key; }, {}, threads);
    scan([&](std::size_t j) { return keyed[j].key; },
         [&](std::size_t j) { return keyed[j].index; });
  }
  keys = {};
  const std::size_t count = cubeKey.size();

  // Bricks of 4x4x4 cubes (a Morton key's low 6 bits): a brick's cubes are
  // one run of the sorted cubes, each brick keeps a dense table of its 64,
  // and the bricks are hashed.
  std::vector<std::uint64_t> brickKey;
  std::vector<std::uint32_t> brickStart;
  // Per brick, each of its 64 cubes as an offset from the brick's first
  // (kEmptyCube: not occupied): one cache line a brick.
  constexpr std::uint8_t kEmptyCube = 0xFF;
  std::vector<std::array<std::uint8_t, 64>> brickCubes;
  for (std::size_t c = 0; c < count; ++c) {
    if (brickKey.empty() || brickKey.back() != cubeKey[c] >> 6) {
      brickKey.push_back(cubeKey[c] >> 6);
      brickStart.push_back(static_cast<std::uint32_t>(c));
      brickCubes.emplace_back().fill(kEmptyCube);
    }
    brickCubes.back()[cubeKey[c] & 63u] = static_cast<std::uint8_t>(c - brickStart.back());
  }
  brickStart.push_back(static_cast<std::uint32_t>(count));
  const std::size_t bricks = brickKey.size();
  // The hash holds key and index side by side: one miss a look-up.
  struct Slot {
    std::uint64_t key;
    std::uint64_t brick;  // + 1; 0 empty
  };
  const std::size_t tableSize = std::bit_ceil(2 * bricks + 1);
  const std::uint64_t mask = tableSize - 1;
  const auto slotOf = [&](std::uint64_t brick) {
    return (brick * 0x9E3779B97F4A7C15ull >> 20) & mask;
  };
  std::vector<Slot> table(tableSize, Slot{0, 0});
  for (std::size_t k = 0; k < bricks; ++k) {
    std::uint64_t at = slotOf(brickKey[k]);
    while (table[at].brick != 0) at = (at + 1) & mask;
    table[at] = {brickKey[k], k + 1};
  }
  const auto findBrick = [&](std::uint64_t brick) -> std::size_t {
    for (std::uint64_t at = slotOf(brick);; at = (at + 1) & mask) {
      const Slot& slot = table[at];
      if (slot.brick == 0) return kNotFound;
      if (slot.key == brick) return slot.brick - 1;
    }
  };
  const auto coordinateOf = [&](std::size_t c, std::size_t a) {
    return compactBits(cubeKey[c] >> (2 - a));
  };

  // Each cube's sums (about its centre) and centroid.
  Filled<CubeSums> sums(count);
  centroid_.resize(count);
  parallelFor(
      count, threads,
      [&](std::size_t c) {
        double middle[3];
        for (std::size_t a = 0; a < 3; ++a)
          middle[a] = lattice.origin[a] + (static_cast<double>(coordinateOf(c, a)) + 0.5) * side;
        double sum[3] = {0, 0, 0}, square[6] = {0, 0, 0, 0, 0, 0};
        // The points are in the octree's order, not the lattice's: fetched
        // 16 cubes ahead, their misses overlap (0.2 -> 0.12 s on 10 M points).
        if (c + 16 < count) {
          const std::span<const std::uint32_t> ahead = pointsOf(c + 16);
          for (const std::uint32_t i : ahead) __builtin_prefetch(&points[i]);
        }
        for (const std::uint32_t i : pointsOf(c)) {
          double d[3];
          for (std::size_t a = 0; a < 3; ++a)
            d[a] = static_cast<double>(points[i].position[a]) - middle[a];
          for (std::size_t a = 0; a < 3; ++a) sum[a] += d[a];
          square[0] += d[0] * d[0];
          square[1] += d[0] * d[1];
          square[2] += d[0] * d[2];
          square[3] += d[1] * d[1];
          square[4] += d[1] * d[2];
          square[5] += d[2] * d[2];
        }
        const auto m = static_cast<double>(cubeStart_[c + 1] - cubeStart_[c]);
        CubeSums& s = sums[c];
        s.count = static_cast<float>(m);
        for (std::size_t a = 0; a < 3; ++a) {
          s.sum[a] = static_cast<float>(sum[a]);
          centroid_[c][a] = static_cast<float>(middle[a] + sum[a] / m);
        }
        for (std::size_t j = 0; j < 6; ++j) s.square[j] = static_cast<float>(square[j]);
      },
      4096);

  // Each cube's block, brick by brick: the brick's cubes and the layer of
  // cubes around it (6x6x6) as a dense window of sums about one corner, so
  // a block is 27 additions of dense cells, with no look-up per cube. Then
  // the block's covariance, the normal and radius (eigenvectors a batch at
  // a time), and the neighbour cubes nearest in the lattice.
  normal_.resize(count);
  blockNormal_.resize(count);
  radius_.resize(count);
  neighbours_.resize(count * k_);
  constexpr std::size_t kSide = 6, kCells = kSide * kSide * kSide;
  // A window cell's 27 (with itself), and its 26 by lattice distance, as
  // steps in the window's cells.
  constexpr auto windowStep = [](std::ptrdiff_t dx, std::ptrdiff_t dy, std::ptrdiff_t dz) {
    constexpr auto width = static_cast<std::ptrdiff_t>(kSide);
    return (dx * width + dy) * width + dz;
  };
  std::array<std::ptrdiff_t, 27> blockSteps{};
  std::array<std::ptrdiff_t, 26> neighbourSteps{};
  {
    std::size_t all = 0, around = 0;
    for (int distance = 0; distance <= 3; ++distance)
      for (std::ptrdiff_t dx = -1; dx <= 1; ++dx)
        for (std::ptrdiff_t dy = -1; dy <= 1; ++dy)
          for (std::ptrdiff_t dz = -1; dz <= 1; ++dz) {
            if (std::abs(dx) + std::abs(dy) + std::abs(dz) != distance) continue;
            blockSteps[all++] = windowStep(dx, dy, dz);
            if (distance > 0) neighbourSteps[around++] = windowStep(dx, dy, dz);
          }
  }
  // Empty cells hold zeros, so a block adds its 27 cells without a branch;
  // the cells filled are listed and emptied again after the brick.
  // The eight 2x2x2 blocks that hold a cell, as steps: per axis the cell and
  // the one before it, or the cell and the one after.
  std::array<std::array<std::ptrdiff_t, 8>, 8> octantSteps{};
  for (std::size_t o = 0; o < 8; ++o) {
    std::size_t k = 0;
    for (std::ptrdiff_t dx = 0; dx < 2; ++dx)
      for (std::ptrdiff_t dy = 0; dy < 2; ++dy)
        for (std::ptrdiff_t dz = 0; dz < 2; ++dz)
          octantSteps[o][k++] =
              windowStep((o & 1) ? dx : dx - 1, (o & 2) ? dy : dy - 1, (o & 4) ? dz : dz - 1);
  }
  // A block is far from flat above this variation (0.01 helped the building
  // as much and cost the kitten more); a 2x2x2 block needs this many points
  // to be tried (10 did worse on all three scans).
  constexpr double kCreaseVariation = 0.03;
  constexpr double kOctantPoints = 6.0;
  struct Window {
    std::array<std::uint32_t, kCells> cube{};           // cube + 1; 0 empty
    std::array<std::array<double, 10>, kCells> sums{};  // count, sum xyz, squares
    std::array<std::uint16_t, kCells> filled{};
    std::size_t filledCount = 0;
    void empty() {
      for (std::size_t k = 0; k < filledCount; ++k) {
        cube[filled[k]] = 0;
        sums[filled[k]] = {};
      }
      filledCount = 0;
    }
  };
  // A brick's cubes, their blocks' covariances and eigenvectors, and where a
  // block is far from flat (an edge or corner runs through it), the eight
  // 2x2x2 blocks that hold the cube: the flattest of all gives the normal, so
  // a cube beside an edge takes the face it lies on, not a blend of both. The
  // 3 M city's mean error 4.8 -> 3.1 degrees, CGAL's building scan's median
  // 9.0 -> 6.5; its noisy kitten scan's mean 6.3 -> 6.4.
  constexpr std::size_t kBrickCubes = 64;
  struct BrickBatch {
    std::array<std::uint32_t, kBrickCubes> cube;
    std::array<std::size_t, kBrickCubes> self;
    std::array<Sym3, kBrickCubes> covariance;
    std::array<double, kBrickCubes> population;
    std::array<SmallestEigen3, kBrickCubes> eigen;
    std::array<Sym3, 8 * kBrickCubes> octant;
    std::array<std::uint8_t, 8 * kBrickCubes> owner;
    std::array<SmallestEigen3, 8 * kBrickCubes> octantEigen;
  };
  // lambda0 / (lambda0 + lambda1 + lambda2): 0 on a plane, 1/3 for a ball.
  const auto variationOf = [](const SmallestEigen3& e) {
    const double total = e.values[0] + e.values[1] + e.values[2];
    return total > 0.0 ? e.values[0] / total : 1.0;
  };
  const auto isPlane = [](const SmallestEigen3& e, double population) {
    const double l1 = e.values[2], l2 = e.values[1];
    return population >= 3.0 && l1 > 0.0 && l2 > 1e-12 * l1;
  };
  const auto covarianceOf = [](const std::array<double, 10>& block) {
    return covarianceFromSums(block[0], {block[1], block[2], block[3]},
                              {block[4], block[5], block[6], block[7], block[8], block[9]});
  };
  // Per task, the look-ups of bricks it made lately (direct-mapped): bricks
  // next to each other share most of their neighbours.
  constexpr unsigned kRecentBits = 9;
  using RecentBricks = std::array<std::pair<std::uint64_t, std::size_t>, 1u << kRecentBits>;
  constexpr std::uint64_t kNoBrick = ~std::uint64_t{0};
  const auto recentSlot = [](std::uint64_t key) {
    return (key * 0x9E3779B97F4A7C15ull) >> (64 - kRecentBits);
  };
  // The 27 bricks around `brick` (kNotFound: none there), by offset + 1.
  using Around = std::array<std::array<std::array<std::size_t, 3>, 3>, 3>;
  const auto findAround = [&](std::size_t brick, const std::int64_t b[3], RecentBricks& recent) {
    Around around;
    // The keys first, with the table's slots of those not seen lately
    // fetched ahead: the look-ups then miss the cache side by side, not one
    // after another.
    std::array<std::uint64_t, 27> aroundKeys;
    const auto lastBrick = static_cast<std::int64_t>(kMaxCoordinate >> 2);
    for (std::size_t k = 0; k < 27; ++k) {
      const std::int64_t q[3] = {b[0] + static_cast<std::int64_t>(k / 9) - 1,
                                 b[1] + static_cast<std::int64_t>(k / 3 % 3) - 1,
                                 b[2] + static_cast<std::int64_t>(k % 3) - 1};
      aroundKeys[k] = kNoBrick;
      if (k == 13 || std::min({q[0], q[1], q[2]}) < 0 || std::max({q[0], q[1], q[2]}) > lastBrick)
        continue;
      const std::uint64_t u[3] = {static_cast<std::uint64_t>(q[0]),
                                  static_cast<std::uint64_t>(q[1]),
                                  static_cast<std::uint64_t>(q[2])};
      aroundKeys[k] = mortonInterleave(u);
      if (recent[recentSlot(aroundKeys[k])].first != aroundKeys[k])
        __builtin_prefetch(&table[slotOf(aroundKeys[k])]);
    }
    for (std::size_t k = 0; k < 27; ++k) {
      std::size_t& found = around[k / 9][k / 3 % 3][k % 3];
      found = k == 13 ? brick : kNotFound;
      if (aroundKeys[k] == kNoBrick) continue;
      auto& hit = recent[recentSlot(aroundKeys[k])];
      if (hit.first != aroundKeys[k]) hit = {aroundKeys[k], findBrick(aroundKeys[k])};
      found = hit.second;
      __builtin_prefetch(brickCubes[found == kNotFound ? brick : found].data());
    }
    return around;
  };
  // The window of a brick: its cubes and the layer around, each cell's sums
  // about the window's corner (empty cells zero). Per axis, a brick before
  // gives the window's first cell (its last cube), the brick itself the
  // next four, a brick after the last.
  struct AxisCells {
    std::size_t first, count, local;
  };
  static constexpr AxisCells kAxis[3] = {{0, 1, 3}, {1, 4, 0}, {5, 1, 0}};
  static constexpr std::uint64_t kSpread[4] = {0, 1, 8, 9};  // 2-bit Morton spread
  const auto addToWindow = [&](std::uint32_t c, std::size_t x, std::size_t y, std::size_t z,
                               Window& w) {
    const std::size_t cell = (x * kSide + y) * kSide + z;
    w.cube[cell] = c + 1;
    w.filled[w.filledCount++] = static_cast<std::uint16_t>(cell);
    const CubeSums& s = sums[c];
    // The cube's centre from the window's corner.
    const double o[3] = {(static_cast<double>(x) + 0.5) * side,
                         (static_cast<double>(y) + 0.5) * side,
                         (static_cast<double>(z) + 0.5) * side};
    const double m = s.count;
    const double t[3] = {s.sum[0], s.sum[1], s.sum[2]};
    std::array<double, 10>& v = w.sums[cell];
    v[0] = m;
    for (std::size_t d = 0; d < 3; ++d) v[1 + d] = t[d] + m * o[d];
    v[4] = static_cast<double>(s.square[0]) + 2.0 * t[0] * o[0] + m * o[0] * o[0];
    v[5] = static_cast<double>(s.square[1]) + t[0] * o[1] + t[1] * o[0] + m * o[0] * o[1];
    v[6] = static_cast<double>(s.square[2]) + t[0] * o[2] + t[2] * o[0] + m * o[0] * o[2];
    v[7] = static_cast<double>(s.square[3]) + 2.0 * t[1] * o[1] + m * o[1] * o[1];
    v[8] = static_cast<double>(s.square[4]) + t[1] * o[2] + t[2] * o[1] + m * o[1] * o[2];
    v[9] = static_cast<double>(s.square[5]) + 2.0 * t[2] * o[2] + m * o[2] * o[2];
  };
  const auto fillWindow = [&](const Around& around, Window& w) {
    w.empty();
    for (std::size_t bx = 0; bx < 3; ++bx)
      for (std::size_t by = 0; by < 3; ++by)
        for (std::size_t bz = 0; bz < 3; ++bz) {
          const std::size_t owner = around[bx][by][bz];
          if (owner == kNotFound) continue;
          const AxisCells &ax = kAxis[bx], &ay = kAxis[by], &az = kAxis[bz];
          for (std::size_t x = 0; x < ax.count; ++x)
            for (std::size_t y = 0; y < ay.count; ++y)
              for (std::size_t z = 0; z < az.count; ++z) {
                const std::uint64_t slot =
                    kSpread[ax.local + x] << 2 | kSpread[ay.local + y] << 1 | kSpread[az.local + z];
                const std::uint8_t offset = brickCubes[owner][slot];
                if (offset != kEmptyCube)
                  addToWindow(brickStart[owner] + offset, ax.first + x, ay.first + y, az.first + z,
                              w);
              }
        }
  };
  // The sums of the window's cells at `self` + each step (empty cells zero).
  const auto sumCells = [](const Window& w, std::size_t self,
                           std::span<const std::ptrdiff_t> steps) {
    std::array<double, 10> block{};
    for (const std::ptrdiff_t step : steps) {
      const std::size_t cell = self + static_cast<std::size_t>(step);
      for (std::size_t j = 0; j < 10; ++j) block[j] += w.sums[cell][j];
    }
    return block;
  };
  const auto listNeighbours = [&](std::size_t c, std::size_t self, const Window& w) {
    std::array<std::uint32_t, 26> occupied;
    std::size_t listed = 0;
    for (const std::ptrdiff_t step : neighbourSteps) {
      const std::uint32_t other = w.cube[self + static_cast<std::size_t>(step)];
      occupied[listed] = other - 1;
      listed += other != 0 ? 1u : 0u;
    }
    std::uint32_t* list = neighbours_.data() + c * k_;
    for (std::size_t e = 0; e < k_; ++e)
      list[e] = e < listed   ? occupied[e]
                : listed > 0 ? occupied[listed - 1]
                             : static_cast<std::uint32_t>(c);
  };
  // A brick's cubes from its window: blocks, eigenvectors, the 2x2x2 blocks
  // of those far from flat, and each cube's normal and radius.
  const auto solveBrick = [&](std::size_t brick, const std::int64_t corner[3], const Window& w,
                              BrickBatch& b) {
    std::size_t m = 0;
    for (std::size_t c = brickStart[brick]; c < brickStart[brick + 1]; ++c, ++m) {
      std::size_t at[3];
      for (std::size_t a = 0; a < 3; ++a)
        at[a] = static_cast<std::size_t>(static_cast<std::int64_t>(coordinateOf(c, a)) - corner[a]);
      const std::size_t self = (at[0] * kSide + at[1]) * kSide + at[2];
      const std::array<double, 10> block = sumCells(w, self, blockSteps);
      b.cube[m] = static_cast<std::uint32_t>(c);
      b.self[m] = self;
      b.population[m] = block[0];
      b.covariance[m] = covarianceOf(block);
      listNeighbours(c, self, w);
    }
    smallestEigen3Batch(std::span<const Sym3>(b.covariance.data(), m),
                        std::span<SmallestEigen3>(b.eigen.data(), m));
    std::size_t octants = 0;
    for (std::size_t j = 0; j < m; ++j) {
      if (b.population[j] < kOctantPoints || variationOf(b.eigen[j]) <= kCreaseVariation) continue;
      for (const auto& steps : octantSteps) {
        const std::array<double, 10> block = sumCells(w, b.self[j], steps);
        if (block[0] < kOctantPoints) continue;
        b.octant[octants] = covarianceOf(block);
        b.owner[octants++] = static_cast<std::uint8_t>(j);
      }
    }
    smallestEigen3Batch(std::span<const Sym3>(b.octant.data(), octants),
                        std::span<SmallestEigen3>(b.octantEigen.data(), octants));
    std::array<const SmallestEigen3*, kBrickCubes> flattest;
    std::array<double, kBrickCubes> variation;
    for (std::size_t j = 0; j < m; ++j) {
      flattest[j] = &b.eigen[j];
      variation[j] = variationOf(b.eigen[j]);
    }
    for (std::size_t k = 0; k < octants; ++k) {
      const std::size_t j = b.owner[k];
      const double v = variationOf(b.octantEigen[k]);
      if (v < variation[j] && isPlane(b.octantEigen[k], kOctantPoints)) {
        variation[j] = v;
        flattest[j] = &b.octantEigen[k];
      }
    }
    const auto unit = [](const Vec3d& v, std::array<float, 3>& out) {
      const double length = std::sqrt(dot(v, v));
      for (std::size_t a = 0; a < 3; ++a) out[a] = static_cast<float>(v[a] / length);
    };
    for (std::size_t j = 0; j < m; ++j) {
      const SmallestEigen3& e = b.eigen[j];
      const bool plane = isPlane(e, b.population[j]);
      unit(plane ? e.vector : Vec3d{0.0, 0.0, 1.0}, blockNormal_[b.cube[j]]);
      unit(plane ? flattest[j]->vector : Vec3d{0.0, 0.0, 1.0}, normal_[b.cube[j]]);
      // The radius from the whole block: its density is the steadier.
      radius_[b.cube[j]] =
          static_cast<float>(radiusFromSpread(e.values[2], e.values[1], b.population[j]));
    }
  };
  constexpr std::size_t kBricksPerTask = 256;
  parallelFor((bricks + kBricksPerTask - 1) / kBricksPerTask, threads,
              [&](std::size_t task) {
                // Per thread, reached once a task (a thread_local named in the loops
                // is looked up at every use).
                thread_local Window windowOfThread;
                thread_local BrickBatch batchOfThread;
                Window& w = windowOfThread;
                BrickBatch& batch = batchOfThread;
                RecentBricks recent;
                recent.fill({kNoBrick, kNotFound});
                for (std::size_t brick = task * kBricksPerTask;
                     brick < std::min(bricks, (task + 1) * kBricksPerTask); ++brick) {
                  // The window's corner: the cube before the brick's first.
                  std::int64_t b[3], corner[3];
                  for (std::size_t a = 0; a < 3; ++a) {
                    b[a] = static_cast<std::int64_t>(compactBits(brickKey[brick] >> (2 - a)));
                    corner[a] = 4 * b[a] - 1;
                  }
                  fillWindow(findAround(brick, b, recent), w);
                  solveBrick(brick, corner, w, batch);
                }
              },
              1);
}

}  // namespace pointillist::preprocess
