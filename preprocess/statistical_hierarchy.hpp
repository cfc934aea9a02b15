#pragma once
// Seed 004 §3-§5 on the preprocess side: the hierarchical PCA of one top-level
// cell's points (2-means splits seeded along the first principal axis,
// Mahalanobis distance first and Euclidean when that split is unbalanced),
// per node the PCA of position, of normals unwrapped onto the tangent plane of
// their mean, and of colour, with the curvature correction of §3; and the
// k-means classification of the standard deviations into global tables.
// Free of MPI and GL; common/statistical_node.hpp is the stored form.
#include <array>
#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "common/geometry.hpp"
#include "common/splat.hpp"

namespace pointillist::preprocess {

struct StatisticalOptions {
  // Stop splitting at nodes with fewer points than this (seed 004 §4: 6-30).
  std::uint32_t leafPoints = 8;
  // ... or whose largest standard deviation is below this share of the cell's
  // largest extent (the paper's variance threshold; 0: split down to leafPoints).
  double minSigmaShare = 0.0;
  // 2-means stops when the distortion changes by less than this (relative) or
  // after maxIterations (seed 004 §4: 1e-7 and 30).
  double distortionTolerance = 1e-7;
  std::uint32_t maxIterations = 30;
  // A Mahalanobis split whose smaller side holds less than this share of the
  // points is redone with the Euclidean metric (seed 004 §4: 30 % - 70 %).
  double balanceShare = 0.3;
  // Curvature correction of sigma_1 and sigma_2 (seed 004 §3):
  // beta = eta0 + (1 - eta0) * max(0, 1 - eta1 * sqrt(sigmaNormal_1)).
  double eta0 = 0.5;
  double eta1 = 1.0;
  // Classes of the global tables (seed 004 §5: 64 to 4K per model).
  std::uint32_t positionClasses = 4096;
  std::uint32_t normalClasses = 4096;
  std::uint32_t colorClasses = 64;
  unsigned threads = 0;  // 0: all cores
};

// One node of a cell's hierarchy, unquantized.
struct PcaNode {
  Vec3d mean{};
  std::array<Vec3d, 3> axes{};  // unit, right-handed, axes[2] the smallest spread
  Vec3d sigma{};                // descending; sigma[0..1] curvature-corrected
  Vec3d rawSigma{};             // before the curvature correction
  std::array<Vec3d, 3> normalFrame{};  // [2] = mean normal; [0] major axis of the unwrapped normals
  std::array<double, 2> sigmaNormal{};  // radians, descending
  Vec3d color{};                        // mean RGB 0..255
  std::array<Vec3d, 3> colorAxes{};
  Vec3d sigmaColor{};                   // descending
  std::uint32_t firstPoint = 0;  // the node's points: [firstPoint, firstPoint + pointCount)
  std::uint32_t pointCount = 0;  //   of PcaTree::order
  std::uint32_t firstChild = 0;  // 0: leaf; else the left child (right = firstChild + 1)
  std::uint32_t parent = 0;
  bool euclideanSplit = false;  // its children came from the Euclidean fallback
};

// Breadth-first: node 0 is the root, children follow their parent's level and
// the children of the j-th node with children are 2j + 1 and 2j + 2.
struct PcaTree {
  std::vector<PcaNode> nodes;
  // Indices into the points given to buildPcaTree: every node's points are a
  // contiguous range of it.
  std::vector<std::uint32_t> order;
};

// Points without a normal ((0,0,0)) are left out of the normal PCA (a node
// with none gets normalFrame = identity, sigmaNormal = pi). Throws UsageError
// for invalid options.
PcaTree buildPcaTree(std::span<const Splat> points, const StatisticalOptions& options);

// Seed 004 §5: k-means (k-means++ seeding, Lloyd iterations on at most
// `sampleLimit` vectors drawn at random with `seed`) of D-dimensional vectors,
// in the space the caller chose (the encoder classifies log standard
// deviations). Returns at most k centres (fewer when there are fewer distinct
// vectors); deterministic for a given input, k and seed.
template <std::size_t D>
std::vector<std::array<float, D>> kMeansClasses(std::span<const std::array<float, D>> vectors,
                                                std::uint32_t k, std::uint32_t sampleLimit = 262144,
                                                std::uint64_t seed = 1,
                                                std::uint32_t iterations = 20);
// The index of the nearest centre (squared Euclidean), for many queries: a
// kd-tree over the centres.
template <std::size_t D>
class NearestClass {
 public:
  explicit NearestClass(std::vector<std::array<float, D>> centres);
  ~NearestClass();
  NearestClass(NearestClass&&) noexcept;
  std::uint32_t operator()(const std::array<float, D>& v) const;
  const std::vector<std::array<float, D>>& centres() const;

 private:
  struct Index;
  std::unique_ptr<Index> index_;
};

}  // namespace pointillist::preprocess
