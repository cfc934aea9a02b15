#include "preprocess/statistical_encoding.hpp"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <exception>
#include <mutex>
#include <string>
#include <thread>

#include "common/checksum.hpp"
#include "common/errors.hpp"
#include "preprocess/parallel.hpp"

namespace pointillist::preprocess {

namespace {

// Floors before taking logs: a flat node's sigma_3, a node of coincident
// points, identical normals or colours have zero spread.
constexpr double kRootSigmaFloor = 1e-9;    // of the reference length
constexpr double kNormalSigmaFloor = 1e-4;  // radians
constexpr double kColorSigmaFloor = 0.25;   // RGB units

std::array<float, 3> positionKey(const Vec3d& sigma, double reference) {
  const double s0 = std::max(sigma[0], kRootSigmaFloor * reference);
  std::array<float, 3> key{};
  for (std::size_t k = 0; k < 3; ++k) {
    const double s = k == 0 ? s0 : std::max(sigma[k], double(kSigmaFloor) * s0);
    key[k] = static_cast<float>(std::log(s / reference));
  }
  return key;
}
std::array<float, 2> normalKey(const std::array<double, 2>& sigma) {
  return {static_cast<float>(std::log(std::max(sigma[0], kNormalSigmaFloor))),
          static_cast<float>(std::log(std::max(sigma[1], kNormalSigmaFloor)))};
}
std::array<float, 3> colorKey(const Vec3d& sigma) {
  std::array<float, 3> key{};
  for (std::size_t k = 0; k < 3; ++k)
    key[k] = static_cast<float>(std::log(std::max(sigma[k], kColorSigmaFloor)));
  return key;
}

template <std::size_t D>
std::vector<std::array<float, D>> exponentiated(std::vector<std::array<float, D>> centres) {
  for (auto& c : centres) {
    for (float& v : c) v = std::exp(v);
    std::sort(c.begin(), c.end(), [](float a, float b) { return a > b; });  // descending
  }
  return centres;
}

template <std::size_t D>
std::vector<std::array<float, D>> logs(const std::vector<std::array<float, D>>& table) {
  std::vector<std::array<float, D>> out(table.size());
  for (std::size_t i = 0; i < table.size(); ++i)
    for (std::size_t k = 0; k < D; ++k) out[i][k] = std::log(table[i][k]);
  return out;
}

double seconds(std::chrono::steady_clock::time_point since) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - since).count();
}

}  // namespace

ClassTables classifyStatisticalTrees(std::span<const PcaTree> trees,
                                     std::span<const StatisticalPacketHeader> headers,
                                     const StatisticalOptions& options) {
  std::vector<std::array<float, 3>> position, color;
  std::vector<std::array<float, 2>> normal;
  for (std::size_t t = 0; t < trees.size(); ++t) {
    const auto& nodes = trees[t].nodes;
    const double rootReference = positionClassReference(nullptr, headers[t]);
    for (std::size_t i = 0; i < nodes.size(); ++i) {
      const double reference = i == 0 ? rootReference : nodes[nodes[i].parent].sigma[0];
      position.push_back(positionKey(nodes[i].sigma, reference > 0 ? reference : 1.0));
      normal.push_back(normalKey(nodes[i].sigmaNormal));
      color.push_back(colorKey(nodes[i].sigmaColor));
    }
  }
  if (position.empty()) throw Error("internal error: no statistical nodes to classify");
  ClassTables tables;
  tables.position = exponentiated(
      kMeansClasses<3>(std::span<const std::array<float, 3>>(position), options.positionClasses));
  tables.normal = exponentiated(
      kMeansClasses<2>(std::span<const std::array<float, 2>>(normal), options.normalClasses));
  tables.color = exponentiated(
      kMeansClasses<3>(std::span<const std::array<float, 3>>(color), options.colorClasses));
  return tables;
}

StatisticalPacketHeader statisticalHeader(std::span<const Splat> points, std::uint32_t nodeCount) {
  StatisticalPacketHeader h{};
  h.magic = kStatisticalMagic;
  h.version = kStatisticalVersion;
  h.nodeCount = nodeCount;
  h.pointCount = static_cast<std::uint32_t>(points.size());
  float low[3] = {0, 0, 0}, high[3] = {0, 0, 0};
  for (std::size_t i = 0; i < points.size(); ++i)
    for (std::size_t k = 0; k < 3; ++k) {
      const float v = points[i].position[k];
      low[k] = i == 0 ? v : std::min(low[k], v);
      high[k] = i == 0 ? v : std::max(high[k], v);
    }
  for (std::size_t k = 0; k < 3; ++k) {
    h.origin[k] = low[k];
    h.extent[k] = high[k] - low[k];
  }
  return h;
}

struct StatisticalEncoder::Classes {
  ClassTables tables;
  NearestClass<3> position;
  NearestClass<2> normal;
  NearestClass<3> color;
  explicit Classes(ClassTables t)
      : tables(std::move(t)),
        position(logs(tables.position)),
        normal(logs(tables.normal)),
        color(logs(tables.color)) {}
};

StatisticalEncoder::StatisticalEncoder(ClassTables tables)
    : classes_(std::make_unique<Classes>(std::move(tables))) {}
StatisticalEncoder::~StatisticalEncoder() = default;
const ClassTables& StatisticalEncoder::tables() const {
  return classes_->tables;
}

EncodedCell StatisticalEncoder::encode(const PcaTree& tree,
                                       const StatisticalPacketHeader& header) const {
  const auto& nodes = tree.nodes;
  EncodedCell out;
  const std::size_t bytes = kStatisticalHeaderBytes + nodes.size() * kStatisticalNodeBytes;
  out.bytes.assign((bytes + 31) / 32 * 32, std::byte{0});
  StatisticalPacketHeader h = header;
  h.nodeCount = static_cast<std::uint32_t>(nodes.size());
  std::memcpy(out.bytes.data(), &h, sizeof h);
  out.decoded.resize(nodes.size());
  for (std::size_t i = 0; i < nodes.size(); ++i) {
    const PcaNode& n = nodes[i];
    const StatisticalNode* parent = i == 0 ? nullptr : &out.decoded[n.parent];
    StatisticalNodeCode code;
    encodeNodeMean(n.mean.data(), parent, h, code.mean);
    encodeFrame(FrameKind::Position, n.axes, code.frame);
    const double reference = positionClassReference(parent, h);
    code.sigmaClass =
        static_cast<std::uint16_t>(classes_->position(positionKey(n.sigma, reference)));
    code.normalClass = static_cast<std::uint16_t>(classes_->normal(normalKey(n.sigmaNormal)));
    encodeFrame(FrameKind::Normal, n.normalFrame, code.normalFrame);
    code.color565 = encodeColor565(n.color.data());
    encodeFrame(FrameKind::Color, n.colorAxes, code.colorFrame);
    code.colorClass = static_cast<std::uint8_t>(classes_->color(colorKey(n.sigmaColor)));
    code.flags = n.firstChild != 0 ? kNodeHasChildren : 0;
    packStatisticalNode(code,
                        out.bytes.data() + kStatisticalHeaderBytes + i * kStatisticalNodeBytes);
    out.decoded[i] = decodeStatisticalNode(code, parent, h, classes_->tables);
    out.decoded[i].parent = n.parent;
    out.decoded[i].firstChild = n.firstChild;
  }
  return out;
}

StatisticalStats addStatisticalPackets(
    DatasetContent& content, const StatisticalOptions& options,
    const std::function<void(std::uint64_t, std::uint64_t)>& progress) {
  const auto& table = content.topLevel;
  const std::size_t count = table.size();
  std::vector<std::uint64_t> begin(count + 1, 0);
  for (std::size_t k = 0; k < count; ++k) begin[k + 1] = begin[k] + table[k].pointCount;
  if (begin[count] != content.points.size())
    throw Error("internal error: the statistical hierarchy needs every point in memory");
  const auto cellPoints = [&](std::size_t k) {
    return std::span<const Splat>(content.points).subspan(begin[k], table[k].pointCount);
  };
  StatisticalStats stats;
  stats.points = begin[count];
  StatisticalOptions perCell = options;
  perCell.threads = 1;

  // Trees, then the global classes, then every packet against them.
  auto start = std::chrono::steady_clock::now();
  std::vector<PcaTree> trees(count);
  std::vector<StatisticalPacketHeader> headers(count);
  std::atomic<std::uint64_t> done{0};
  std::mutex mutex;
  std::exception_ptr error;
  std::atomic<bool> stop{false};
  const auto caller = std::this_thread::get_id();
  const std::uint64_t total = 2 * begin[count];
  if (progress) progress(0, total);
  const auto guarded = [&](auto&& body) {
    return [&, body](std::size_t k) {
      if (stop) return;
      try {
        body(k);
        done += table[k].pointCount;
        if (progress && std::this_thread::get_id() == caller) progress(done, total);
      } catch (...) {
        std::lock_guard lock(mutex);
        if (!error) error = std::current_exception();
        stop = true;
      }
    };
  };
  parallelFor(count, options.threads, guarded([&](std::size_t k) {
                trees[k] = buildPcaTree(cellPoints(k), perCell);
                headers[k] = statisticalHeader(cellPoints(k),
                                               static_cast<std::uint32_t>(trees[k].nodes.size()));
              }),
              1);
  if (error) std::rethrow_exception(error);
  stats.treeSeconds = seconds(start);

  start = std::chrono::steady_clock::now();
  const StatisticalEncoder encoder(classifyStatisticalTrees(trees, headers, options));
  stats.classSeconds = seconds(start);

  start = std::chrono::steady_clock::now();
  std::vector<std::vector<std::byte>> packets(count);
  double meanSq = 0, meanMax = 0, sigmaSq = 0;
  std::uint64_t sigmaTerms = 0;
  parallelFor(
      count, options.threads, guarded([&](std::size_t k) {
        EncodedCell cell = encoder.encode(trees[k], headers[k]);
        double sq = 0, mx = 0, ss = 0;
        std::uint64_t terms = 0, clamped = 0;
        const auto& nodes = trees[k].nodes;
        constexpr double levels[3] = {2047, 2047, 1023};
        for (std::size_t i = 1; i < nodes.size(); ++i) {
          const StatisticalNode& d = cell.decoded[i];
          const StatisticalNode& p = cell.decoded[nodes[i].parent];
          const PcaNode& n = nodes[i];
          // The mean's error in its parent's frame: within half a
          // step of the parent's range unless the mean lay outside it.
          double e = 0;
          bool outside = false;
          for (std::size_t a = 0; a < 3; ++a) {
            double along = 0;
            for (std::size_t j = 0; j < 3; ++j)
              along += (double(d.mean[j]) - n.mean[j]) * double(p.axes[a][j]);
            e += along * along;
            const double s = double(std::max(p.sigma[a], kMeanRangeFloor * p.sigma[0]));
            if (std::abs(along) > (0.5 + 1e-3) * 2 * double(kChildMeanRange) * s / levels[a] +
                                      1e-6 * double(p.sigma[0]))
              outside = true;
          }
          if (outside) ++clamped;
          e = std::sqrt(e) / std::max(double(p.sigma[0]), 1e-30);
          sq += e * e;
          mx = std::max(mx, e);
          for (std::size_t j = 0; j < 3; ++j)
            if (n.sigma[j] > double(kSigmaFloor) * n.sigma[0]) {
              const double l = std::log(double(d.sigma[j]) / n.sigma[j]);
              ss += l * l;
              ++terms;
            }
        }
        packets[k] = std::move(cell.bytes);
        std::lock_guard lock(mutex);
        meanSq += sq;
        meanMax = std::max(meanMax, mx);
        sigmaSq += ss;
        sigmaTerms += terms;
        stats.clampedMeans += clamped;
        stats.nodes += nodes.size();
        for (const PcaNode& n : nodes) {
          if (n.firstChild == 0) ++stats.leaves;
          if (n.euclideanSplit) ++stats.euclideanSplits;
        }
        std::vector<std::uint32_t> depth(nodes.size(), 0);
        for (std::size_t i = 1; i < nodes.size(); ++i) {
          depth[i] = depth[nodes[i].parent] + 1;
          stats.maxDepth = std::max(stats.maxDepth, depth[i]);
        }
      }),
      1);
  if (error) std::rethrow_exception(error);
  stats.encodeSeconds = seconds(start);
  if (stats.nodes > 0) stats.meanErrorRms = std::sqrt(meanSq / double(stats.nodes));
  stats.meanErrorMax = meanMax;
  if (sigmaTerms > 0) stats.sigmaLogErrorRms = std::sqrt(sigmaSq / double(sigmaTerms));
  trees.clear();

  std::vector<StatisticalPacketEntry> entries(count);
  std::vector<std::byte> all;
  for (std::size_t k = 0; k < count; ++k) {
    entries[k].byteOffset = all.size();
    entries[k].records = static_cast<std::uint32_t>(packets[k].size() / sizeof(Splat));
    entries[k].nodeCount = headers[k].nodeCount;
    entries[k].checksum = checksum64(packets[k].data(), packets[k].size());
    all.insert(all.end(), packets[k].begin(), packets[k].end());
    std::vector<std::byte>().swap(packets[k]);
  }
  std::vector<std::byte> index(entries.size() * sizeof(StatisticalPacketEntry));
  if (!index.empty()) std::memcpy(index.data(), entries.data(), index.size());
  auto classes = encodeClassTables(encoder.tables());
  stats.packetBytes = all.size();
  stats.classBytes = classes.size();
  // The build's options, so a tool can rebuild the same hierarchies
  // (pointillist-statistical-quality) and a dataset can be reproduced.
  auto& extra = content.manifest.extra;
  const auto number = [](double v) {
    char text[32];
    std::snprintf(text, sizeof text, "%.17g", v);
    return std::string(text);
  };
  extra["statistical_leaf_points"] = std::to_string(options.leafPoints);
  extra["statistical_min_sigma_share"] = number(options.minSigmaShare);
  extra["statistical_balance_share"] = number(options.balanceShare);
  extra["statistical_eta"] = number(options.eta0) + " " + number(options.eta1);
  extra["statistical_classes"] = std::to_string(encoder.tables().position.size()) + " " +
                                 std::to_string(encoder.tables().normal.size()) + " " +
                                 std::to_string(encoder.tables().color.size());
  content.extraFiles.push_back({kStatisticalPacketsKey, kStatisticalPacketsName, std::move(all)});
  content.extraFiles.push_back({kStatisticalIndexKey, kStatisticalIndexName, std::move(index)});
  content.extraFiles.push_back(
      {kStatisticalClassesKey, kStatisticalClassesName, std::move(classes)});
  return stats;
}

}  // namespace pointillist::preprocess
