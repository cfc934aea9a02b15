#pragma once
// Per-frame and per-render-process statistics of a run, printed and written as
// JSON for benchmarks (deploy/bench-*.sh read it).
#include <cstdint>
#include <filesystem>
#include <map>
#include <string>
#include <vector>

namespace pointillist::display {

struct FrameRecord {
  std::uint64_t frame = 0;
  double startSeconds = 0.0;  // since the run began
  double endSeconds = 0.0;
  std::uint64_t splats = 0;
  std::uint32_t tiles = 0;
  std::uint32_t reissuedTiles = 0;
  std::uint32_t failedTiles = 0;
  std::uint64_t bytesOrdered = 0;  // top-level cell data sent to render processes
  std::map<int, std::uint64_t> splatsPerRender;
  std::map<int, double> busySecondsPerRender;
};

struct RenderSample {
  double seconds = 0.0;  // since the run began
  std::uint64_t frame = 0;
  std::uint64_t workloadSplats = 0;
  std::uint64_t cacheBytes = 0;
  std::uint64_t peakCacheBytes = 0;
  std::uint64_t cacheHits = 0;
  std::uint64_t cacheMisses = 0;
  std::uint64_t evictions = 0;
  std::uint64_t dataBytesReceived = 0;
};

struct RunStats {
  std::string layout;
  std::string dataset;
  std::string cameraPath;
  std::uint32_t width = 0;
  std::uint32_t height = 0;
  std::string mode;
  std::vector<FrameRecord> frames;
  std::map<int, std::vector<RenderSample>> renders;  // by world rank
  std::uint64_t lateTiles = 0;  // arrived after their frame was done or re-issued
  double totalSeconds = 0.0;

  // Frames per second over frames [first, end).
  double framesPerSecond(std::size_t first) const;
  std::string toJson() const;
  void writeJson(const std::filesystem::path& file) const;
  // Human summary: frame rate (all and steady state), splats/s per render,
  // imbalance, bytes per frame, cache hit rate.
  std::string summary() const;
};

}  // namespace pointillist::display
