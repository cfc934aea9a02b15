#pragma once
// Model rates taken from a measured run: a deploy/bench-loadbalance.sh output
// directory (one subdirectory per scheduler) or one of its run directories
// (the display's stats.json and CSV files, see display/frame_stats.cpp).
#include <cstdint>
#include <filesystem>
#include <optional>
#include <span>
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

// One packet as a render process drew it (a line of the display's tiles.csv).
struct PacketSample {
  double seconds = 0.0;  // render_seconds
  double splats = 0.0;
  double pixels = 0.0;  // of the tile's (or part's) rect
};

// A render packet's time as the simulator models it:
//   seconds = T_p + T_px * pixels + T_s * splats
struct PacketTimeFit {
  double secondsPerPacket = 0.0;  // T_p
  double secondsPerPixel = 0.0;   // T_px
  double secondsPerSplat = 0.0;   // T_s
  std::size_t samples = 0;
  double rSquared = 0.0;  // share of the variance of the packets' times explained
};

// Least squares over the samples. A coefficient the data would make negative
// (noise, or too little spread in that column) is dropped and the others
// refitted, so the model never credits time for more work. Throws InputError
// when no packet drew a splat or no fit gives splats a positive time.
PacketTimeFit fitPacketTimes(std::span<const PacketSample> samples);

struct Calibration {
  // T_s: busy seconds of all render processes, less the per-packet overhead
  // for every tile, per splat drawn. With the runs' tiles.csv files: fitted,
  // with T_p and T_px, from every packet drawn (`fit`).
  double secondsPerSplat = 0.0;
  std::optional<PacketTimeFit> fit;
  std::vector<MeasuredRun> runs;
};

// Throws InputError naming the directory or file when no run is found or a
// CSV file lacks a column the calibration needs. Without tiles.csv files the
// per-packet overhead is `packetOverheadSeconds` (a guess taken off the busy time).
Calibration calibrateFromRuns(const std::filesystem::path& directory, double packetOverheadSeconds);

}  // namespace pointillist::simulator
