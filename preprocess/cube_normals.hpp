#pragma once
// Normals and radii from the moments of small cubes (NormalMethod::Moments,
// normals.hpp), for scans without normals: a k-nearest-neighbour search per
// point was most of a preprocess of such a scan.
//
// The points are bucketed into cubes of a lattice sized so an occupied cube
// holds about kMomentPointsPerCube points. Each cube keeps the sums of its
// points (count, positions, outer products). A cube's block is the 3x3x3
// cubes around it, whose summed moments give the covariance of its 15-40
// points on a surface (about the neighbourhood of 12 nearest neighbours),
// with no search and no sort: the block's smallest eigenvector is the normal
// of every point of the cube (where an edge runs through the block, the
// flattest 2x2x2 block's), and its density gives their radius
// (r = sqrt(3 area / (pi n)), area = 12 sqrt(l1 l2) from the two largest
// eigenvalues, the rule of normals.hpp: pi r^2 = 3 / density).
//
// The lattice is anchored at the octree's cube and its side is chosen from a
// sample of the cloud picked by a hash of each position, so the whole cloud
// in memory and its chunks out of core get the same cubes and the same
// normals inside every chunk.
#include <array>
#include <bit>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <numbers>
#include <span>
#include <vector>

#include "common/splat.hpp"
#include "common/uninitialized_allocator.hpp"

namespace pointillist::preprocess {

struct CubeLattice {
  double origin[3] = {0.0, 0.0, 0.0};
  double side = 0.0;  // 0: not chosen yet
};

// The mean occupancy of an occupied cube aimed at. chooseCubeLattice lands
// somewhat above it (1.7-2.4 on the bunny, CGAL's scans, the city, a
// sphere): finer cubes cost time, coarser ones blur curves and creases
// (README, "Normals from cube moments").
inline constexpr double kMomentPointsPerCube = 1.6;

// A hash of a point's position (stable across runs and machines): samples
// are the points whose hash falls in one residue class, so a chunk or the
// whole cloud picks the same points without a look-up.
inline std::uint64_t positionHash(const Splat& s) {
  std::uint64_t h = 0x9E3779B97F4A7C15ull;
  for (const float c : s.position)
    h = (h ^ std::bit_cast<std::uint32_t>(c)) * 0xC2B2AE3D27D4EB4Full;
  return h ^ (h >> 29);
}

// Whether a point is in the sample of one point in about `every`: the one
// rule the in-memory and the out-of-core paths both draw their samples by.
inline bool inHashSample(const Splat& s, std::uint64_t every) {
  return positionHash(s) % every == 0;
}

// The radius rule of normals.hpp (pi r^2 = 3 / density) for n points whose
// covariance's two largest eigenvalues are l1 >= l2: they span about
// 12 sqrt(l1 l2) (exact for a uniformly sampled rectangle, l = side^2 / 12).
// 0 when they span no area (fewer than three, or on a line).
inline double radiusFromSpread(double l1, double l2, double n) {
  if (!(n >= 3.0) || !(l1 > 0.0) || !(l2 > 1e-12 * l1)) return 0.0;
  const double area = 12.0 * std::sqrt(l1 * l2);
  return std::sqrt(3.0 * area / (std::numbers::pi * n));
}

// The lattice's sample: points inHashSample(s, every), every from
// the cloud's whole count (about 65536 points).
std::uint64_t latticeSampleEvery(std::uint64_t points);

// Appends the points of `points` inHashSample(s, every) to `sample`, in
// order, hashed on all cores (a hash and a 64-bit division a point on one
// thread held the other cores waiting).
void appendHashSample(std::span<const Splat> points, std::uint64_t every,
                      std::vector<Splat>& sample);

// The side for a cloud of which `sample` holds one point in about `every`,
// inside the octree's cube (`origin`, `extent`): measured on the sample
// where its cubes hold at least 8 points each, then carried down to the
// aimed occupancy by the way the cube count grew with the last halving (a
// surface: 4x a level). Depends only on its arguments.
CubeLattice chooseCubeLattice(std::span<const Splat> sample, std::uint64_t every,
                              const double origin[3], double extent,
                              double pointsPerCube = kMomentPointsPerCube);
// The same, drawing the sample from the whole cloud.
CubeLattice chooseCubeLattice(std::span<const Splat> points, const double origin[3], double extent,
                              double pointsPerCube = kMomentPointsPerCube);

// The points bucketed into the lattice's cubes (in Morton order of the cubes)
// and, per cube, the figures of its block.
class CubeBlocks {
 public:
  // Built on `threads` threads (0: all cores); the figures do not depend on
  // the thread count. `neighbours`: how many neighbouring cubes to list.
  CubeBlocks(std::span<const Splat> points, const CubeLattice& lattice, std::size_t neighbours,
             unsigned threads);

  std::size_t cubes() const { return cubeStart_.size() - 1; }
  // Indices into `points` of the cube's points.
  std::span<const std::uint32_t> pointsOf(std::size_t cube) const {
    return {order_.data() + cubeStart_[cube], cubeStart_[cube + 1] - cubeStart_[cube]};
  }
  // The block's smallest eigenvector (unit, either sign); 0,0,1 where the
  // block's points do not fix one (fewer than three, all on a line).
  const std::array<float, 3>& blockNormal(std::size_t cube) const { return blockNormal_[cube]; }
  // The normal of the cube's points: the block's, or where the block is far
  // from flat (an edge runs through it), that of the flattest 2x2x2 block
  // holding the cube, so points beside an edge take their own face's.
  const std::array<float, 3>& normal(std::size_t cube) const { return normal_[cube]; }
  // sqrt(3 area / (pi n)) over the block; 0 where its points span no area.
  float radius(std::size_t cube) const { return radius_[cube]; }
  // The mean position of the cube's own points.
  const std::array<float, 3>& centroid(std::size_t cube) const { return centroid_[cube]; }
  // Per cube, `neighbours` occupied cubes of the 26 around it, faces first,
  // then edges, then corners (each in a fixed order of offsets); where fewer
  // are occupied the last is repeated, and a cube with none lists itself.
  std::span<const std::uint32_t> neighbours() const { return neighbours_; }
  std::size_t neighbourCount() const { return k_; }

 private:
  template <class T>
  using Filled = std::vector<T, UninitializedAllocator<T>>;
  std::size_t k_ = 0;
  Filled<std::uint32_t> order_;
  std::vector<std::uint32_t> cubeStart_;
  Filled<std::array<float, 3>> normal_;
  Filled<std::array<float, 3>> blockNormal_;
  Filled<float> radius_;
  Filled<std::array<float, 3>> centroid_;
  Filled<std::uint32_t> neighbours_;
};

}  // namespace pointillist::preprocess
