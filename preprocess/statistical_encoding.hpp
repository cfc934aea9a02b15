#pragma once
// Seed 004 §5 and the dataset: every top-level cell's PCA hierarchy
// (preprocess/statistical_hierarchy.hpp) classified and quantized into a
// statistical packet (common/statistical_node.hpp). Encoding is closed-loop:
// a node is coded against its parent as the decoder will see it, so
// quantization errors do not add up down the tree.
#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <vector>

#include "common/dataset_writer.hpp"
#include "common/statistical_node.hpp"
#include "preprocess/statistical_hierarchy.hpp"

namespace pointillist::preprocess {

struct StatisticalStats {
  std::uint64_t points = 0;
  std::uint64_t nodes = 0;
  std::uint64_t leaves = 0;
  std::uint64_t euclideanSplits = 0;
  std::uint32_t maxDepth = 0;
  std::uint64_t packetBytes = 0;  // statistical.bin
  std::uint64_t classBytes = 0;   // statistical-classes.bin
  // Decoded against unquantized nodes: the mean's error in units of its
  // parent's sigma_1 (the scale it is coded at; rms and largest), the means
  // that lay outside their parent's coding range (clamped), the position
  // sigmas' relative error (rms of log).
  double meanErrorRms = 0.0;
  double meanErrorMax = 0.0;
  std::uint64_t clampedMeans = 0;
  double sigmaLogErrorRms = 0.0;
  double treeSeconds = 0.0;
  double classSeconds = 0.0;
  double encodeSeconds = 0.0;
};

// The global tables from every tree's standard deviations: position sigmas as
// ratios to the parent's sigma_1 (the root's: to the cell's largest extent),
// classified in log space, likewise normal and colour sigmas.
ClassTables classifyStatisticalTrees(std::span<const PcaTree> trees,
                                     std::span<const StatisticalPacketHeader> headers,
                                     const StatisticalOptions& options);

// The root's box of a cell's packet: its points' bounds.
StatisticalPacketHeader statisticalHeader(std::span<const Splat> points, std::uint32_t nodeCount);

// One cell's packet (header, nodes, padding to 32 bytes) and its decoded nodes
// (what a render process will decode), adding errors to `stats` sums.
struct EncodedCell {
  std::vector<std::byte> bytes;
  std::vector<StatisticalNode> decoded;
};
class StatisticalEncoder {
 public:
  explicit StatisticalEncoder(ClassTables tables);
  ~StatisticalEncoder();
  const ClassTables& tables() const;
  EncodedCell encode(const PcaTree& tree, const StatisticalPacketHeader& header) const;

 private:
  struct Classes;
  std::unique_ptr<Classes> classes_;
};

// Adds statistical.bin, statistical-index.bin and statistical-classes.bin to
// `content` (its points in memory, table order). On `threads` threads;
// progress(done, total) in points from the calling thread.
StatisticalStats addStatisticalPackets(
    DatasetContent& content, const StatisticalOptions& options,
    const std::function<void(std::uint64_t, std::uint64_t)>& progress = {});

}  // namespace pointillist::preprocess
