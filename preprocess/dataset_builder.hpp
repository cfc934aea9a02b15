#pragma once
// Seed 003 §4.1.1, step two: turns the octree and its level-splats into the
// compact dataset records -- the 64-byte octree-cell-array, the top-level table
// and the point-array grouped per top-level cell -- ready for writeDataset.
#include <cstdint>
#include <functional>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "common/dataset.hpp"
#include "common/geometry.hpp"
#include "preprocess/instancing.hpp"
#include "preprocess/level_splats.hpp"
#include "preprocess/normals.hpp"
#include "preprocess/octree_builder.hpp"
#include "preprocess/statistical_encoding.hpp"

namespace pointillist::preprocess {

struct PreprocessOptions {
  OctreeOptions octree;
  LevelSplatOptions levelSplats;
  int topLevelDepth = -1;  // -1: chooseTopLevelDepth(targetPacketBytes)
  std::uint64_t targetPacketBytes = kDefaultPacketBytes;
  // Fill missing radii (<= 0) from neighbours within each octree leaf
  // (estimateRadiiInLeaves) once the tree is built.
  bool radiiInLeaves = false;
  int radiusNeighbours = 12;
  // Fill missing normals and radii from the radiusNeighbours nearest
  // neighbours (estimateNormalsAndRadii) once the points are in Morton order:
  // neighbours are then near in memory too.
  bool estimateNormals = false;
  // Points beside the cloud (out of core: of chunks built before, near this
  // one) with their final normals and radii: they count as neighbours and
  // their side carries over, as if the cloud went on; they are not written.
  std::span<const Splat> neighbourAnchors;
  // NormalOptions::sideReference.
  std::function<bool(const Splat&, float[3])> sideReference;
  NeighbourSearch neighbourSearch = NeighbourSearch::Grid;
  NormalMethod normalMethod = NormalMethod::Neighbours;
  // NormalMethod::Moments: the cubes; side 0: chosen from the points, inside
  // the octree's cube (out of core, every chunk is given the whole cloud's).
  CubeLattice cubeLattice;
  // The points an occupied cube holds on average, aimed at where the side
  // is chosen (--cube-points): coarser cubes are faster and blur more.
  double cubePoints = kMomentPointsPerCube;
  unsigned threads = 0;  // 0: all cores
  std::string source;    // recorded in the manifest
  // --instanced: every top-level cell's points also as vertex and
  // transformation streams (preprocess/instancing.hpp); statistics add up in
  // *instancingStats when it is set.
  std::optional<InstancingOptions> instancing;
  InstancingStats* instancingStats = nullptr;
  // --statistical: every top-level cell's points also as a hierarchy of PCA
  // nodes (seed 004, preprocess/statistical_encoding.hpp); its figures go to
  // *statisticalStats when it is set.
  std::optional<StatisticalOptions> statistical;
  StatisticalStats* statisticalStats = nullptr;
  // Each packet's bytes, in packet order, as soon as its level-splats are made
  // (on the thread that called buildDatasetContent, while the others go on):
  // DatasetWriter::appendPacket writes the dataset meanwhile. Not with
  // instancing or statistical, which add to packets afterwards.
  std::function<void(std::span<const Splat> levelSplats, std::span<const Splat> points)> packetSink;
};

// stage is "octree", "normals and radii", "radii", "level-splats" or "cells";
// (done, total) in points.
using StageProgressFn =
    std::function<void(const char* stage, std::uint64_t done, std::uint64_t total)>;

// A cell's normal sum (unit normals of its subtree's splats) and whether any
// normal is unknown: what the cone of a cell above it is made from.
struct CellNormals {
  Vec3d sum{};
  bool unknown = false;
};

// Normal cone of cell `index`, above the top-level depth, from its children's
// cones in `cells` (their points need not be in memory): the axis is its normal
// sum, the half angle the widest child cone seen from that axis. No cone when a
// child has none.
void mergeChildCones(std::span<OctreeCell> cells, std::size_t index, const CellNormals& normals);

// Builds everything writeDataset needs. Per cell: bounds are the tight bounds
// of all splat centres of its subtree (points and level-splats);
// maxSplatRadius the largest radius among them; the normal cone contains every
// normal among them (no cone when any normal is unknown, i.e. zero); cells
// above the top-level depth merge their children's cones (mergeChildCones).
// With a frame the points are one chunk of a larger cloud (buildOctree);
// `normals`, when given, receives every cell's CellNormals.
DatasetContent buildDatasetContent(std::vector<Splat> points, const PreprocessOptions& options,
                                   const StageProgressFn& progress = {},
                                   const OctreeFrame* frame = nullptr,
                                   std::vector<CellNormals>* normals = nullptr);

// The same from an already built octree with top-level cells and level-splats
// (tests use the pieces).
DatasetContent assembleDatasetContent(Octree tree, LevelSplats levelSplats,
                                      const PreprocessOptions& options,
                                      std::vector<CellNormals>* normals = nullptr);

}  // namespace pointillist::preprocess
