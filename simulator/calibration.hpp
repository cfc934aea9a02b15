#pragma once
// Model rates taken from a measured run: a deploy/bench-loadbalance.sh output
// directory (one subdirectory per scheduler) or one of its run directories
// (the display's stats.json and CSV files, see display/frame_stats.cpp).
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

namespace pointillist::simulator {

struct MeasuredRun {
  std::string name;    // the run directory's name (the scheduler in a benchmark)
  std::string layout;  // from stats.json, empty when unknown
  std::uint64_t splats = 0;
  double busySeconds = 0.0;
  std::uint64_t tiles = 0;
  double framesPerSecondSteady = 0.0;
  double imbalanceBusy = 0.0;
};

struct Calibration {
  // T_s: busy seconds of all render processes, less the per-packet overhead
  // for every tile, per splat drawn.
  double secondsPerSplat = 0.0;
  std::vector<MeasuredRun> runs;
};

// Throws InputError naming the directory or file when no run is found or a
// CSV file lacks a column the calibration needs.
Calibration calibrateFromRuns(const std::filesystem::path& directory, double packetOverheadSeconds);

}  // namespace pointillist::simulator
