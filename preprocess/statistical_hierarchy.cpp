#include "preprocess/statistical_hierarchy.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <nanoflann.hpp>
#include <numbers>
#include <numeric>
#include <optional>
#include <random>
#include <string>

#include "common/errors.hpp"
#include "common/statistical_node.hpp"
#include "preprocess/parallel.hpp"

namespace pointillist::preprocess {

namespace {

// ---- PCA ------------------------------------------------------------------

struct Pca3 {
  Vec3d mean{};
  std::array<Vec3d, 3> axes{};  // descending spread, unit, right-handed
  Vec3d sigma{};                // descending
};

const std::array<Vec3d, 3> kIdentity{Vec3d{1, 0, 0}, Vec3d{0, 1, 0}, Vec3d{0, 0, 1}};

// A unit vector perpendicular to unit `a` (the two of Duff et al. 2017's
// branchless basis): (a, b, a x b) is right-handed.
Vec3d perpendicular(const Vec3d& a) {
  const double sign = std::copysign(1.0, a[2]);
  const double p = -1.0 / (sign + a[2]);
  const double q = a[0] * a[1] * p;
  return {1.0 + sign * a[0] * a[0] * p, sign * q, -sign * a[0]};
}

// Axes from eigenSymmetric3's vectors (ascending values): re-orthonormalized
// (Jacobi's rounding), largest first, the third their cross product.
std::array<Vec3d, 3> descendingAxes(const Eigen3& e) {
  Vec3d a0 = normalized(e.vectors[2]);
  if (length(a0) == 0.0) return kIdentity;
  Vec3d a1 = normalized(sub(e.vectors[1], scale(a0, dot(e.vectors[1], a0))));
  if (length(a1) == 0.0) a1 = perpendicular(a0);
  return {a0, a1, normalized(cross(a0, a1))};
}

Pca3 pcaOf(const Vec3d& mean, const Sym3& covariance) {
  const Eigen3 e = eigenSymmetric3(covariance);
  Pca3 p;
  p.mean = mean;
  p.axes = descendingAxes(e);
  for (std::size_t k = 0; k < 3; ++k) p.sigma[k] = std::sqrt(std::max(0.0, e.values[2 - k]));
  return p;
}

Pca3 pcaOf(const CovarianceAccumulator& acc) {
  return pcaOf(acc.mean(), acc.covariance());
}

Vec3d positionOf(const Splat& s) {
  return {s.position[0], s.position[1], s.position[2]};
}

// ---- the 2-means split ----------------------------------------------------

// A centre with the metric of its distances: |rows (q - centre)|^2, rows the
// frame scaled by 1 / sigma (Mahalanobis) or the identity (Euclidean).
struct Centre {
  Vec3d at{};
  std::array<Vec3d, 3> rows = kIdentity;

  double distance2(const Vec3d& q) const {
    const Vec3d d = sub(q, at);
    const double a = dot(rows[0], d), b = dot(rows[1], d), c = dot(rows[2], d);
    return a * a + b * b + c * c;
  }
  void setMetric(const Pca3& pca, double sigmaFloor) {
    for (std::size_t k = 0; k < 3; ++k)
      rows[k] = scale(pca.axes[k], 1.0 / std::max(pca.sigma[k], sigmaFloor));
  }
};

// twoMeansSplit on a node whose PCA is known; labels[i] gets point i's side.
// False (labels unspecified) when a side ran empty.
bool splitTwoMeans(std::span<const Vec3d> positions, const Pca3& node, SplitMetric metric,
                   const StatisticalOptions& options, std::span<std::uint8_t> labels) {
  const bool mahalanobis = metric == SplitMetric::Mahalanobis;
  // The paper's S_p divides by sigma: floored so flat or collinear clusters
  // (sigma_3 = 0) weigh their normal direction heavily but finitely.
  const double sigmaFloor = double{kSigmaFloor} * node.sigma[0];
  std::array<Centre, 2> centres;
  centres[0].at = add(node.mean, scale(node.axes[0], node.sigma[0]));
  centres[1].at = sub(node.mean, scale(node.axes[0], node.sigma[0]));
  if (mahalanobis)
    for (Centre& c : centres) c.setMetric(node, sigmaFloor);
  double previous = std::numeric_limits<double>::infinity();
  for (std::uint32_t iteration = 0; iteration < options.maxIterations; ++iteration) {
    std::array<CovarianceAccumulator, 2> sides;
    double distortion = 0.0;
    bool changed = false;
    for (std::size_t i = 0; i < positions.size(); ++i) {
      const Vec3d& q = positions[i];
      const double d0 = centres[0].distance2(q), d1 = centres[1].distance2(q);
      const std::uint8_t side = d1 < d0 ? 1 : 0;
      changed |= side != labels[i];
      labels[i] = side;
      sides[side].add(q);
      distortion += side ? d1 : d0;
    }
    if (sides[0].count() == 0 || sides[1].count() == 0) return false;
    for (std::size_t s = 0; s < 2; ++s) {
      if (mahalanobis) {
        const Pca3 pca = pcaOf(sides[s]);
        centres[s].at = pca.mean;
        centres[s].setMetric(pca, sigmaFloor);
      } else {
        centres[s].at = sides[s].mean();
      }
    }
    if (iteration > 0 &&
        (!changed || std::abs(previous - distortion) <= options.distortionTolerance * previous))
      break;
    previous = distortion;
  }
  return true;
}

// The fallback that always terminates: the lower half along f1 (ties by
// index) against the upper half.
void splitAtMedian(std::span<const Vec3d> positions, const Pca3& node,
                   std::span<std::uint8_t> labels) {
  const std::size_t n = positions.size();
  std::vector<std::pair<double, std::uint32_t>> keyed(n);
  for (std::size_t i = 0; i < n; ++i)
    keyed[i] = {dot(sub(positions[i], node.mean), node.axes[0]), static_cast<std::uint32_t>(i)};
  const auto middle = keyed.begin() + static_cast<std::ptrdiff_t>(n / 2);
  std::nth_element(keyed.begin(), middle, keyed.end());
  // Upper half to side 0, the side of the seed at mean + sigma_1 f_1.
  for (auto it = keyed.begin(); it != middle; ++it) labels[it->second] = 1;
  for (auto it = middle; it != keyed.end(); ++it) labels[it->second] = 0;
}

void validate(const StatisticalOptions& o) {
  const auto fail = [](const std::string& what) {
    throw UsageError("statistical hierarchy: " + what);
  };
  if (o.leafPoints < 1) fail("leafPoints must be at least 1");
  if (!(o.minSigmaShare >= 0.0) || !std::isfinite(o.minSigmaShare))
    fail("minSigmaShare must be finite and not negative");
  if (!(o.distortionTolerance >= 0.0) || !std::isfinite(o.distortionTolerance))
    fail("distortionTolerance must be finite and not negative");
  if (o.maxIterations < 1) fail("maxIterations must be at least 1");
  if (!(o.balanceShare >= 0.0 && o.balanceShare <= 0.5)) fail("balanceShare must be in [0, 0.5]");
  if (!(o.eta0 >= 0.0 && o.eta0 <= 1.0)) fail("eta0 must be in [0, 1]");
  if (!(o.eta1 >= 0.0) || !std::isfinite(o.eta1)) fail("eta1 must be finite and not negative");
}

// ---- per-node attributes --------------------------------------------------

// Seed 004 §3: the normals rotated so their mean is z, unwrapped onto the
// tangent plane at the pole by elevation theta and azimuth phi to
// theta (cos phi, sin phi) -- the paper's (theta sin phi, theta cos phi) with
// the tangent axes named the other way round, and exactly the inverse of the
// decoding in common/statistical_node.hpp -- then a 2x2 PCA. The second
// moments are taken about the pole, not about the unwrapped points' mean,
// since generation centres the Gaussian on the mean normal. False when no
// point has a normal or they cancel out.
bool normalPca(std::span<const Splat> splats, std::span<const std::uint32_t> order, PcaNode& node) {
  Vec3d sum{};
  std::size_t count = 0;
  for (const std::uint32_t i : order) {
    const Splat& s = splats[i];
    if (!hasNormal(s)) continue;
    sum = add(sum, normalized({s.normal[0], s.normal[1], s.normal[2]}));
    ++count;
  }
  const Vec3d mean = normalized(sum);
  if (count == 0 || length(mean) == 0.0) {
    node.normalFrame = kIdentity;
    node.sigmaNormal = {std::numbers::pi, std::numbers::pi};
    return false;
  }
  const Vec3d e1 = perpendicular(mean);
  const Vec3d e2 = cross(mean, e1);
  double xx = 0.0, xy = 0.0, yy = 0.0;
  for (const std::uint32_t i : order) {
    const Splat& s = splats[i];
    if (!hasNormal(s)) continue;
    const Vec3d n = normalized({s.normal[0], s.normal[1], s.normal[2]});
    const double x = dot(n, e1), y = dot(n, e2), z = dot(n, mean);
    const double rho = std::sqrt(x * x + y * y);
    if (rho == 0.0) continue;  // at the pole (or its antipode: direction unknown)
    const double f = std::atan2(rho, z) / rho;
    xx += f * x * f * x;
    xy += f * x * f * y;
    yy += f * y * f * y;
  }
  const double inv = 1.0 / static_cast<double>(count);
  // The third row set to -1 keeps the plane's two eigenvectors at [1] and [2].
  const Eigen3 e = eigenSymmetric3(Sym3{xx * inv, xy * inv, 0.0, yy * inv, 0.0, -1.0});
  Vec3d major = normalized(add(scale(e1, e.vectors[2][0]), scale(e2, e.vectors[2][1])));
  if (length(major) == 0.0) major = e1;
  node.normalFrame = {major, cross(mean, major), mean};
  node.sigmaNormal = {std::sqrt(std::max(0.0, e.values[2])), std::sqrt(std::max(0.0, e.values[1]))};
  return true;
}

void colorPca(std::span<const Splat> splats, std::span<const std::uint32_t> order, PcaNode& node) {
  CovarianceAccumulator acc;
  for (const std::uint32_t i : order) {
    const Splat& s = splats[i];
    acc.add({static_cast<double>(s.color[0]), static_cast<double>(s.color[1]),
             static_cast<double>(s.color[2])});
  }
  const Pca3 pca = pcaOf(acc);
  node.color = pca.mean;
  node.colorAxes = pca.axes;
  node.sigmaColor = pca.sigma;
}

// Seed 004 §3's curvature correction. The paper (its formula garbled in our
// copy) scales sigma_p by beta = eta0 + (1 - eta0) max(0, 1 - eta1 sqrt(c)),
// c its curvature estimate sigma_n / sigma_p, and says the square root gave
// better pictures. Measured in units of the node's own size sigma_p, that
// curvature is the dimensionless sigma_n: the angle (radians) the normals
// turn over the node. So c = sigmaNormal[0], which makes beta scale-free: a
// flat node keeps beta = 1, one whose normals spread by a radian or more is cut
// to eta0 of its width. Only the tangential spreads sigma[0..1] shrink, never
// below sigma[2], so sigma stays descending and the axes keep their order.
void correctCurvature(const StatisticalOptions& options, bool haveNormals, PcaNode& node) {
  node.sigma = node.rawSigma;
  if (!haveNormals) return;
  const double beta =
      options.eta0 +
      (1.0 - options.eta0) * std::max(0.0, 1.0 - options.eta1 * std::sqrt(node.sigmaNormal[0]));
  for (std::size_t k = 0; k < 2; ++k)
    node.sigma[k] = std::max(beta * node.rawSigma[k], node.rawSigma[2]);
}

}  // namespace

std::vector<std::uint8_t> twoMeansSplit(std::span<const Vec3d> positions, SplitMetric metric,
                                        const StatisticalOptions& options) {
  validate(options);
  std::vector<std::uint8_t> labels(positions.size(), 0);
  if (positions.size() < 2) return labels;
  CovarianceAccumulator acc;
  for (const Vec3d& p : positions) acc.add(p);
  const Pca3 node = pcaOf(acc);
  if (node.sigma[0] == 0.0) return labels;
  if (!splitTwoMeans(positions, node, metric, options, labels))
    std::fill(labels.begin(), labels.end(), std::uint8_t{0});
  return labels;
}

PcaTree buildPcaTree(std::span<const Splat> points, const StatisticalOptions& options) {
  validate(options);
  PcaTree tree;
  if (points.empty()) return tree;
  if (points.size() > std::numeric_limits<std::uint32_t>::max())
    throw UsageError("statistical hierarchy: more than 2^32 - 1 points in a cell");
  const std::size_t n = points.size();

  // Positions and their indices, permuted together so every node's points are
  // one contiguous range; splits partition a node's range in place.
  std::vector<Vec3d> positions(n);
  tree.order.resize(n);
  Vec3d lo = positionOf(points[0]), hi = lo;
  for (std::size_t i = 0; i < n; ++i) {
    positions[i] = positionOf(points[i]);
    tree.order[i] = static_cast<std::uint32_t>(i);
    for (std::size_t a = 0; a < 3; ++a) {
      lo[a] = std::min(lo[a], positions[i][a]);
      hi[a] = std::max(hi[a], positions[i][a]);
    }
  }
  const double extent = std::max({hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]});
  const double minSigma = options.minSigmaShare * extent;
  // Below this the points coincide but for rounding of the covariance sums.
  const double coincident = 1e-12 * extent;
  std::vector<std::uint8_t> labels(n, 0);
  std::vector<Vec3d> scratchPositions(n);
  std::vector<std::uint32_t> scratchOrder(n);

  PcaNode root;
  root.pointCount = static_cast<std::uint32_t>(n);
  tree.nodes.push_back(root);

  // Level by level: the nodes of a level are analysed and split in parallel
  // (disjoint point ranges), then their children are appended in order, which
  // is the breadth-first layout with the j-th split node's children at 2j + 1.
  std::vector<std::uint32_t> leftCount;  // per node of the level; 0: a leaf
  for (std::size_t begin = 0, end = 1; begin < end; begin = end, end = tree.nodes.size()) {
    leftCount.assign(end - begin, 0);
    parallelFor(
        end - begin, options.threads,
        [&](std::size_t k) {
          PcaNode& node = tree.nodes[begin + k];
          const std::size_t first = node.firstPoint, count = node.pointCount;
          const std::span<Vec3d> pos(positions.data() + first, count);
          const std::span<std::uint32_t> ord(tree.order.data() + first, count);
          CovarianceAccumulator acc;
          for (const Vec3d& p : pos) acc.add(p);
          const Pca3 pca = pcaOf(acc);
          node.mean = pca.mean;
          node.axes = pca.axes;
          node.rawSigma = pca.sigma;
          correctCurvature(options, normalPca(points, ord, node), node);
          colorPca(points, ord, node);

          if (count < options.leafPoints || pca.sigma[0] <= minSigma || pca.sigma[0] <= coincident)
            return;
          const std::span<std::uint8_t> lab(labels.data() + first, count);
          std::fill(lab.begin(), lab.end(), std::uint8_t{0});
          bool ok = splitTwoMeans(pos, pca, SplitMetric::Mahalanobis, options, lab);
          std::size_t left =
              ok ? static_cast<std::size_t>(std::count(lab.begin(), lab.end(), 0)) : 0;
          if (!ok || static_cast<double>(std::min(left, count - left)) <
                         options.balanceShare * static_cast<double>(count)) {
            node.euclideanSplit = true;
            std::fill(lab.begin(), lab.end(), std::uint8_t{0});
            ok = splitTwoMeans(pos, pca, SplitMetric::Euclidean, options, lab);
            left = ok ? static_cast<std::size_t>(std::count(lab.begin(), lab.end(), 0)) : 0;
            if (!ok || left == 0 || left == count) {
              splitAtMedian(pos, pca, lab);
              left = static_cast<std::size_t>(std::count(lab.begin(), lab.end(), 0));
            }
          }
          // Stable partition: side 0 first.
          std::size_t a = first, b = first + left;
          for (std::size_t i = 0; i < count; ++i) {
            std::size_t& to = lab[i] ? b : a;
            scratchPositions[to] = pos[i];
            scratchOrder[to] = ord[i];
            ++to;
          }
          std::copy_n(scratchPositions.begin() + static_cast<std::ptrdiff_t>(first), count,
                      pos.begin());
          std::copy_n(scratchOrder.begin() + static_cast<std::ptrdiff_t>(first), count,
                      ord.begin());
          leftCount[k] = static_cast<std::uint32_t>(left);
        },
        1);
    for (std::size_t k = 0; k < end - begin; ++k) {
      if (leftCount[k] == 0) continue;
      const auto parent = static_cast<std::uint32_t>(begin + k);
      PcaNode left, right;
      left.parent = right.parent = parent;
      left.firstPoint = tree.nodes[parent].firstPoint;
      left.pointCount = leftCount[k];
      right.firstPoint = left.firstPoint + left.pointCount;
      right.pointCount = tree.nodes[parent].pointCount - left.pointCount;
      tree.nodes[parent].firstChild = static_cast<std::uint32_t>(tree.nodes.size());
      tree.nodes.push_back(left);
      tree.nodes.push_back(right);
    }
  }
  return tree;
}

// ---- k-means classification -------------------------------------------------

namespace {

template <std::size_t D>
struct CentreCloud {
  const std::vector<std::array<float, D>>* centres;
  std::size_t kdtree_get_point_count() const { return centres->size(); }
  float kdtree_get_pt(std::uint32_t index, std::size_t dim) const { return (*centres)[index][dim]; }
  template <class Box>
  bool kdtree_get_bbox(Box&) const {
    return false;
  }
};

// nanoflann's squared distance, summed in the same order.
template <std::size_t D>
float distance2(const std::array<float, D>& a, const std::array<float, D>& b) {
  float result = 0.0f;
  for (std::size_t i = 0; i < D; ++i) {
    const float d = a[i] - b[i];
    result += d * d;
  }
  return result;
}

// A one-nearest result set that can start from a candidate: the kd-tree then
// prunes with its distance from the start.
struct NearestResult {
  using DistanceType = float;
  using IndexType = std::uint32_t;
  using CountType = std::size_t;
  std::uint32_t index = 0;
  float distance = std::numeric_limits<float>::max();

  std::size_t size() const { return 1; }
  bool full() const { return true; }
  bool addPoint(float d, std::uint32_t i) {
    if (d < distance || (d == distance && i < index)) {
      distance = d;
      index = i;
    }
    return true;
  }
  float worstDist() const { return distance; }
};

// Uniform in [0, 1) from 53 bits: the same on every standard library.
double uniform01(std::mt19937_64& rng) {
  return static_cast<double>(rng() >> 11) * 0x1.0p-53;
}

}  // namespace

template <std::size_t D>
struct NearestClass<D>::Index {
  using Cloud = CentreCloud<D>;
  using Tree = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<float, Cloud>,
                                                   Cloud, static_cast<int>(D), std::uint32_t>;
  std::vector<std::array<float, D>> centres;
  Cloud cloud{&centres};
  std::optional<Tree> tree;
};

template <std::size_t D>
NearestClass<D>::NearestClass(std::vector<std::array<float, D>> centres)
    : index_(std::make_unique<Index>()) {
  if (centres.empty()) throw UsageError("NearestClass: no centres");
  if (centres.size() > std::numeric_limits<std::uint32_t>::max())
    throw UsageError("NearestClass: too many centres");
  index_->centres = std::move(centres);
  index_->tree.emplace(static_cast<int>(D), index_->cloud,
                       nanoflann::KDTreeSingleIndexAdaptorParams(8));
}

template <std::size_t D>
NearestClass<D>::~NearestClass() = default;
template <std::size_t D>
NearestClass<D>::NearestClass(NearestClass&&) noexcept = default;

template <std::size_t D>
std::uint32_t NearestClass<D>::operator()(const std::array<float, D>& v) const {
  NearestResult result;
  index_->tree->findNeighbors(result, v.data(), nanoflann::SearchParams());
  return result.index;
}

template <std::size_t D>
std::uint32_t NearestClass<D>::nearest(const std::array<float, D>& v,
                                       std::uint32_t candidate) const {
  if (candidate >= index_->centres.size()) return (*this)(v);
  NearestResult result;
  result.index = candidate;
  result.distance = distance2(v, index_->centres[candidate]);
  index_->tree->findNeighbors(result, v.data(), nanoflann::SearchParams());
  return result.index;
}

template <std::size_t D>
const std::vector<std::array<float, D>>& NearestClass<D>::centres() const {
  return index_->centres;
}

template <std::size_t D>
std::vector<std::array<float, D>> kMeansClasses(std::span<const std::array<float, D>> vectors,
                                                std::uint32_t k, std::uint32_t sampleLimit,
                                                std::uint64_t seed, std::uint32_t iterations) {
  using Vec = std::array<float, D>;
  if (vectors.empty() || k == 0) return {};
  for (const Vec& v : vectors)
    for (const float c : v)
      if (!std::isfinite(c)) throw UsageError("kMeansClasses: a vector is not finite");
  std::mt19937_64 rng(seed);

  // The sample: a partial Fisher-Yates shuffle, then in input order.
  std::vector<Vec> sample;
  if (sampleLimit == 0 || vectors.size() <= sampleLimit) {
    sample.assign(vectors.begin(), vectors.end());
  } else {
    std::vector<std::uint32_t> pick(vectors.size());
    std::iota(pick.begin(), pick.end(), 0u);
    for (std::size_t i = 0; i < sampleLimit; ++i)
      std::swap(pick[i], pick[i + rng() % (pick.size() - i)]);
    pick.resize(sampleLimit);
    std::sort(pick.begin(), pick.end());
    sample.reserve(sampleLimit);
    for (const std::uint32_t i : pick) sample.push_back(vectors[i]);
  }
  const std::size_t m = sample.size();

  // k-means++ seeding: each next centre drawn with probability proportional to
  // the squared distance to the nearest centre so far. Stops early when every
  // sample vector is a centre already (fewer distinct vectors than k). The
  // vectors are kept in lists per nearest centre with the lists' largest
  // distance and sum: a new centre c cannot take a vector x from centre j when
  // |c - c_j| >= 2 |x - c_j| (triangle inequality), so whole lists far from c
  // are skipped -- exact k-means++, without touching every vector per centre.
  std::vector<Vec> centres;
  centres.reserve(k);
  std::vector<float> nearest2(m);
  std::vector<std::uint32_t> assign(m, 0);
  std::vector<std::vector<std::uint32_t>> members(1);
  std::vector<double> memberSum(1, 0.0);
  std::vector<float> memberRadius2(1, 0.0f);
  centres.push_back(sample[rng() % m]);
  members[0].resize(m);
  std::iota(members[0].begin(), members[0].end(), 0u);
  for (std::size_t i = 0; i < m; ++i) {
    nearest2[i] = distance2(sample[i], centres[0]);
    memberSum[0] += double{nearest2[i]};
    memberRadius2[0] = std::max(memberRadius2[0], nearest2[i]);
  }
  while (centres.size() < k) {
    double total = 0.0;
    for (const double sum : memberSum) total += sum;
    if (!(total > 0.0)) break;
    // The draw: the list, then the vector within it.
    const double target = uniform01(rng) * total;
    double running = 0.0;
    std::size_t drawn = 0;
    for (std::size_t j = 0; j < memberSum.size(); ++j) {
      if (memberSum[j] == 0.0) continue;
      drawn = j;
      if (running + memberSum[j] > target) break;
      running += memberSum[j];
    }
    std::uint32_t pick = members[drawn].front();
    for (const std::uint32_t i : members[drawn]) {
      if (nearest2[i] == 0.0f) continue;
      pick = i;
      running += double{nearest2[i]};
      if (running > target) break;
    }
    const Vec c = sample[pick];
    const auto ci = static_cast<std::uint32_t>(centres.size());
    centres.push_back(c);
    std::vector<std::uint32_t> taken;
    double takenSum = 0.0;
    float takenRadius2 = 0.0f;
    for (std::size_t j = 0; j < ci; ++j) {
      if (distance2(c, centres[j]) >= 4.0f * memberRadius2[j]) continue;
      std::vector<std::uint32_t>& list = members[j];
      std::size_t kept = 0;
      double sum = 0.0;
      float radius2 = 0.0f;
      for (const std::uint32_t i : list) {
        const float d = distance2(sample[i], c);
        if (d < nearest2[i]) {
          nearest2[i] = d;
          assign[i] = ci;
          taken.push_back(i);
          takenSum += double{d};
          takenRadius2 = std::max(takenRadius2, d);
        } else {
          list[kept++] = i;
          sum += double{nearest2[i]};
          radius2 = std::max(radius2, nearest2[i]);
        }
      }
      list.resize(kept);
      memberSum[j] = sum;
      memberRadius2[j] = radius2;
    }
    members.push_back(std::move(taken));
    memberSum.push_back(takenSum);
    memberRadius2.push_back(takenRadius2);
  }
  members.clear();

  // Lloyd iterations: assignment by the kd-tree over the centres (each point
  // starting from its previous centre), then means. An emptied centre moves to
  // the sample vector farthest from its own centre.
  std::vector<std::array<double, D>> sums;
  std::vector<std::uint32_t> counts;
  for (std::uint32_t iteration = 0; iteration < iterations; ++iteration) {
    bool changed = false;
    if (iteration > 0) {
      const NearestClass<D> nearest(centres);
      for (std::size_t i = 0; i < m; ++i) {
        const std::uint32_t c = nearest.nearest(sample[i], assign[i]);
        changed |= c != assign[i];
        assign[i] = c;
      }
    }
    sums.assign(centres.size(), std::array<double, D>{});
    counts.assign(centres.size(), 0);
    for (std::size_t i = 0; i < m; ++i) {
      for (std::size_t d = 0; d < D; ++d) sums[assign[i]][d] += double{sample[i][d]};
      ++counts[assign[i]];
    }
    std::vector<std::uint32_t> empty;
    for (std::size_t c = 0; c < centres.size(); ++c) {
      if (counts[c] == 0) {
        empty.push_back(static_cast<std::uint32_t>(c));
        continue;
      }
      for (std::size_t d = 0; d < D; ++d)
        centres[c][d] = static_cast<float>(sums[c][d] / counts[c]);
    }
    if (!empty.empty()) {
      std::vector<std::pair<float, std::uint32_t>> far(m);
      for (std::size_t i = 0; i < m; ++i)
        far[i] = {-distance2(sample[i], centres[assign[i]]), static_cast<std::uint32_t>(i)};
      const std::size_t take = std::min(empty.size(), m);
      std::partial_sort(far.begin(), far.begin() + static_cast<std::ptrdiff_t>(take), far.end());
      std::vector<bool> drop(centres.size(), false);
      for (std::size_t e = 0; e < empty.size(); ++e) {
        if (e < take && far[e].first < 0.0f) {
          centres[empty[e]] = sample[far[e].second];
          assign[far[e].second] = empty[e];
        } else {
          drop[empty[e]] = true;  // every vector sits on a centre: fewer classes
        }
      }
      if (std::find(drop.begin(), drop.end(), true) != drop.end()) {
        std::vector<std::uint32_t> renumber(centres.size());
        std::vector<Vec> kept;
        for (std::size_t c = 0; c < centres.size(); ++c) {
          renumber[c] = static_cast<std::uint32_t>(kept.size());
          if (!drop[c]) kept.push_back(centres[c]);
        }
        centres = std::move(kept);
        for (std::uint32_t& a : assign) a = renumber[a];  // never a dropped (empty) one
      }
      changed = true;
    }
    if (iteration > 0 && !changed) break;
  }
  return centres;
}

template std::vector<std::array<float, 2>> kMeansClasses<2>(std::span<const std::array<float, 2>>,
                                                            std::uint32_t, std::uint32_t,
                                                            std::uint64_t, std::uint32_t);
template std::vector<std::array<float, 3>> kMeansClasses<3>(std::span<const std::array<float, 3>>,
                                                            std::uint32_t, std::uint32_t,
                                                            std::uint64_t, std::uint32_t);
template class NearestClass<2>;
template class NearestClass<3>;

}  // namespace pointillist::preprocess
