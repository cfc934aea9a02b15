#pragma once
// Normals and splat radii from k nearest neighbours (003 §4.1: "derived from
// sample neighborhoods").
//
// Per point, over its k nearest neighbours (a uniform grid, or a nanoflann
// kd-tree; NormalOptions::search), or, with NormalMethod::Moments, over the
// points of a block of small cubes around it (cube_normals.hpp: the same
// rules, per cube, at a fraction of the cost):
//  - normal: the eigenvector of the smallest eigenvalue of the neighbourhood
//    covariance (smallestEigen3 of common/geometry.hpp, no Eigen);
//  - orientation: propagated along a minimum spanning tree of the neighbour
//    graph, most parallel normals first (weight 1 - |n_i . n_j|, Hoppe et al.
//    1992), but only across edges within 60 degrees: at creases and where
//    surfaces cross (a trunk through the ground) the sign would be a coin toss.
//    Points that already had a normal are anchors and the points they reach
//    agree with them. Every other connected piece is grown with arbitrary
//    sign and then turned as a whole: when mostly horizontal and facing one
//    way (terrain, floors, roofs), to point up; else away from its own
//    centroid (closed objects get outward normals, a flat torus too: it faces
//    up and down alike). The tree is grown in spatial blocks on all
//    cores and the blocks' pieces joined by a second tree over them.
//    Known weakness: surfaces that touch face to face or interpenetrate can
//    pass on a wrong sign.
//  - radius: r = d_k * sqrt(3 / k), d_k the distance to the k-th neighbour.
//    With local density rho, pi d_k^2 rho ~= k, so pi r^2 ~= 3 / rho: each disk
//    has three times the area per point and the disks cover the surface
//    without holes even where sampling is irregular. On a regular grid of
//    spacing s with k = 12, r = s.
// Points whose neighbours all coincide get the median radius of the others.
// Colours: readers already give grey to points without colour; when the cloud
// has no colours, splats left all zero (RGBA 0,0,0,0, never written) get that
// grey too.
#include <cstdint>
#include <functional>
#include <optional>

#include "common/geometry.hpp"
#include "preprocess/cube_normals.hpp"
#include "preprocess/octree_builder.hpp"
#include "preprocess/point_cloud.hpp"

namespace pointillist::preprocess {

// How the k nearest neighbours are found: a uniform grid (neighbour_grid.hpp)
// or a nanoflann kd-tree; both exact.
enum class NeighbourSearch { Grid, KdTree };

// What a point's normal and radius are measured over: its k nearest
// neighbours, or the block of 3x3x3 small cubes around its own
// (cube_normals.hpp); the cubes are oriented as points are, and each point
// takes its cube's normal and radius.
// Auto (the command line's default): Moments for clouds of at least
// kMomentNormalsFromPoints points, where the neighbour search was most of a
// preprocess, Neighbours below, where it costs little and sparse samplings of
// curved surfaces keep it a few degrees closer (README, "Normals from cube moments").
enum class NormalMethod { Neighbours, Moments, Auto };
inline constexpr std::uint64_t kMomentNormalsFromPoints = 2'000'000;
inline NormalMethod resolveNormalMethod(NormalMethod method, std::uint64_t points) {
  if (method != NormalMethod::Auto) return method;
  return points >= kMomentNormalsFromPoints ? NormalMethod::Moments : NormalMethod::Neighbours;
}

struct NormalOptions {
  int neighbours = 12;
  NeighbourSearch search = NeighbourSearch::Grid;
  NormalMethod method = NormalMethod::Neighbours;
  // Moments: the cubes (side 0: chosen from this cloud, inside its bounding
  // cube). A chunk out of core is given the whole cloud's.
  CubeLattice lattice;
  // Only fill in what is missing: zero normals, non-positive radii. When false,
  // every normal and radius is recomputed (new normals keep the side of old ones).
  bool onlyWhereMissing = true;
  unsigned threads = 0;  // for the neighbour search; 0: all cores (at most 8)
  // Orientation runs in blocks of this many consecutive points on all cores,
  // then joins the blocks' pieces (see normals.cpp); the result does not
  // depend on the thread count.
  std::size_t orientBlockPoints = std::size_t{1} << 18;
  // Where set, a piece that no anchor reaches takes the side most of its
  // points with a reference normal (given here) agree with, before the
  // rules: out of core, from the whole cloud oriented at a coarser sampling.
  std::function<bool(const Splat&, float normal[3])> sideReference;
  ProgressFn progress;  // (points done, 2 * points): neighbour search, then orientation
};

// Afterwards hasNormals and hasRadii are true.
void estimateNormalsAndRadii(PointCloud& cloud, const NormalOptions& options);

// Radii without a global neighbour search, for clouds that have normals but
// no radii: the same r = d_k sqrt(3 / k) rule as above, measured at
// kLeafRadiusSamples points spread through each octree leaf, with the k
// nearest searched among the leaf's own points (a leaf holds at most
// leafPoints), and the median given to every point of the leaf: about 0.02 of
// the cost of a kd-tree search for every point. It follows the sampling
// per leaf, not per point; near a leaf's faces the k-th neighbour inside the
// leaf is somewhat farther than the true one, so radii err on the large side.
// A leaf with at most k points takes the mean of its measured sibling leaves,
// else its parent's density (r = sqrt(3 area / (pi n)), the area from the two
// largest covariance eigenvalues). Only missing radii (<= 0) are written.
inline constexpr std::size_t kLeafRadiusSamples = 5;
void estimateRadiiInLeaves(Octree& tree, int neighbours = 12, unsigned threads = 0,
                           const ProgressFn& progress = {});

}  // namespace pointillist::preprocess
