#pragma once
// Seed 003 §4.1.2: level-splats. A cell of level n gets splats that cluster its
// level n-1 splats -- a leaf clusters its points, an inner cell the level-
// splats of its children -- by covariance analysis (Pauly et al. 2002):
//   1. hierarchical split: the cluster with the largest spread (total
//      variance) is cut by the plane through its centroid normal to its
//      largest covariance eigenvector, until the target count is reached;
//   2. refinement: every input is reassigned to the cluster Gaussian with the
//      smallest Mahalanobis distance (plus log-determinant, i.e. the most
//      likely one), every cluster of the cell tried (SIMD over the inputs,
//      preprocess/likeliest_gaussian); covariances are regularized by half the
//      mean input radius so flat clusters stay thin but finite.
// Each output splat: centroid position; normal = smallest covariance
// eigenvector oriented like the mean input normal (the mean normal itself when
// the cluster is not flat, e.g. two inputs or a line); mean colour; radius =
// max over its inputs of max(distance + radiusShare * radius, radius), rounded
// up in float from the stored (float) centre. With the default
// share 1 the level-splat's sphere contains the sphere of every splat it
// replaces, so a level covers whatever the level below covered (no holes at
// coarse LOD); radii grow about 1.5-2x a level as counts fall 4x.
#include <cstddef>
#include <cstdint>
#include <functional>
#include <span>
#include <vector>

#include "common/splat.hpp"
#include "preprocess/octree_builder.hpp"
#include "preprocess/point_cloud.hpp"

namespace pointillist::preprocess {

struct LevelSplatOptions {
  // Inputs per level-splat: each level has about 1/4 of the splats of the one
  // below, i.e. about one level-splat per (2x coarser) pixel footprint on a
  // surface, and a cell's count stays roughly constant going up the tree.
  double reduction = 4.0;
  std::uint32_t maxPerCell = 256;  // cap for dense (volumetric) cells
  double radiusShare = 1.0;        // see above; below 1 gives sharper but possibly holey levels
  int refineIterations = 1;
};

// ceil(inputs / reduction), at least 1 and at most maxPerCell (and inputs).
std::size_t levelSplatTarget(std::size_t inputs, const LevelSplatOptions& options);

struct Clustering {
  std::vector<Splat> splats;
  std::vector<std::uint32_t> assignment;  // input i is replaced by splats[assignment[i]]
};

// Clusters `input` into at most `target` splats (fewer only when clusters
// cannot be split: identical positions). Deterministic.
Clustering clusterSplats(std::span<const Splat> input, std::size_t target,
                         const LevelSplatOptions& options);

struct LevelSplats {
  // Grouped by top-level cell (table order), each group laid out as its packet
  // is (common/dataset.hpp): coarse first, its cells' splats by level from the
  // highest down, cells of one level in depth-first order, each cell's splats
  // contiguous. Empty when LevelSplatHooks::keepSplats is false.
  std::vector<Splat> splats;
  std::vector<std::uint64_t> cellBegin;      // per cell; for cells above the top-level depth:
                                             // where their subtree's level-splats begin
  std::vector<std::uint32_t> cellCount;      // per cell; 0 above the top-level depth
  std::vector<std::uint64_t> topLevelBegin;  // per top-level cell, plus one final entry
};

// Top-level cell k's level-splats, laid out as in LevelSplats, once they are
// made; cellBegin and cellCount per cell of its subtree (cell index - the
// top-level cell's), cellBegin into levelSplats.
struct MadePacket {
  std::size_t k = 0;
  std::span<const Splat> levelSplats;
  std::span<const std::uint32_t> cellBegin;
  std::span<const std::uint32_t> cellCount;
};

// What the caller does with each packet as it is made. An exception from
// either stops the workers and is rethrown.
struct LevelSplatHooks {
  // On the worker that made it, packets in any order (a packet's cells are
  // described while its splats are in the cache).
  std::function<void(const MadePacket&)> made;
  // In order of k, on the thread that called buildLevelSplats, while the
  // workers go on (a dataset's packets are written meanwhile).
  std::function<void(const MadePacket&)> handOn;
  // false: splats are dropped once handed on and the result's stay empty
  // (its tables are filled all the same).
  bool keepSplats = true;
};

// Needs assignTopLevelCells first. Runs top-level cells in parallel on
// `threads` threads (0: all cores). progress(points done, points total).
// An exception from progress stops the workers and is rethrown.
LevelSplats buildLevelSplats(const Octree& tree, const LevelSplatOptions& options,
                             const ProgressFn& progress = {}, unsigned threads = 0,
                             const LevelSplatHooks& hooks = {});

}  // namespace pointillist::preprocess
