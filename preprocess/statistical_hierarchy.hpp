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
  std::array<Vec3d, 3> axes{};         // unit, right-handed, axes[2] the smallest spread
  Vec3d sigma{};                       // descending; sigma[0..1] curvature-corrected
  Vec3d rawSigma{};                    // before the curvature correction
  std::array<Vec3d, 3> normalFrame{};  // [2] = mean normal; [0] major axis of the unwrapped normals
  std::array<double, 2> sigmaNormal{};  // radians, descending
  Vec3d color{};                        // mean RGB 0..255
  std::array<Vec3d, 3> colorAxes{};
  Vec3d sigmaColor{};            // descending
  std::uint32_t firstPoint = 0;  // the node's points: [firstPoint, firstPoint + pointCount)
  std::uint32_t pointCount = 0;  //   of PcaTree::order
  std::uint32_t firstChild = 0;  // 0: leaf; else the left child (right = firstChild + 1)
  std::uint32_t parent = 0;
  // Its Mahalanobis split was rejected (unbalanced or degenerate): the children
  // came from the Euclidean fallback, or the median along f1 if that ran empty.
  bool euclideanSplit = false;
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
// with none gets normalFrame = identity, sigmaNormal = pi, and no curvature
// correction). Throws UsageError for invalid options; no points: no nodes.
//
// A node is a leaf when it has fewer than leafPoints points, when its largest
// raw sigma is at most minSigmaShare times the largest extent of all the
// points' box, or when its points coincide; every other node is split in two
// (never into an empty side), so leaves of a tree built with minSigmaShare = 0
// from distinct points hold fewer than leafPoints points. The split: 2-means
// with the Mahalanobis metric (twoMeansSplit); when its smaller side holds less
// than balanceShare of the points, 2-means with the Euclidean metric from the
// same seeds (euclideanSplit is then set on the parent); when a side comes out
// empty, the median along f1. The left child is the side of the seed at
// mean + sigma_1 f_1.
PcaTree buildPcaTree(std::span<const Splat> points, const StatisticalOptions& options);

// One 2-means split of a node's positions as buildPcaTree starts it (seed 004
// §4), without the balance check: seeds at mean +- sigma_1 f_1 of the points'
// PCA. Euclidean: Lloyd iterations. Mahalanobis: each point goes to the centre
// nearer in m(q) = ||S T (q - centre)|| under that cluster's own current PCA
// (T its frame, S = diag(1 / sigma_k) with sigma_k floored at kSigmaFloor times
// the node's sigma_1); the first assignment, before the clusters exist, uses the
// node's PCA for both and so is the plane through the mean normal to f_1.
// Stops when the distortion (the sum of the squared distances) changes by less
// than distortionTolerance relatively, when no point changes side, or after
// maxIterations. Returns each point's side, 0 (the seed at mean + sigma_1 f_1)
// or 1; all 0 when fewer than two points, coincident points, or a side ran
// empty. Exposed for tests and tools; buildPcaTree calls the same code.
// The Mahalanobis metric keeps apart a flat part and a part off its plane (a
// sphere on a plane, a sheet above a larger one or overlapping it in part:
// seed 004 figure 7) where the Euclidean one cuts across both; two sheets
// stacked exactly stay mirror images under either metric and are not parted.
enum class SplitMetric { Mahalanobis, Euclidean };
std::vector<std::uint8_t> twoMeansSplit(std::span<const Vec3d> positions, SplitMetric metric,
                                        const StatisticalOptions& options);

// Seed 004 §5: k-means (k-means++ seeding, Lloyd iterations on at most
// `sampleLimit` vectors (0: all) drawn at random with `seed`) of D-dimensional vectors,
// in the space the caller chose (the encoder classifies log standard
// deviations). Returns at most k centres (fewer when there are fewer distinct
// vectors); deterministic for a given input, k and seed. A centre left without
// vectors moves to the vector farthest from its centre. Throws UsageError for
// non-finite vectors.
template <std::size_t D>
std::vector<std::array<float, D>> kMeansClasses(std::span<const std::array<float, D>> vectors,
                                                std::uint32_t k, std::uint32_t sampleLimit = 262144,
                                                std::uint64_t seed = 1,
                                                std::uint32_t iterations = 20);
// The index of the nearest centre (squared Euclidean, in float; among
// equidistant centres one chosen deterministically), for many queries: a
// kd-tree over the centres. Throws UsageError for no centres.
template <std::size_t D>
class NearestClass {
 public:
  explicit NearestClass(std::vector<std::array<float, D>> centres);
  ~NearestClass();
  NearestClass(NearestClass&&) noexcept;
  std::uint32_t operator()(const std::array<float, D>& v) const;
  // The same, starting from a candidate (a centre near v, e.g. its previous
  // one): faster when the candidate is close. Equidistant centres may resolve
  // differently from operator(); a candidate out of range is ignored.
  std::uint32_t nearest(const std::array<float, D>& v, std::uint32_t candidate) const;
  const std::vector<std::array<float, D>>& centres() const;

 private:
  struct Index;
  std::unique_ptr<Index> index_;
};

}  // namespace pointillist::preprocess
