#pragma once
// Seed 004 §10.1: the rate-distortion curve of the statistical hierarchy. At
// every depth d of the hierarchies, the cut of the nodes at depth d (and the
// leaves above it) generates as many points as each node holds (samples of
// the quasi-random sequence); each generated point's distance to the nearest
// original point, root-mean-squared, against the bounding box diagonal gives
// the Hausdorff PSNR, 20 log10(diagonal / rms). The rate is what a decoder
// needs for that cut: every node down to depth d, 13 bytes each for position
// and normal (18 with colour and flags), per original point.
#include <cstdint>
#include <span>
#include <vector>

#include "common/splat.hpp"
#include "common/statistical_node.hpp"
#include "preprocess/statistical_hierarchy.hpp"

namespace pointillist::preprocess {

struct RateDistortionPoint {
  std::uint32_t depth = 0;
  std::uint64_t cutNodes = 0;
  std::uint64_t prefixNodes = 0;  // every node down to the depth
  double bitsPerPoint = 0.0;      // position and normal: 13 bytes a node
  double bitsWithColor = 0.0;     // the whole 18-byte node
  std::uint64_t generated = 0;    // points measured (nodes may be sampled, see maxGenerated)
  double rmsDistance = 0.0;
  double psnr = 0.0;             // decoded (quantized) nodes
  double psnrUnquantized = 0.0;  // the same cut from the unquantized PCA
};

// One top-level cell: its original points, its hierarchy and the nodes a
// render process decodes from its packet (same order).
struct CellHierarchy {
  std::span<const Splat> points;
  const PcaTree* tree = nullptr;
  std::span<const StatisticalNode> decoded;
};

// The curve over all cells, one entry per depth up to the deepest. At most
// `maxGenerated` points are generated per depth (every k-th cut node when the
// cut holds more); distances go to the nearest of `allPoints`.
std::vector<RateDistortionPoint> rateDistortion(std::span<const Splat> allPoints,
                                                std::span<const CellHierarchy> cells,
                                                std::uint64_t maxGenerated = 2'000'000,
                                                unsigned threads = 0);

// The unquantized node as the generator reads a decoded one.
StatisticalNode unquantizedNode(const PcaNode& node);

}  // namespace pointillist::preprocess
