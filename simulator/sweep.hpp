#pragma once
// A sweep of simulated jobs over render, traverse and data-send counts and
// schedulers, and its outputs: an aligned table, CSV and a markdown report,
// each with the model's assumptions beside the figures.
#include <cstdint>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "common/run_settings.hpp"
#include "simulator/simulation.hpp"

namespace pointillist::simulator {

struct SweepOptions {
  std::vector<std::uint32_t> renders{8, 16, 32, 64, 128, 256, 512, 1024};
  std::vector<std::uint32_t> traverses{1, 2, 4, 8};
  std::vector<std::uint32_t> datasends{0};  // 0: autoDatasends(renders)
  std::vector<display::SchedulerKind> schedulers{
      display::SchedulerKind::Cost, display::SchedulerKind::RoundRobin,
      display::SchedulerKind::Static, display::SchedulerKind::Equalizer};
  // Cost rows are repeated for each cost model (paper is the runtime default).
  std::vector<traverse::CostModel> costModels{traverse::costModelOf(kDefaultCostModel)};
  bool balancedTiles = true;         // cost scheduler: tiles sized by last frame's work
  std::uint32_t prefetchFrames = 0;  // cost scheduler: order data this many frames ahead
  double tilesPerRender = 2.0;
  std::uint32_t minTileSize = 32;
  std::uint32_t tileTasksAhead = 0;  // 0: auto
  // Heavy tiles split by their data (--tile-split): off, or the part size
  // in splats (0: the display's choice per frame).
  bool tileSplit = true;
  std::uint64_t tilePartSplats = 0;
  bool tilePartTuned = true;   // the display's part size tuned (--tile-split auto, not share)
  bool tileCountTuned = true;  // the display's tile count tuned (no --tiles-per-render)
  ModelParameters parameters;
  unsigned jobs = 1;  // configurations simulated at once
};

// One data-send process per four render processes (at least one).
std::uint32_t autoDatasends(std::uint32_t renders);

// Every configuration of the sweep: traverses, then renders, then data-sends,
// then schedulers (cost once per cost model) vary, the last fastest. Throws UsageError for empty
// lists or invalid counts.
std::vector<SimulationConfig> sweepConfigs(const SweepOptions& options);

// The figures of one configuration (rates per simulated second).
struct SweepRow {
  SimulationConfig config;
  double framesPerSecond = 0.0;
  double framesPerSecondSteady = 0.0;
  double meanFrameLatency = 0.0;
  double imbalanceBusy = 0.0;
  double imbalanceSplats = 0.0;
  double imbalanceBusyRun = 0.0;  // max/mean of busy time summed over the steady frames
  double bytesFirstFrame = 0.0;
  double bytesPerFrameSteady = 0.0;
  double imageBytesPerFrameSteady = 0.0;              // tile images into the display
  double imageBytesUncompressedPerFrameSteady = 0.0;  // what they expand to
  std::uint64_t partSizeFactor = 0;                   // the display's last; 0: not tuned
  double tilesPerRenderTuned = 0.0;                   // the display's last; 0: not tuned
  double planMsPerFrame = 0.0;  // the display's tile layout, wall time here (not simulated)
  // With --loops above 1: the loops after the first (the tuners settled,
  // the caches warm); 0 with one loop.
  double framesPerSecondLaterLoops = 0.0;
  double imbalanceBusyLaterLoops = 0.0;
  double splatsPerFrame = 0.0;
  double tilesPerFrame = 0.0;
  double cacheHitRate = 0.0;
  double cacheHitRateSteady = 0.0;
  Utilisation utilisation;
  std::string bottleneck;
  double bottleneckUtilisation = 0.0;
  std::uint64_t reissuedTiles = 0;
  std::uint64_t failedTiles = 0;
  std::uint64_t packetsRendered = 0;
  std::uint64_t events = 0;
  double wallSeconds = 0.0;  // real time the simulation took
};

SweepRow summarize(const SimulationResult& result, double wallSeconds);

// (rows done, rows in all, the row just done); called from one thread at a time.
using SweepProgress = std::function<void(std::size_t, std::size_t, const SweepRow&)>;

// Rows in sweepConfigs() order, simulated on options.jobs threads.
std::vector<SweepRow> runSweep(const Scene& scene, const SweepOptions& options,
                               const SweepProgress& progress = {});

using Assumptions = std::vector<std::pair<std::string, std::string>>;

// The model's inputs as named lines: the scene, the view, every parameter and
// the sweep; `extra` lines (where figures came from) are appended.
Assumptions describeAssumptions(const Scene& scene, const ViewOptions& view,
                                const SweepOptions& options, const Assumptions& extra = {});

// The printed table: one line per row, columns aligned.
std::string formatTable(const std::vector<SweepRow>& rows);
// Per scheduler and render count: the smallest layout (traverses, then
// data-sends) within 5 % of the best frame rate swept for it, what then
// limits the job, and a word when more processes of a kind would help:
// the traverse processes or the display are named when they are the bottleneck.
struct LayoutRecommendation {
  std::string scheduler;
  std::uint32_t renders = 0;
  std::uint32_t traverses = 0;
  std::uint32_t datasends = 0;
  double framesPerSecond = 0.0;
  std::string bottleneck;
  double bottleneckUtilisation = 0.0;
  std::string advice;
};
std::vector<LayoutRecommendation> recommendLayouts(const std::vector<SweepRow>& rows);
std::string formatRecommendations(const std::vector<LayoutRecommendation>& recommendations);

// Assumptions as "name: value" lines.
std::string formatAssumptions(const Assumptions& assumptions);
// Header plus one line per row, raw units (seconds, bytes, shares 0..1).
std::string formatCsv(const std::vector<SweepRow>& rows);
// Markdown: assumptions, the table, notes on reading it, and `plots` (file names).
std::string formatReport(const std::vector<SweepRow>& rows, const Assumptions& assumptions,
                         const std::vector<std::string>& plots = {});

}  // namespace pointillist::simulator
