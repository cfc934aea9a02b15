// pointillist-simulate: predicts frame rate, imbalance, bytes moved and the
// bottleneck of Pointillist jobs of many sizes by driving the real scheduling
// code with modelled processes in simulated time (no MPI, no rendering).
#include <CLI/CLI.hpp>

#include "common/tool_entry.hpp"

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <thread>

#include "common/dataset.hpp"
#include "common/errors.hpp"
#include "common/image_compression.hpp"
#include "common/run_settings.hpp"
#include "simulator/calibration.hpp"
#include "simulator/replay.hpp"
#include "simulator/sweep.hpp"

namespace pointillist::simulator {
namespace {

std::vector<std::uint32_t> parseCounts(const std::string& option,
                                       const std::vector<std::string>& texts, bool allowAuto) {
  std::vector<std::uint32_t> counts;
  for (const std::string& text : texts) {
    if (allowAuto && text == "auto") {
      counts.push_back(0);
      continue;
    }
    std::size_t used = 0;
    unsigned long value = 0;
    try {
      value = std::stoul(text, &used);
    } catch (const std::exception&) {
      used = 0;
    }
    if (used != text.size() || text.empty() || text[0] == '-' || value == 0 || value > 1u << 20) {
      throw UsageError(option + " '" + text + "' is not a count from 1 to 1048576" +
                       (allowAuto ? " or 'auto'" : ""));
    }
    counts.push_back(static_cast<std::uint32_t>(value));
  }
  if (counts.empty()) throw UsageError(option + " needs at least one value");
  return counts;
}

void writeText(const std::string& file, const std::string& text, const char* what) {
  const auto folder = std::filesystem::path(file).parent_path();
  if (!folder.empty()) std::filesystem::create_directories(folder);
  std::ofstream out(file);
  out << text;
  if (!out) throw Error(file + ": cannot write the " + what);
}

// Returns 0 when every logged decision comes out the same, 1 otherwise.
int replay(const std::string& datasetPath, const std::vector<std::string>& logs) {
  const Dataset dataset = Dataset::open(datasetPath, DatasetParts::Cells);
  bool same = true;
  for (const std::string& file : logs) {
    const traverse::DecisionLog log = traverse::readDecisionLog(file);
    const ReplayResult result = replayDecisions(log, dataset.cells(), dataset.topLevelCells());
    std::printf("%s: %zu tiles and %zu reports replayed; %zu of %zu tiles decided identically\n",
                file.c_str(), result.tasks, result.reports, result.identical, result.tasks);
    for (std::size_t i = 0; i < result.mismatches.size() && i < 5; ++i) {
      std::printf("  decision %zu differs: %s\n", result.mismatches[i].decision,
                  result.mismatches[i].difference.c_str());
    }
    same = same && result.mismatches.empty() && result.tasks > 0;
  }
  std::printf("replay: %s\n", same ? "every decision identical" : "DIFFERENT decisions");
  return same ? 0 : 1;
}

int run(int argc, char** argv) {
  CLI::App app{
      "Pointillist scheduler simulator: drives the roles' own cores (the display's frame "
      "assembly, the traverse's packet planner, the data-send's ledger and the render's core) "
      "with modelled time and network, for many job sizes; or replays a real job's traverse "
      "decisions (--replay)"};
  std::string datasetPath;
  ViewOptions view;
  view.frames = 16;
  std::vector<std::string> renders{"8", "16", "32", "64", "128", "256", "512", "1024"};
  std::vector<std::string> traverses{"1", "2", "4", "8"};
  std::vector<std::string> datasends{"auto"};
  std::vector<std::string> schedulers{"cost", "round-robin", "static", "equalizer"};
  std::vector<std::string> costModels{costModelName(kDefaultCostModel)};
  bool equalTiles = false;
  SweepOptions sweep;
  ModelParameters& p = sweep.parameters;
  double secondsPerSplat = 0.0;
  double packetOverheadMs = p.packetOverheadSeconds * 1e3;
  double packetNsPerPixel = p.packetSecondsPerPixel * 1e9;
  double bandwidthMBs = p.bandwidthBytesPerSecond / 1e6;
  double displayBandwidthMBs = 0.0;
  double latencyUs = p.latencySeconds * 1e6;
  double traverseSecondsPerCell = 0.0;
  double traverseTileUs = p.traverseTileSeconds * 1e6;
  double composeNsPerPixel = p.composeSecondsPerPixel * 1e9;
  std::string calibrateDir, csvFile, reportFile, statsDir;
  std::vector<std::string> reportPlots;
  unsigned jobs = std::max(1u, std::thread::hardware_concurrency());
  bool quiet = false;

  app.add_option("--dataset", datasetPath, "Dataset directory (pointillist-preprocess)")
      ->required();
  addViewOptions(app, view);
  app.add_option("--renders", renders, "Render process counts, comma-separated")->delimiter(',');
  app.add_option("--traverses", traverses, "Traverse process counts")->delimiter(',');
  app.add_option("--datasends", datasends, "Data-send process counts, or auto (renders/4)")
      ->delimiter(',');
  app.add_option("--scheduler", schedulers, "cost, regions, round-robin, static, equalizer")
      ->delimiter(',');
  app.add_option("--cost-model", costModels,
                 "Cost scheduler: paper (seed 003, runtime default), overlap, or both")
      ->delimiter(',');
  app.add_option("--prefetch-frames", sweep.prefetchFrames,
                 "Cost scheduler: order what each tile's rect needs this many frames on (0: off)")
      ->capture_default_str();
  app.add_flag("--equal-tiles", equalTiles,
               "Cost scheduler: equal tiles instead of tiles sized by last frame's work");
  app.add_option("--tiles-per-render", sweep.tilesPerRender,
                 "Tiles per frame per render process (not given: the cost scheduler's display "
                 "divides it by a factor it tunes on the frame rate, as the job does; given: "
                 "as given)")
      ->capture_default_str();
  app.add_option("--min-tile", sweep.minTileSize, "Smallest tile side in pixels")
      ->capture_default_str();
  auto* splatOption = app.add_option(
      "--seconds-per-splat", secondsPerSplat,
      "T_s, render seconds per splat (default: the CPU point kernel as measured here; OSMesa "
      "points were about 2e-7)");
  auto* packetOption =
      app.add_option("--packet-overhead-ms", packetOverheadMs,
                     "T_p, render time per packet besides pixels and splats (OSMesa: about 1)")
          ->capture_default_str();
  auto* pixelOption = app.add_option("--packet-ns-per-pixel", packetNsPerPixel,
                                     "T_px, render time per pixel of a packet's rect (clearing, "
                                     "read-back, sending)")
                          ->capture_default_str();
  app.add_option("--bandwidth-mbs", bandwidthMBs, "Link bandwidth in MB/s (117: 1 GbE)")
      ->capture_default_str();
  app.add_option("--display-bandwidth-mbs", displayBandwidthMBs,
                 "The display's link in MB/s, where tile images come in (1170: 10 GbE; 0: as "
                 "--bandwidth-mbs)")
      ->capture_default_str();
  std::string tileTasksAhead = "auto";
  app.add_option("--tile-tasks-ahead", tileTasksAhead,
                 "Tile requests each traverse process keeps at the display (1: one at a time; "
                 "auto: " +
                     autoTileTasksAheadRule() + ")")
      ->capture_default_str();
  std::string imageCompression = "auto";
  int imageCompressionLevel = kDefaultImageCompressionLevel;
  double compressNsPerByte = p.compressSecondsPerByte * 1e9;
  double decompressNsPerByte = p.decompressSecondsPerByte * 1e9;
  app.add_option("--image-compression", imageCompression,
                 "Tile images as zstd frames, as the job's render processes send them to a "
                 "display on another machine: auto or zstd (on; the ratio measured on each "
                 "frame the scene draws, so with --lit-pixels on), or off")
      ->check(CLI::IsMember({"auto", "zstd", "off"}))
      ->capture_default_str();
  app.add_option("--image-compression-level", imageCompressionLevel,
                 "zstd level the ratio is measured at (the job's --image-compression-level)")
      ->check(CLI::Range(-7, 19))
      ->capture_default_str();
  app.add_option("--compress-ns-per-byte", compressNsPerByte,
                 "A render's time to compress a byte of tile image")
      ->capture_default_str();
  app.add_option("--decompress-ns-per-byte", decompressNsPerByte,
                 "The display's time to expand a byte of tile image")
      ->capture_default_str();
  app.add_option("--display-image-threads", p.displayImageThreads,
                 "Threads expanding compressed tile images at the display (its --image-threads)")
      ->check(CLI::Range(1, 256))
      ->capture_default_str();
  std::string litPixels = "on";
  app.add_option("--lit-pixels", litPixels,
                 "Size tile images by the pixels each frame lights (each frame drawn once by the "
                 "CPU point kernel from the dataset's points): on, or off (a pixel a splat, "
                 "capped by the box)")
      ->check(CLI::IsMember({"on", "off"}))
      ->capture_default_str();
  std::string tileSplit = "auto";
  app.add_option("--tile-split", tileSplit,
                 "Heavy tiles split by their cells into parts drawn by several render processes "
                 "and composed by depth at the display (the display's --tile-split): auto (one "
                 "render's share of a frame times a factor the display tunes on the frame rate), "
                 "share (not tuned), off, or a part size in splats")
      ->capture_default_str();
  app.add_option("--latency-us", latencyUs, "Message latency in microseconds")
      ->capture_default_str();
  app.add_option("--traverse-seconds-per-cell", traverseSecondsPerCell,
                 "Traverse time per visited cell (default: timed on the first frames here)");
  app.add_option("--traverse-tile-us", traverseTileUs, "Traverse time per tile besides cells")
      ->capture_default_str();
  app.add_option("--compose-ns-per-pixel", composeNsPerPixel, "Display time per composed pixel")
      ->capture_default_str();
  app.add_option("--cache-mb", p.cacheMegabytes, "Render cache cap in MiB")->capture_default_str();
  app.add_option("--frames-in-flight", p.framesInFlight, "Frames the display hands out at once")
      ->capture_default_str();
  app.add_option("--tile-timeout", p.tileTimeoutSeconds, "Seconds before a tile is re-issued")
      ->capture_default_str();
  app.add_option("--max-attempts", p.maxAttempts, "Times a tile is handed out before given up")
      ->capture_default_str();
  app.add_option("--calibrate", calibrateDir,
                 "Take T_s from a deploy/bench-loadbalance.sh output (or run) directory");
  app.add_option("--csv", csvFile, "Write every figure of every configuration as CSV");
  app.add_option("--report", reportFile, "Write a markdown report (assumptions, table)");
  app.add_option("--stats", statsDir,
                 "One configuration only: write the display's stats.json and CSV files of the "
                 "simulated run (the runtime's format) into this directory");
  app.add_option("--report-plot", reportPlots, "Image file to link from the report (repeatable)");
  app.add_option("--jobs", jobs, "Configurations simulated at once")->capture_default_str();
  app.add_flag("--quiet", quiet, "No progress lines on stderr");
  std::vector<std::string> replayLogs;
  app.add_option("--replay", replayLogs,
                 "Decision logs of a real job (pointillist-traverse --decision-log): replay each "
                 "through the simulator's traverse core and report any different choice")
      ->check(CLI::ExistingFile);
  app.name("pointillist-simulate");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& error) {
    return app.exit(error);
  }

  if (!replayLogs.empty()) return replay(datasetPath, replayLogs);
  sweep.renders = parseCounts("--renders", renders, false);
  sweep.traverses = parseCounts("--traverses", traverses, false);
  sweep.datasends = parseCounts("--datasends", datasends, true);
  sweep.schedulers.clear();
  for (const std::string& name : schedulers) {
    sweep.schedulers.push_back(display::parseSchedulerKind(name));
  }
  sweep.costModels.clear();
  for (const std::string& name : costModels) {
    sweep.costModels.push_back(traverse::costModelOf(parseCostModel(name)));
  }
  sweep.balancedTiles = !equalTiles;
  {
    v1::RunSettings split;
    sweep.tileTasksAhead = parseTileTasksAhead(tileTasksAhead);
    parseTileSplit(tileSplit, split);
    sweep.tileSplit = !split.no_tile_split();
    sweep.tilePartSplats = split.tile_part_splats();
    sweep.tilePartTuned = !split.tile_part_untuned();
    sweep.tileCountTuned = app.count("--tiles-per-render") == 0;
  }
  if (jobs == 0) throw UsageError("--jobs must be at least 1");
  sweep.jobs = jobs;
  p.packetOverheadSeconds = packetOverheadMs * 1e-3;
  p.packetSecondsPerPixel = packetNsPerPixel * 1e-9;
  p.bandwidthBytesPerSecond = bandwidthMBs * 1e6;
  p.displayBandwidthBytesPerSecond = displayBandwidthMBs * 1e6;
  p.latencySeconds = latencyUs * 1e-6;
  p.traverseTileSeconds = traverseTileUs * 1e-6;
  p.composeSecondsPerPixel = composeNsPerPixel * 1e-9;
  p.compressSecondsPerByte = compressNsPerByte * 1e-9;
  p.decompressSecondsPerByte = decompressNsPerByte * 1e-9;
  p.compressImages = imageCompression != "off" && litPixels == "on";
  if (imageCompression != "off" && litPixels != "on" && app.count("--image-compression") > 0)
    throw UsageError("--image-compression " + imageCompression +
                     " measures each frame's ratio on the frames --lit-pixels on draws");
  if (secondsPerSplat < 0.0 || traverseSecondsPerCell < 0.0) {
    throw UsageError("--seconds-per-splat and --traverse-seconds-per-cell must be positive");
  }
  if (!calibrateDir.empty() &&
      (splatOption->count() > 0 || packetOption->count() > 0 || pixelOption->count() > 0)) {
    throw UsageError(
        "--calibrate measures T_s, T_p and T_px: give it or --seconds-per-splat, "
        "--packet-overhead-ms and --packet-ns-per-pixel, not both");
  }

  Assumptions sources;
  if (secondsPerSplat > 0.0) {
    p.secondsPerSplat = secondsPerSplat;
    sources.emplace_back("T_s from", "--seconds-per-splat");
  } else if (!calibrateDir.empty()) {
    const Calibration calibration = calibrateFromRuns(calibrateDir, p.packetOverheadSeconds);
    p.secondsPerSplat = calibration.secondsPerSplat;
    if (calibration.fit) {
      p.packetOverheadSeconds = calibration.fit->secondsPerPacket;
      p.packetSecondsPerPixel = calibration.fit->secondsPerPixel;
    }
    std::string runs;
    for (const MeasuredRun& run : calibration.runs) {
      char line[256];
      std::snprintf(line, sizeof line, "%s%s (%s): %.2f frames/s steady, imbalance busy %.2f",
                    runs.empty() ? "" : "; ", run.name.c_str(),
                    run.layout.empty() ? "layout unknown" : run.layout.c_str(),
                    run.framesPerSecondSteady, run.imbalanceBusy);
      runs += line;
    }
    if (calibration.fit) {
      char fit[160];
      std::snprintf(fit, sizeof fit, "%zu packets (tiles.csv), R^2 %.3f", calibration.fit->samples,
                    calibration.fit->rSquared);
      sources.emplace_back("T_s, T_p and T_px fitted from",
                           calibrateDir + ": least squares of render seconds over " + fit);
    } else {
      sources.emplace_back("T_s from", calibrateDir + ": render busy seconds per splat");
    }
    sources.emplace_back("measured there", runs);
  } else {
    sources.emplace_back("T_s from",
                         "default (the CPU point kernel on the 2-core development machine)");
  }
  validateParameters(p);

  // Bad sweeps fail before the dataset is read.
  const auto configs = sweepConfigs(sweep);
  if (!statsDir.empty() && configs.size() != 1) {
    throw UsageError("--stats needs exactly one configuration; this sweep has " +
                     std::to_string(configs.size()));
  }
  const Scene scene = Scene::load(datasetPath, view, litPixels == "on", jobs,
                                  p.compressImages ? imageCompressionLevel : 0);
  if (traverseSecondsPerCell > 0.0) {
    p.traverseSecondsPerCell = traverseSecondsPerCell;
    sources.emplace_back("traverse time from", "--traverse-seconds-per-cell");
  } else {
    p.traverseSecondsPerCell = scene.measureTraverseSecondsPerCell();
    sources.emplace_back("traverse time from", "timing whole-frame traversals on this machine");
  }
  const Assumptions assumptions = describeAssumptions(scene, view, sweep, sources);

  if (!quiet) {
    std::fprintf(stderr, "pointillist-simulate: %zu configurations on %u threads\n", configs.size(),
                 std::min<unsigned>(jobs, static_cast<unsigned>(configs.size())));
  }
  std::vector<SweepRow> rows;
  if (!statsDir.empty()) {
    const auto start = std::chrono::steady_clock::now();
    const SimulationResult result = simulate(scene, configs.front(), p);
    rows.push_back(summarize(
        result, std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count()));
    std::filesystem::create_directories(statsDir);
    result.stats.writeJson(std::filesystem::path(statsDir) / "stats.json");
    result.stats.writeCsv(statsDir);
  } else {
    rows = runSweep(scene, sweep, [&](std::size_t done, std::size_t total, const SweepRow& row) {
      if (quiet) return;
      std::fprintf(stderr,
                   "pointillist-simulate: [%zu/%zu] %-11s R=%-4u T=%-2u S=%-3u %7.2f frames/s "
                   "steady, imbalance %.2f, %s (%.1f s; tile layout %.2f ms a frame here)\n",
                   done, total, configName(row.config).c_str(), row.config.renders,
                   row.config.traverses, row.config.datasends, row.framesPerSecondSteady,
                   row.imbalanceBusy, row.bottleneck.c_str(), row.wallSeconds, row.planMsPerFrame);
      std::fflush(stderr);
    });
  }

  std::printf("Assumptions (simulated, not measured):\n%s\n%s\n%s",
              formatAssumptions(assumptions).c_str(), formatTable(rows).c_str(),
              formatRecommendations(recommendLayouts(rows)).c_str());
  if (!csvFile.empty()) writeText(csvFile, formatCsv(rows), "CSV figures");
  if (!reportFile.empty()) {
    writeText(reportFile, formatReport(rows, assumptions, reportPlots), "report");
  }
  return 0;
}

}  // namespace
}  // namespace pointillist::simulator

int main(int argc, char** argv) {
  return pointillist::runToolMain("pointillist-simulate",
                                  [&] { return pointillist::simulator::run(argc, argv); });
}
