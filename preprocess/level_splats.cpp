#include "preprocess/level_splats.hpp"

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <exception>
#include <limits>
#include <mutex>
#include <numeric>
#include <thread>

#include "common/geometry.hpp"
#include "preprocess/eigen_batch.hpp"
#include "preprocess/likeliest_gaussian.hpp"
#include "preprocess/parallel.hpp"

namespace pointillist::preprocess {

namespace {

// Raw first and second moments: a split sums one side and takes the other
// as the parent's minus it. Positions are relative to the cell's first input,
// so the sums stay small and the subtraction loses nothing that matters.
struct Moments {
  double count = 0.0;
  Vec3d sum{};
  Sym3 square{};

  void add(const Vec3d& p) {
    count += 1.0;
    sum = pointillist::add(sum, p);
    addOuterProduct(square, p);
  }
  Vec3d mean() const { return scale(sum, 1.0 / count); }
  Sym3 covariance() const { return covarianceFromSums(count, sum, square); }
  Moments minus(const Moments& o) const {
    Moments r;
    r.count = count - o.count;
    r.sum = sub(sum, o.sum);
    for (std::size_t j = 0; j < 6; ++j) r.square[j] = square[j] - o.square[j];
    return r;
  }
};

struct Range {
  std::uint32_t begin;
  std::uint32_t end;
  double spread;  // total variance (covariance trace): the split priority
  Moments moments;
};

// The trace of m.covariance(), as covarianceFromSums computes its diagonal:
// only a range that is split needs the whole matrix and the mean, and about
// half of them never are.
double spreadOf(const Moments& m) {
  if (!(m.count > 0.0)) return 0.0;
  const double w = 1.0 / m.count;
  double trace = 0.0;
  for (const std::size_t a : {0u, 1u, 2u}) {
    const double mean = m.sum[a] * w;
    trace += std::max(m.square[a == 0 ? 0 : a == 1 ? 3 : 5] * w - mean * mean, 0.0);
  }
  return trace;
}

Range makeRange(std::uint32_t begin, std::uint32_t end, const Moments& m) {
  return {begin, end, end - begin >= 2 ? spreadOf(m) : 0.0, m};
}

// Inverse and log-determinant of (covariance + eps I) by the adjugate: no
// eigen-decomposition needed for the Mahalanobis distance.
GaussianRecord makeGaussian(const Moments& acc, double eps) {
  Sym3 c = acc.covariance();
  c[0] += eps;
  c[3] += eps;
  c[5] += eps;
  const double a00 = c[3] * c[5] - c[4] * c[4];
  const double a01 = c[2] * c[4] - c[1] * c[5];
  const double a02 = c[1] * c[4] - c[2] * c[3];
  const double det = c[0] * a00 + c[1] * a01 + c[2] * a02;
  // Positive definite by construction (PSD + eps I); guard against rounding.
  const double safeDet = std::max(det, eps * eps * eps);
  const double inv = 1.0 / safeDet;
  const Vec3d mean = acc.mean();
  return {{mean[0], mean[1], mean[2]},
          {a00 * inv, a01 * inv, a02 * inv, (c[0] * c[5] - c[2] * c[2]) * inv,
           (c[1] * c[2] - c[0] * c[4]) * inv, (c[0] * c[3] - c[1] * c[1]) * inv},
          std::log(safeDet)};
}

// What clusterSplats needs besides its output, kept per thread between calls.
struct ClusterScratch {
  std::vector<Vec3d> positions;
  std::vector<std::uint32_t> order, partitioned, active, activeBegin, done, remap;
  std::vector<double> activeSpread;
  std::vector<Range> ranges;
  std::vector<Moments> moments;
  std::vector<GaussianRecord> gaussians;
  std::vector<double> radii;
  std::vector<std::uint8_t> alive, anyNormal;
  std::vector<Vec3d> normalSums;
  std::vector<Sym3> covariances;
  std::vector<SmallestEigen3> planes;
  std::vector<std::array<double, 4>> colorSums;
};

// std::lround of v clamped to [0, 255], without its library call (a level-
// splat has four): v - floor(v) is exact there, so halves round up as lround's do.
std::uint8_t roundedChannel(double v) {
  v = std::clamp(v, 0.0, 255.0);
  const double whole = std::floor(v);
  return static_cast<std::uint8_t>(whole + (v - whole >= 0.5 ? 1.0 : 0.0));
}

float roundUp(double v) {
  float f = static_cast<float>(v);
  if (static_cast<double>(f) < v) f = std::nextafter(f, std::numeric_limits<float>::infinity());
  return f;
}

}  // namespace

std::size_t levelSplatTarget(std::size_t inputs, const LevelSplatOptions& options) {
  if (inputs == 0) return 0;
  const double reduction = std::max(options.reduction, 1.0);
  auto t = static_cast<std::size_t>(std::ceil(static_cast<double>(inputs) / reduction));
  t = std::min<std::size_t>(t, std::max<std::uint32_t>(options.maxPerCell, 1));
  return std::clamp<std::size_t>(t, 1, inputs);
}

Clustering clusterSplats(std::span<const Splat> input, std::size_t target,
                         const LevelSplatOptions& options) {
  Clustering out;
  const std::size_t m = input.size();
  if (m == 0) return out;
  target = std::clamp<std::size_t>(target, 1, m);

  // Buffers kept between calls on this thread: a preprocess clusters millions
  // of small cells, and their allocations cost more than some of the steps.
  thread_local ClusterScratch scratch;
  // Positions relative to the first input keep doubles precise far from the origin.
  const Vec3d origin = {input[0].position[0], input[0].position[1], input[0].position[2]};
  std::vector<Vec3d>& pos = scratch.positions;
  pos.resize(m);
  double radiusSum = 0.0;
  for (std::size_t i = 0; i < m; ++i) {
    pos[i] = sub({input[i].position[0], input[i].position[1], input[i].position[2]}, origin);
    radiusSum += static_cast<double>(input[i].radius);
  }

  // 1. Hierarchical covariance split.
  std::vector<std::uint32_t>& order = scratch.order;
  order.resize(m);
  std::iota(order.begin(), order.end(), 0u);
  auto sum = [&](std::uint32_t b, std::uint32_t e) {
    Moments moments;
    for (std::uint32_t i = b; i < e; ++i) moments.add(pos[order[i]]);
    return moments;
  };
  const auto all = static_cast<std::uint32_t>(m);
  std::vector<Range>& ranges = scratch.ranges;
  ranges.assign(1, makeRange(0, all, sum(0, all)));
  // The ranges still to split, by index, and their spread and begin side by
  // side: a cell has a dozen or so, and a scan for the widest beats a heap,
  // whose sifts the branch predictor cannot guess.
  std::vector<std::uint32_t>& active = scratch.active;
  std::vector<double>& activeSpread = scratch.activeSpread;
  std::vector<std::uint32_t>& activeBegin = scratch.activeBegin;
  active.assign(1, 0);
  activeSpread.assign(1, ranges[0].spread);
  activeBegin.assign(1, 0);
  std::vector<std::uint32_t>& done = scratch.done;
  done.clear();
  std::vector<std::uint32_t>& partitioned = scratch.partitioned;
  partitioned.resize(m);
  const double rootSpread = ranges[0].spread;
  while (!active.empty() && active.size() + done.size() < target) {
    // The largest spread; equal spreads by position, so the result does
    // not depend on the scan's order.
    std::size_t w = 0;
    for (std::size_t j = 1; j < active.size(); ++j)
      if (activeSpread[j] > activeSpread[w] ||
          (activeSpread[j] == activeSpread[w] && activeBegin[j] < activeBegin[w]))
        w = j;
    const std::uint32_t index = active[w];
    const Range r = ranges[index];
    if (!(r.spread > 0.0)) {
      done.push_back(index);
      active[w] = active.back();
      activeSpread[w] = activeSpread.back();
      activeBegin[w] = activeBegin.back();
      active.pop_back();
      activeSpread.pop_back();
      activeBegin.pop_back();
      continue;
    }
    // Cut through the centroid, normal to the direction of largest variance.
    const Vec3d axis = majorAxis(r.moments.covariance());
    const Vec3d mean = r.moments.mean();
    auto proj = [&](std::uint32_t i) { return dot(sub(pos[i], mean), axis); };
    // Partition without branches (the side is a coin toss to the predictor):
    // the low side fills scratch from the front, the high side from the back.
    // Each input is written to both free ends, and only one end advances:
    // the other write lands in a free slot that a later input overwrites.
    std::size_t low = 0, high = r.end - r.begin;
    for (std::uint32_t j = r.begin; j < r.end; ++j) {
      const std::uint32_t i = order[j];
      const bool isLow = proj(i) < 0.0;
      partitioned[low] = i;
      partitioned[high - 1] = i;
      low += isLow;
      high -= !isLow;
    }
    std::copy(partitioned.begin(), partitioned.begin() + (r.end - r.begin),
              order.begin() + r.begin);
    auto* first = order.data() + r.begin;
    auto* last = order.data() + r.end;
    auto* mid = first + low;
    if (mid == first || mid == last) {  // numerically one-sided: cut at the median
      mid = first + (last - first) / 2;
      std::nth_element(first, mid, last, [&](std::uint32_t a, std::uint32_t b) {
        return proj(a) < proj(b) || (proj(a) == proj(b) && a < b);
      });
    }
    const auto cut = static_cast<std::uint32_t>(mid - order.data());
    const bool lowSmaller = cut - r.begin <= r.end - cut;
    const Moments small = lowSmaller ? sum(r.begin, cut) : sum(cut, r.end);
    const Moments large = r.moments.minus(small);
    // The split range's slot takes the low half; the high half is appended.
    ranges[index] = makeRange(r.begin, cut, lowSmaller ? small : large);
    activeSpread[w] = ranges[index].spread;
    active.push_back(static_cast<std::uint32_t>(ranges.size()));
    ranges.push_back(makeRange(cut, r.end, lowSmaller ? large : small));
    activeSpread.push_back(ranges.back().spread);
    activeBegin.push_back(cut);
  }
  done.insert(done.end(), active.begin(), active.end());
  std::sort(done.begin(), done.end(),
            [&](std::uint32_t a, std::uint32_t b) { return ranges[a].begin < ranges[b].begin; });

  std::size_t k = done.size();
  out.assignment.assign(m, 0);
  for (std::size_t c = 0; c < k; ++c)
    for (std::uint32_t i = ranges[done[c]].begin; i < ranges[done[c]].end; ++i)
      out.assignment[order[i]] = static_cast<std::uint32_t>(c);

  // 2. Mahalanobis refinement: reassign to the most likely cluster Gaussian.
  // Skipped when the all-pairs cost would explode (huge degenerate leaves).
  double eps = 0.25 * (radiusSum / static_cast<double>(m)) * (radiusSum / static_cast<double>(m));
  if (!(eps > 0.0)) eps = 1e-6 * rootSpread;
  if (!(eps > 0.0)) eps = 1e-12;
  for (int it = 0; it < options.refineIterations && k > 1 && m * k <= (std::size_t{1} << 22);
       ++it) {
    std::vector<Moments>& acc = scratch.moments;
    acc.assign(k, Moments{});
    for (std::size_t i = 0; i < m; ++i) acc[out.assignment[i]].add(pos[i]);
    std::vector<GaussianRecord>& g = scratch.gaussians;
    g.clear();
    for (const auto& a : acc) g.push_back(makeGaussian(a, eps));
    // Every cluster is tried (SIMD over inputs): choosing a few near ones
    // first cost more than trying them all.
    const bool changed = assignLikeliestGaussians(pos, g, out.assignment);
    // Drop clusters that lost all their members.
    std::vector<std::uint8_t>& alive = scratch.alive;
    alive.assign(k, 0);
    for (const std::uint32_t a : out.assignment) alive[a] = 1;
    std::vector<std::uint32_t>& remap = scratch.remap;
    remap.assign(k, kNoIndex);
    std::uint32_t used = 0;
    for (std::size_t c = 0; c < k; ++c)
      if (alive[c]) remap[c] = used++;
    for (auto& a : out.assignment) a = remap[a];
    k = used;
    if (!changed) break;
  }

  // 3. One splat per cluster.
  std::vector<Moments>& acc = scratch.moments;
  acc.assign(k, Moments{});
  std::vector<Vec3d>& normalSum = scratch.normalSums;
  normalSum.assign(k, Vec3d{});
  std::vector<std::array<double, 4>>& colorSum = scratch.colorSums;
  colorSum.assign(k, std::array<double, 4>{});
  std::vector<std::uint8_t>& anyNormal = scratch.anyNormal;
  anyNormal.assign(k, 0);
  for (std::size_t i = 0; i < m; ++i) {
    const std::uint32_t c = out.assignment[i];
    acc[c].add(pos[i]);
    const Vec3d n = {input[i].normal[0], input[i].normal[1], input[i].normal[2]};
    if (dot(n, n) > 0.25) {
      normalSum[c] = add(normalSum[c], normalized(n));
      anyNormal[c] = 1;
    }
    for (std::size_t ch = 0; ch < 4; ++ch) colorSum[c][ch] += input[i].color[ch];
  }
  // The plane fits' eigenvectors, solved together (SIMD).
  std::vector<Sym3>& covariances = scratch.covariances;
  covariances.clear();
  for (std::size_t c = 0; c < k; ++c) {
    if (anyNormal[c] && acc[c].count >= 3.0) covariances.push_back(acc[c].covariance());
  }
  std::vector<SmallestEigen3>& planes = scratch.planes;
  planes.resize(covariances.size());
  smallestEigen3Batch(covariances, planes);
  std::size_t plane = 0;
  out.splats.resize(k);
  for (std::size_t c = 0; c < k; ++c) {
    Splat& s = out.splats[c];
    const Vec3d mean = add(acc[c].mean(), origin);
    for (std::size_t a = 0; a < 3; ++a) s.position[a] = static_cast<float>(mean[a]);
    Vec3d normal{};
    if (anyNormal[c]) {
      normal = normalized(normalSum[c]);
      if (acc[c].count >= 3.0) {
        const SmallestEigen3& e = planes[plane++];
        // A plane fit needs a cluster that is flat but not a line: otherwise
        // the plane can spin about the line and the mean normal is better.
        const bool flat = e.values[1] > 0.0 && e.values[0] <= 0.25 * e.values[1] &&
                          e.values[1] >= 0.05 * e.values[2];
        if (flat) normal = dot(e.vector, normalSum[c]) < 0.0 ? scale(e.vector, -1.0) : e.vector;
      }
    }
    for (std::size_t a = 0; a < 3; ++a) s.normal[a] = static_cast<float>(normal[a]);
    const double n = acc[c].count;
    for (std::size_t ch = 0; ch < 4; ++ch) s.color[ch] = roundedChannel(colorSum[c][ch] / n);
    s.radius = 0.0f;
  }
  // Radius from the stored (float) centre so the coverage property holds exactly.
  std::vector<double>& radius = scratch.radii;
  radius.assign(k, 0.0);
  for (std::size_t i = 0; i < m; ++i) {
    const std::uint32_t c = out.assignment[i];
    const Splat& s = out.splats[c];
    Vec3d d;
    for (std::size_t a = 0; a < 3; ++a)
      d[a] = static_cast<double>(input[i].position[a]) - static_cast<double>(s.position[a]);
    const auto ri = static_cast<double>(input[i].radius);
    radius[c] = std::max({radius[c], length(d) + options.radiusShare * ri, ri});
  }
  for (std::size_t c = 0; c < k; ++c) out.splats[c].radius = roundUp(radius[c]);
  return out;
}

LevelSplats buildLevelSplats(const Octree& tree, const LevelSplatOptions& options,
                             const ProgressFn& progress, unsigned threads,
                             const LevelSplatHooks& hooks) {
  const auto& cells = tree.cells;
  const std::size_t nTop = tree.topLevelCells.size();
  struct TopResult {
    std::vector<Splat> splats;
    std::vector<std::uint32_t> begin;  // per cell of the subtree
    std::vector<std::uint32_t> count;
    std::size_t size = 0;  // splats, still known when they are dropped
  };
  std::vector<TopResult> results(nTop);
  const auto madePacket = [&](std::size_t k) {
    return MadePacket{k, results[k].splats, results[k].begin, results[k].count};
  };

  auto process = [&](std::size_t k) {
    const std::uint32_t root = tree.topLevelCells[k];
    const std::uint32_t end = cells[root].nextSibling == kNoIndex
                                  ? static_cast<std::uint32_t>(cells.size())
                                  : cells[root].nextSibling;
    const std::size_t count = end - root;
    std::vector<std::vector<Splat>> perCell(count);
    std::vector<Splat> gathered;
    for (std::uint32_t i = end; i-- > root;) {
      const BuildCell& c = cells[i];
      std::span<const Splat> inputs;
      if (c.isLeaf()) {
        inputs = std::span<const Splat>(tree.points)
                     .subspan(static_cast<std::size_t>(c.begin),
                              static_cast<std::size_t>(c.end - c.begin));
      } else {
        gathered.clear();
        for (std::uint32_t j = i + 1; j < end && cells[j].parent == i; j = cells[j].nextSibling) {
          const auto& child = perCell[j - root];
          gathered.insert(gathered.end(), child.begin(), child.end());
          if (cells[j].nextSibling == kNoIndex) break;
        }
        inputs = gathered;
      }
      perCell[i - root] =
          clusterSplats(inputs, levelSplatTarget(inputs.size(), options), options).splats;
    }
    // Laid out as the packet: by level from the highest down, cells of one
    // level in depth-first order.
    std::vector<std::uint32_t> order(count);
    std::iota(order.begin(), order.end(), 0u);
    std::stable_sort(order.begin(), order.end(), [&](std::uint32_t a, std::uint32_t b) {
      return cells[root + a].level > cells[root + b].level;
    });
    TopResult& r = results[k];
    r.begin.resize(count);
    r.count.resize(count);
    std::size_t total = 0;
    for (const auto& v : perCell) total += v.size();
    r.splats.reserve(total);
    for (const std::uint32_t j : order) {
      r.begin[j] = static_cast<std::uint32_t>(r.splats.size());
      r.count[j] = static_cast<std::uint32_t>(perCell[j].size());
      r.splats.insert(r.splats.end(), perCell[j].begin(), perCell[j].end());
    }
    r.size = r.splats.size();
    if (hooks.made) hooks.made(madePacket(k));
  };

  // Workers take top-level cells in turn; this thread reports progress and
  // hands finished packets on in order, so a callback that throws (interrupt,
  // a full disk) stops the workers cleanly.
  std::atomic<std::size_t> next{0};
  std::atomic<std::uint64_t> pointsDone{0};
  std::atomic<bool> stop{false};
  std::mutex mutex;
  std::condition_variable cv;
  std::size_t finishedWorkers = 0;
  const bool handOn = static_cast<bool>(hooks.handOn);
  std::vector<std::uint8_t> finished(handOn ? nTop : 0, 0);  // under mutex
  std::exception_ptr error;
  if (threads == 0) threads = std::max(1u, std::thread::hardware_concurrency());
  threads = static_cast<unsigned>(std::min<std::size_t>(threads, std::max<std::size_t>(nTop, 1)));
  auto worker = [&] {
    try {
      for (std::size_t k; !stop && (k = next++) < nTop;) {
        process(k);
        const BuildCell& root = cells[tree.topLevelCells[k]];
        pointsDone += root.end - root.begin;
        if (handOn) {
          std::lock_guard lock(mutex);
          finished[k] = 1;
          cv.notify_all();
        }
      }
    } catch (...) {
      std::lock_guard lock(mutex);
      if (!error) error = std::current_exception();
      stop = true;
    }
    std::lock_guard lock(mutex);
    ++finishedWorkers;
    cv.notify_all();
  };
  if (progress) progress(0, tree.points.size());
  std::vector<std::thread> pool;
  for (unsigned t = 0; t < threads; ++t) pool.emplace_back(worker);
  try {
    std::size_t handedOn = 0;
    auto lastProgress = std::chrono::steady_clock::now();
    std::unique_lock lock(mutex);
    while (finishedWorkers < pool.size() || (handOn && !error && handedOn < nTop)) {
      if (handOn && handedOn < nTop && finished[handedOn] != 0) {
        lock.unlock();
        hooks.handOn(madePacket(handedOn));
        if (!hooks.keepSplats) results[handedOn].splats = {};
        ++handedOn;
        lock.lock();
      } else {
        cv.wait_for(lock, std::chrono::milliseconds(200));
      }
      if (progress &&
          std::chrono::steady_clock::now() - lastProgress >= std::chrono::milliseconds(200)) {
        lastProgress = std::chrono::steady_clock::now();
        lock.unlock();
        progress(pointsDone.load(), tree.points.size());
        lock.lock();
      }
    }
  } catch (...) {
    stop = true;
    for (auto& t : pool) t.join();
    throw;
  }
  for (auto& t : pool) t.join();
  if (error) std::rethrow_exception(error);

  LevelSplats out;
  out.cellBegin.assign(cells.size(), 0);
  out.cellCount.assign(cells.size(), 0);
  out.topLevelBegin.resize(nTop + 1);
  std::size_t total = 0;
  for (std::size_t k = 0; k < nTop; ++k) {
    out.topLevelBegin[k] = total;
    total += results[k].size;
  }
  out.topLevelBegin[nTop] = total;
  // Gathered on all threads: a copy of a third of the points' bytes, into
  // pages mapped on all threads first (the resize only zeroes them).
  if (hooks.keepSplats) resizePopulated(out.splats, total, threads);
  parallelFor(
      nTop, threads,
      [&](std::size_t k) {
        const std::uint32_t root = tree.topLevelCells[k];
        for (std::size_t j = 0; j < results[k].begin.size(); ++j) {
          out.cellBegin[root + j] = out.topLevelBegin[k] + results[k].begin[j];
          out.cellCount[root + j] = results[k].count[j];
        }
        if (hooks.keepSplats)
          std::copy(results[k].splats.begin(), results[k].splats.end(),
                    out.splats.begin() + static_cast<std::ptrdiff_t>(out.topLevelBegin[k]));
        results[k] = {};
      },
      16);
  // Cells above the top-level depth: where their subtree's packets begin.
  for (std::size_t i = cells.size(); i-- > 0;)
    if (cells[i].topLevel == kNoIndex) out.cellBegin[i] = out.cellBegin[i + 1];
  if (progress) progress(tree.points.size(), tree.points.size());
  return out;
}

}  // namespace pointillist::preprocess
