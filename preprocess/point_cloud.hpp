#pragma once
// In-memory point cloud as read from an input file or generated.
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <span>
#include <string>
#include <vector>

#include "common/splat.hpp"

namespace pointillist::preprocess {

struct PointCloud {
  std::vector<Splat> splats;
  bool hasNormals = false;
  bool hasColors = false;
  bool hasRadii = false;
  std::string source;  // file name or generator name, for messages
};

// The grey given to points whose input has no colour (readers, and splats
// that normal estimation finds never written).
inline constexpr std::uint8_t kDefaultGrey = 128;

// Progress callback: (work done, work total); total 0 when unknown.
using ProgressFn = std::function<void(std::uint64_t done, std::uint64_t total)>;

struct ReadOptions {
  // Meshes (OFF, PLY with faces) are sampled to this many surface points.
  std::size_t meshSamplePoints = 1'000'000;
  std::uint64_t seed = 1;
  // Drop NaN/Inf points with a warning instead of refusing the file.
  bool dropNonFinite = false;
  ProgressFn progress;
  // Streaming (the out-of-core preprocess): when set, point readers hand the
  // points over in blocks of about sinkBlock and keep none, so the returned
  // cloud has no splats, only its flags. Meshes (sampled) still return theirs.
  std::function<void(std::span<const Splat>)> sink;
  std::size_t sinkBlock = std::size_t{1} << 18;
};

}  // namespace pointillist::preprocess
