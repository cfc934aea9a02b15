#pragma once
// Exact k nearest neighbours through a uniform grid, for normal and radius
// estimation: a grid of cubes sized so an occupied cube holds a handful of
// points, the points stored cube by cube (a Morton order of the cubes, so a
// cloud already in Morton order is not moved), cubes found by hashing, and a
// query that scans shells of cubes around the point's own until the k-th
// nearest is closer than anything outside them. On scanned surfaces it needs
// no tree descent and reads neighbouring points from neighbouring memory;
// deploy/bench-preprocess.sh measures it against the nanoflann kd-tree
// (pointillist-preprocess --neighbour-search kdtree).
#include <cstddef>
#include <cstdint>
#include <functional>
#include <span>
#include <vector>

#include "common/splat.hpp"
#include "common/uninitialized_allocator.hpp"

namespace pointillist::preprocess {

class NeighbourGrid {
 public:
  // pointsPerCube: the least mean occupancy of an occupied cube to aim for.
  // Built on `threads` threads (0: all cores).
  explicit NeighbourGrid(std::span<const Splat> points, double pointsPerCube = 6.0,
                         unsigned threads = 0);

  // The k nearest points to points[i] other than i itself, nearest first
  // (equal distances by index), as indices into `points` and squared
  // distances (float, as the positions). Returns min(k, n - 1).
  std::size_t nearest(std::size_t i, std::size_t k, std::uint32_t* index, float* distance2) const;

  // The same for every point of occupied cube `cube` (0 .. occupiedCubes()),
  // cheaper: the points of the 27 cubes around it are gathered once for all
  // of them. fn(i, index, distance2, count) for each point i of the cube.
  using NeighboursFn = std::function<void(std::size_t i, const std::uint32_t* index,
                                          const float* distance2, std::size_t count)>;
  void nearestInCube(std::size_t cube, std::size_t k, const NeighboursFn& fn) const;

  unsigned level() const { return level_; }  // cubes per axis: 2^level
  std::size_t occupiedCubes() const { return cubeKey_.size(); }

 private:
  std::size_t findCube(std::uint64_t key) const;  // npos when empty

  std::size_t n_ = 0;
  unsigned level_ = 0;
  double min_[3] = {0, 0, 0};
  double scale_ = 1.0;  // cubes per unit length
  // Written in full on all threads: not zeroed first.
  template <class T>
  using Filled = std::vector<T, UninitializedAllocator<T>>;
  Filled<float> xyz_;                   // positions cube by cube
  Filled<std::uint32_t> original_;      // their indices in `points`
  Filled<std::uint32_t> slot_;          // points[i] sits at slot_[i]
  std::vector<std::uint64_t> cubeKey_;  // occupied cubes, ascending Morton key
  std::vector<std::uint32_t> cubeStart_;
  std::vector<std::uint32_t> table_;  // open addressing: cube index + 1, 0 empty
  std::uint64_t tableMask_ = 0;
};

}  // namespace pointillist::preprocess
