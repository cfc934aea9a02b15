#include "display/frame_stats.hpp"

#include <algorithm>
#include <cstdio>
#include <fstream>
#include <sstream>

#include "common/errors.hpp"

namespace pointillist::display {
namespace {

std::string number(double value) {
  char text[64];
  std::snprintf(text, sizeof text, "%.9g", value);
  return text;
}

// Frames after the first few are "steady state" (caches warm).
std::size_t steadyStart(std::size_t frames) {
  return frames > 4 ? std::min<std::size_t>(3, frames / 4) : 0;
}

}  // namespace

double RunStats::framesPerSecond(std::size_t first) const {
  if (frames.size() <= first) return 0.0;
  const double start = first == 0 ? 0.0 : frames[first - 1].endSeconds;
  const double span = frames.back().endSeconds - start;
  return span > 0.0 ? static_cast<double>(frames.size() - first) / span : 0.0;
}

std::string RunStats::toJson() const {
  std::ostringstream out;
  out << "{\n  \"layout\": \"" << layout << "\",\n  \"dataset\": \"" << dataset
      << "\",\n  \"camera_path\": \"" << cameraPath << "\",\n  \"width\": " << width
      << ",\n  \"height\": " << height << ",\n  \"mode\": \"" << mode
      << "\",\n  \"total_seconds\": " << number(totalSeconds)
      << ",\n  \"late_tiles\": " << lateTiles << ",\n  \"frames\": [\n";
  for (std::size_t i = 0; i < frames.size(); ++i) {
    const FrameRecord& f = frames[i];
    out << "    {\"frame\": " << f.frame << ", \"start\": " << number(f.startSeconds)
        << ", \"end\": " << number(f.endSeconds)
        << ", \"seconds\": " << number(f.endSeconds - f.startSeconds)
        << ", \"splats\": " << f.splats << ", \"tiles\": " << f.tiles
        << ", \"reissued_tiles\": " << f.reissuedTiles << ", \"failed_tiles\": " << f.failedTiles
        << ", \"bytes_sent\": " << f.bytesOrdered << ", \"splats_per_render\": {";
    bool first = true;
    for (const auto& [rank, splats] : f.splatsPerRender) {
      out << (first ? "" : ", ") << '"' << rank << "\": " << splats;
      first = false;
    }
    out << "}, \"busy_seconds_per_render\": {";
    first = true;
    for (const auto& [rank, busy] : f.busySecondsPerRender) {
      out << (first ? "" : ", ") << '"' << rank << "\": " << number(busy);
      first = false;
    }
    out << "}}" << (i + 1 < frames.size() ? "," : "") << "\n";
  }
  out << "  ],\n  \"renders\": {\n";
  std::size_t index = 0;
  for (const auto& [rank, samples] : renders) {
    out << "    \"" << rank << "\": [";
    for (std::size_t i = 0; i < samples.size(); ++i) {
      const RenderSample& s = samples[i];
      out << (i ? ", " : "") << "{\"t\": " << number(s.seconds) << ", \"frame\": " << s.frame
          << ", \"workload\": " << s.workloadSplats << ", \"cache_bytes\": " << s.cacheBytes
          << ", \"peak_cache_bytes\": " << s.peakCacheBytes << ", \"hits\": " << s.cacheHits
          << ", \"misses\": " << s.cacheMisses << ", \"evictions\": " << s.evictions
          << ", \"data_bytes\": " << s.dataBytesReceived << "}";
    }
    out << "]" << (++index < renders.size() ? "," : "") << "\n";
  }
  out << "  }\n}\n";
  return out.str();
}

void RunStats::writeJson(const std::filesystem::path& file) const {
  const auto temporary = std::filesystem::path(file.string() + ".tmp");
  {
    std::ofstream out(temporary);
    out << toJson();
    if (!out) throw Error(file.string() + ": cannot write statistics");
  }
  std::filesystem::rename(temporary, file);
}

std::string RunStats::summary() const {
  std::ostringstream out;
  char line[512];
  const std::size_t steady = steadyStart(frames.size());
  std::uint64_t splats = 0, bytes = 0, steadyBytes = 0;
  std::map<int, std::uint64_t> splatsPerRender;
  std::map<int, double> busyPerRender;
  double imbalanceBusy = 0.0, imbalanceSplats = 0.0;
  std::size_t imbalanceFrames = 0;
  for (std::size_t i = 0; i < frames.size(); ++i) {
    const FrameRecord& f = frames[i];
    splats += f.splats;
    bytes += f.bytesOrdered;
    if (i >= steady) steadyBytes += f.bytesOrdered;
    for (const auto& [rank, s] : f.splatsPerRender) splatsPerRender[rank] += s;
    for (const auto& [rank, b] : f.busySecondsPerRender) busyPerRender[rank] += b;
    if (i >= steady && !f.busySecondsPerRender.empty()) {
      double maxBusy = 0.0, sumBusy = 0.0, maxSplats = 0.0, sumSplats = 0.0;
      const auto count = static_cast<double>(renders.size());
      for (const auto& [rank, b] : f.busySecondsPerRender) {
        maxBusy = std::max(maxBusy, b);
        sumBusy += b;
      }
      for (const auto& [rank, s] : f.splatsPerRender) {
        maxSplats = std::max(maxSplats, static_cast<double>(s));
        sumSplats += static_cast<double>(s);
      }
      if (sumBusy > 0.0) imbalanceBusy += maxBusy / (sumBusy / count);
      if (sumSplats > 0.0) imbalanceSplats += maxSplats / (sumSplats / count);
      ++imbalanceFrames;
    }
  }
  std::snprintf(
      line, sizeof line,
      "frames: %zu in %.2f s: %.2f frames/s overall, %.2f frames/s steady (from frame %zu)\n",
      frames.size(), totalSeconds, framesPerSecond(0), framesPerSecond(steady), steady);
  out << line;
  std::snprintf(
      line, sizeof line, "splats: %.2f M per frame, %.2f M splats/s overall\n",
      frames.empty() ? 0.0 : static_cast<double>(splats) / 1e6 / static_cast<double>(frames.size()),
      totalSeconds > 0.0 ? static_cast<double>(splats) / 1e6 / totalSeconds : 0.0);
  out << line;
  for (const auto& [rank, s] : splatsPerRender) {
    const double busy = busyPerRender[rank];
    std::snprintf(line, sizeof line,
                  "  render rank %d: %.2f M splats, %.2f M splats/s of wall time, %.2f M splats/s "
                  "while busy (%.0f%% busy)\n",
                  rank, static_cast<double>(s) / 1e6,
                  totalSeconds > 0.0 ? static_cast<double>(s) / 1e6 / totalSeconds : 0.0,
                  busy > 0.0 ? static_cast<double>(s) / 1e6 / busy : 0.0,
                  totalSeconds > 0.0 ? 100.0 * busy / totalSeconds : 0.0);
    out << line;
  }
  if (imbalanceFrames > 0) {
    std::snprintf(line, sizeof line,
                  "imbalance (steady, max/mean per frame): busy time %.2f, splats %.2f\n",
                  imbalanceBusy / static_cast<double>(imbalanceFrames),
                  imbalanceSplats / static_cast<double>(imbalanceFrames));
    out << line;
  }
  const std::size_t steadyFrames = frames.size() - std::min(frames.size(), steady);
  std::snprintf(line, sizeof line,
                "bytes sent: %.2f MiB total, first frame %.2f MiB, %.3f MiB per frame steady\n",
                static_cast<double>(bytes) / 1048576.0,
                frames.empty() ? 0.0 : static_cast<double>(frames.front().bytesOrdered) / 1048576.0,
                steadyFrames ? static_cast<double>(steadyBytes) / 1048576.0 /
                                   static_cast<double>(steadyFrames)
                             : 0.0);
  out << line;
  std::uint64_t hits = 0, misses = 0, evictions = 0, peak = 0;
  for (const auto& [rank, samples] : renders) {
    if (samples.empty()) continue;
    hits += samples.back().cacheHits;
    misses += samples.back().cacheMisses;
    evictions += samples.back().evictions;
    peak = std::max(peak, samples.back().peakCacheBytes);
  }
  std::snprintf(
      line, sizeof line,
      "cache: hit rate %.1f%% (%llu hits, %llu misses), %llu evictions, peak %.2f MiB on "
      "one render\n",
      hits + misses ? 100.0 * static_cast<double>(hits) / static_cast<double>(hits + misses) : 0.0,
      static_cast<unsigned long long>(hits), static_cast<unsigned long long>(misses),
      static_cast<unsigned long long>(evictions), static_cast<double>(peak) / 1048576.0);
  out << line;
  return out.str();
}

}  // namespace pointillist::display
