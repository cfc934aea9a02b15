#include "preprocess/statistical_quality.hpp"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <mutex>

#include "common/statistical_samples.hpp"
#include "preprocess/parallel.hpp"
#include "preprocess/splat_kd_tree.hpp"

namespace pointillist::preprocess {

StatisticalNode unquantizedNode(const PcaNode& n) {
  StatisticalNode out{};
  for (std::size_t i = 0; i < 3; ++i) {
    out.mean[i] = static_cast<float>(n.mean[i]);
    out.sigma[i] = static_cast<float>(n.sigma[i]);
    out.color[i] = static_cast<float>(n.color[i]);
    out.sigmaColor[i] = static_cast<float>(n.sigmaColor[i]);
    for (std::size_t j = 0; j < 3; ++j) {
      out.axes[i][j] = static_cast<float>(n.axes[i][j]);
      out.normalFrame[i][j] = static_cast<float>(n.normalFrame[i][j]);
      out.colorAxes[i][j] = static_cast<float>(n.colorAxes[i][j]);
    }
  }
  out.sigmaNormal[0] = static_cast<float>(n.sigmaNormal[0]);
  out.sigmaNormal[1] = static_cast<float>(n.sigmaNormal[1]);
  out.firstChild = n.firstChild;
  out.parent = n.parent;
  return out;
}

std::vector<RateDistortionPoint> rateDistortion(std::span<const Splat> allPoints,
                                                std::span<const CellHierarchy> cells,
                                                std::uint64_t maxGenerated, unsigned threads) {
  std::vector<RateDistortionPoint> curve;
  if (allPoints.empty() || cells.empty()) return curve;
  float low[3], high[3];
  for (std::size_t k = 0; k < 3; ++k) low[k] = high[k] = allPoints[0].position[k];
  for (const Splat& s : allPoints)
    for (std::size_t k = 0; k < 3; ++k) {
      low[k] = std::min(low[k], s.position[k]);
      high[k] = std::max(high[k], s.position[k]);
    }
  double diagonal = 0;
  for (std::size_t k = 0; k < 3; ++k)
    diagonal += double(high[k] - low[k]) * double(high[k] - low[k]);
  diagonal = std::sqrt(diagonal);

  const SplatCloudAdaptor adaptor{allPoints};
  SplatKdTree tree(3, adaptor, nanoflann::KDTreeSingleIndexAdaptorParams(16));
  tree.buildIndex();

  // Depth of every node, per cell; the deepest overall.
  std::vector<std::vector<std::uint32_t>> depths(cells.size());
  std::uint32_t deepest = 0;
  std::uint64_t points = 0;
  for (std::size_t c = 0; c < cells.size(); ++c) {
    const auto& nodes = cells[c].tree->nodes;
    depths[c].assign(nodes.size(), 0);
    for (std::size_t i = 1; i < nodes.size(); ++i) {
      depths[c][i] = depths[c][nodes[i].parent] + 1;
      deepest = std::max(deepest, depths[c][i]);
    }
    points += cells[c].points.size();
  }

  std::uint32_t largest = 1;
  for (const CellHierarchy& cell : cells)
    for (const PcaNode& n : cell.tree->nodes) largest = std::max(largest, n.pointCount);
  const auto samples = gaussianSamples(std::min<std::uint32_t>(largest, 1u << 22));

  for (std::uint32_t depth = 0; depth <= deepest; ++depth) {
    RateDistortionPoint p;
    p.depth = depth;
    // The cut: nodes at this depth, and leaves above it.
    struct Pick {
      std::uint32_t cell, node;
    };
    std::vector<Pick> cut;
    std::uint64_t cutPoints = 0;
    for (std::size_t c = 0; c < cells.size(); ++c) {
      const auto& nodes = cells[c].tree->nodes;
      for (std::size_t i = 0; i < nodes.size(); ++i) {
        if (depths[c][i] <= depth) ++p.prefixNodes;
        if (depths[c][i] == depth || (depths[c][i] < depth && nodes[i].firstChild == 0)) {
          cut.push_back({static_cast<std::uint32_t>(c), static_cast<std::uint32_t>(i)});
          cutPoints += nodes[i].pointCount;
        }
      }
    }
    p.cutNodes = cut.size();
    p.bitsPerPoint = double(p.prefixNodes) * 13 * 8 / double(points);
    p.bitsWithColor = double(p.prefixNodes) * 18 * 8 / double(points);
    const std::uint64_t stride =
        std::max<std::uint64_t>(1, (cutPoints + maxGenerated - 1) / maxGenerated);
    std::mutex mutex;
    double sumQ = 0, sumU = 0;
    std::uint64_t generated = 0;
    parallelFor((cut.size() + stride - 1) / stride, threads,
                [&](std::size_t k) {
                  const Pick pick = cut[k * stride];
                  const CellHierarchy& cell = cells[pick.cell];
                  const PcaNode& node = cell.tree->nodes[pick.node];
                  const StatisticalNode raw = unquantizedNode(node);
                  const StatisticalNode& decoded = cell.decoded[pick.node];
                  double q = 0, u = 0;
                  const std::uint32_t count = std::min<std::uint32_t>(
                      node.pointCount, static_cast<std::uint32_t>(samples.size()));
                  for (std::uint32_t i = 0; i < count; ++i) {
                    for (int pass = 0; pass < 2; ++pass) {
                      const Splat s = generatePoint(pass == 0 ? decoded : raw, samples[i], 0.0f);
                      std::uint32_t index = 0;
                      float d2 = std::numeric_limits<float>::max();
                      nanoflann::KNNResultSet<float, std::uint32_t> result(1);
                      result.init(&index, &d2);
                      tree.findNeighbors(result, s.position, nanoflann::SearchParams(10));
                      (pass == 0 ? q : u) += double(d2);
                    }
                  }
                  std::lock_guard lock(mutex);
                  sumQ += q;
                  sumU += u;
                  generated += count;
                },
                16);
    p.generated = generated;
    if (generated > 0) {
      p.rmsDistance = std::sqrt(sumQ / double(generated));
      p.psnr = 20.0 * std::log10(diagonal / std::max(p.rmsDistance, 1e-300));
      p.psnrUnquantized =
          20.0 * std::log10(diagonal / std::max(std::sqrt(sumU / double(generated)), 1e-300));
    }
    curve.push_back(p);
  }
  return curve;
}

}  // namespace pointillist::preprocess
