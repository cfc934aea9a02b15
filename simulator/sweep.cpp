#include "simulator/sweep.hpp"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <exception>
#include <map>
#include <mutex>
#include <numeric>
#include <sstream>
#include <thread>

#include "common/errors.hpp"

namespace pointillist::simulator {
namespace {

// value with `decimals` digits after the point ("%.*f").
std::string fixed(double value, int decimals) {
  char text[64];
  std::snprintf(text, sizeof text, "%.*f", decimals, value);
  return text;
}

// value with `digits` significant digits ("%.*g").
std::string significant(double value, int digits = 6) {
  char text[64];
  std::snprintf(text, sizeof text, "%.*g", digits, value);
  return text;
}

std::string number(double value) {
  return significant(value, 9);
}

std::string mib(double bytes) {
  return fixed(bytes / 1048576.0, 2);
}

std::string percent(double share) {
  return fixed(100.0 * share, 0) + "%";
}

std::string joinCounts(const std::vector<std::uint32_t>& values) {
  std::string text;
  for (std::uint32_t value : values) {
    text += (text.empty() ? "" : ",") + (value == 0 ? std::string("auto") : std::to_string(value));
  }
  return text;
}

struct Column {
  const char* head;
  bool left;  // text columns are left-aligned, figures right-aligned
};

const Column kColumns[] = {
    {"scheduler", true},
    {"R", false},
    {"T", false},
    {"S", false},
    {"tiles/frame", false},
    {"frames/s steady", false},
    {"later loops", false},
    {"latency ms", false},
    {"imb busy", false},
    {"imb splats", false},
    {"imb run", false},
    {"MiB first", false},
    {"MiB/frame steady", false},
    {"M splats/frame", false},
    {"hits steady", false},
    {"render util", false},
    {"traverse util", false},
    {"tiles/R", false},
    {"parts", false},
    {"bottleneck", true},
};

std::vector<std::string> tableCells(const SweepRow& row) {
  return {configName(row.config),
          std::to_string(row.config.renders),
          std::to_string(row.config.traverses),
          std::to_string(row.config.datasends),
          fixed(row.tilesPerFrame, 0),
          fixed(row.framesPerSecondSteady, 2),
          row.framesPerSecondLaterLoops > 0.0 ? fixed(row.framesPerSecondLaterLoops, 2) : "-",
          fixed(row.meanFrameLatency * 1e3, 1),
          fixed(row.imbalanceBusy, 2),
          fixed(row.imbalanceSplats, 2),
          fixed(row.imbalanceBusyRun, 2),
          mib(row.bytesFirstFrame),
          mib(row.bytesPerFrameSteady),
          fixed(row.splatsPerFrame / 1e6, 2),
          fixed(100.0 * row.cacheHitRateSteady, 1) + "%",
          percent(row.utilisation.renderMean) + "/" + percent(row.utilisation.renderMax),
          percent(row.utilisation.traverseMean),
          row.tilesPerRenderTuned > 0.0 ? significant(row.tilesPerRenderTuned) : "-",
          row.partSizeFactor > 0 ? "x" + std::to_string(row.partSizeFactor) : "-",
          row.bottleneck + " " + percent(row.bottleneckUtilisation)};
}

// Rows of cells as aligned text; markdown adds pipes and the alignment line.
std::string alignedTable(const std::vector<SweepRow>& rows, bool markdown) {
  constexpr std::size_t count = std::size(kColumns);
  std::vector<std::vector<std::string>> cells;
  cells.emplace_back();
  for (const Column& column : kColumns) cells.back().emplace_back(column.head);
  for (const SweepRow& row : rows) cells.push_back(tableCells(row));
  std::vector<std::size_t> widths(count, 0);
  for (const auto& line : cells) {
    for (std::size_t j = 0; j < count; ++j) widths[j] = std::max(widths[j], line[j].size());
  }
  std::ostringstream out;
  for (std::size_t i = 0; i < cells.size(); ++i) {
    std::string line = markdown ? "|" : "";
    for (std::size_t j = 0; j < count; ++j) {
      const std::string& text = cells[i][j];
      const std::string pad(widths[j] - text.size(), ' ');
      line += (markdown || j == 0 ? " " : "  ");
      line += kColumns[j].left ? text + pad : pad + text;
      if (markdown) line += " |";
    }
    line.erase(line.find_last_not_of(' ') + 1);
    out << line << '\n';
    if (markdown && i == 0) {
      out << '|';
      for (std::size_t j = 0; j < count; ++j) {
        out << '-' << std::string(widths[j], '-') << (kColumns[j].left ? "-|" : ":|");
      }
      out << '\n';
    }
  }
  return out.str();
}

}  // namespace

std::uint32_t autoDatasends(std::uint32_t renders) {
  return std::max<std::uint32_t>(1, renders / 4);
}

std::vector<SimulationConfig> sweepConfigs(const SweepOptions& options) {
  if (options.renders.empty()) throw UsageError("--renders needs at least one count");
  if (options.traverses.empty()) throw UsageError("--traverses needs at least one count");
  if (options.datasends.empty()) throw UsageError("--datasends needs at least one count");
  if (options.schedulers.empty()) throw UsageError("--scheduler needs at least one name");
  if (options.costModels.empty()) throw UsageError("--cost-model needs at least one name");
  std::vector<SimulationConfig> configs;
  for (std::uint32_t traverses : options.traverses) {
    for (std::uint32_t renders : options.renders) {
      for (std::uint32_t datasends : options.datasends) {
        for (display::SchedulerKind scheduler : options.schedulers) {
          SimulationConfig config;
          config.scheduler = scheduler;
          config.renders = renders;
          config.traverses = traverses;
          config.datasends = datasends == 0 ? autoDatasends(renders) : datasends;
          config.tilesPerRender = options.tilesPerRender;
          config.minTileSize = options.minTileSize;
          config.balancedTiles = options.balancedTiles;
          config.prefetchFrames = options.prefetchFrames;
          config.tileTasksAhead = options.tileTasksAhead;
          config.tileSplit = options.tileSplit;
          config.tilePartSplats = options.tilePartSplats;
          config.tilePartTuned = options.tilePartTuned;
          config.tileCountTuned = options.tileCountTuned;
          validateConfig(config);
          if (scheduler != display::SchedulerKind::Cost) {
            configs.push_back(config);
            continue;
          }
          for (traverse::CostModel model : options.costModels) {
            config.costModel = model;
            configs.push_back(config);
          }
        }
      }
    }
  }
  return configs;
}

SweepRow summarize(const SimulationResult& result, double wallSeconds) {
  const display::KeyFigures& k = result.figures;
  SweepRow row;
  row.config = result.config;
  row.framesPerSecond = k.framesPerSecond;
  row.framesPerSecondSteady = k.framesPerSecondSteady;
  row.meanFrameLatency = result.meanFrameLatency;
  row.imbalanceBusy = k.imbalanceBusy;
  row.imbalanceSplats = k.imbalanceSplats;
  row.imbalanceBusyRun = k.imbalanceBusyRun;
  row.bytesFirstFrame = static_cast<double>(k.bytesFirstFrame);
  row.bytesPerFrameSteady = k.bytesPerFrameSteady;
  row.imageBytesPerFrameSteady = k.imageBytesPerFrameSteady;
  row.imageBytesUncompressedPerFrameSteady = k.imageBytesUncompressedPerFrameSteady;
  row.partSizeFactor = k.partSizeFactor;
  row.tilesPerRenderTuned = k.tilesPerRenderTuned;
  row.planMsPerFrame = result.planMsPerFrame;
  row.framesPerSecondLaterLoops = k.framesPerSecondLaterLoops;
  row.imbalanceBusyLaterLoops = k.imbalanceBusyLaterLoops;
  row.splatsPerFrame = k.splatsPerFrame;
  row.tilesPerFrame = result.tilesPerFrame;
  row.cacheHitRate = k.cacheHitRate;
  row.cacheHitRateSteady = k.cacheHitRateSteady;
  row.utilisation = result.utilisation;
  row.bottleneck = result.bottleneck;
  row.bottleneckUtilisation = result.bottleneckUtilisation;
  row.reissuedTiles = k.reissuedTiles;
  row.failedTiles = k.failedTiles;
  row.packetsRendered = result.packetsRendered;
  row.events = result.events;
  row.wallSeconds = wallSeconds;
  return row;
}

std::vector<SweepRow> runSweep(const Scene& scene, const SweepOptions& options,
                               const SweepProgress& progress) {
  validateParameters(options.parameters);
  const std::vector<SimulationConfig> configs = sweepConfigs(options);
  std::vector<SweepRow> rows(configs.size());
  // Largest jobs first, so the threads finish together.
  std::vector<std::size_t> order(configs.size());
  std::iota(order.begin(), order.end(), 0);
  std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) {
    return configs[a].renders * configs[a].traverses > configs[b].renders * configs[b].traverses;
  });

  std::atomic<std::size_t> next{0};
  std::atomic<bool> failed{false};
  std::mutex mutex;
  std::size_t done = 0;
  std::exception_ptr error;
  const auto work = [&] {
    while (!failed) {
      const std::size_t slot = next++;
      if (slot >= order.size()) return;
      const std::size_t index = order[slot];
      try {
        const auto start = std::chrono::steady_clock::now();
        const SimulationResult result = simulate(scene, configs[index], options.parameters);
        const double wall =
            std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
        rows[index] = summarize(result, wall);
        const std::lock_guard lock(mutex);
        ++done;
        if (progress) progress(done, rows.size(), rows[index]);
      } catch (...) {
        const std::lock_guard lock(mutex);
        if (!error) error = std::current_exception();
        failed = true;
      }
    }
  };
  const unsigned threads =
      std::clamp<unsigned>(options.jobs, 1, static_cast<unsigned>(configs.size()));
  std::vector<std::thread> pool;
  for (unsigned i = 1; i < threads; ++i) pool.emplace_back(work);
  work();
  for (std::thread& thread : pool) thread.join();
  if (error) std::rethrow_exception(error);
  return rows;
}

Assumptions describeAssumptions(const Scene& scene, const ViewOptions& view,
                                const SweepOptions& options, const Assumptions& extra) {
  const ModelParameters& p = options.parameters;
  std::string schedulers;
  for (display::SchedulerKind kind : options.schedulers) {
    schedulers += (schedulers.empty() ? "" : ",") + display::schedulerName(kind);
  }
  std::string costModels;
  for (traverse::CostModel model : options.costModels) {
    costModels += (costModels.empty() ? "" : ",") +
                  std::string(model == traverse::CostModel::Paper ? "paper" : "overlap");
  }
  Assumptions lines = {
      {"dataset", scene.name() + " (" + std::to_string(scene.topLevel().size()) +
                      " top-level cells, " + mib(static_cast<double>(scene.datasetBytes())) +
                      " MiB of cell data)"},
      {"view", view.cameraPath + ", " + std::to_string(scene.cameras().size()) + " frames at " +
                   std::to_string(scene.width()) + "x" + std::to_string(scene.height()) +
                   ", mode " + view.mode + " (T_s is for it), lod " +
                   significant(static_cast<double>(view.lodPixels)) + " px, size scale " +
                   significant(static_cast<double>(view.sizeScale)) +
                   (view.noBackfaceCull ? ", no back-face culling" : "")},
      {"render T_s", significant(p.secondsPerSplat, 3) + " s/splat (" +
                         fixed(1e-6 / p.secondsPerSplat, 2) + " M splats/s) + " +
                         significant(p.packetOverheadSeconds * 1e3, 3) + " ms per packet + " +
                         significant(p.packetSecondsPerPixel * 1e9, 3) +
                         " ns per pixel of its "
                         "rect; one packet at a time, first ready packet in queue order"},
      {"network", fixed(p.bandwidthBytesPerSecond / 1e6, 0) + " MB/s per link, latency " +
                      fixed(p.latencySeconds * 1e6, 0) + " us" +
                      "; one NIC per process; bulk bytes (cell data, render packets, tile "
                      "images) serialise on the sender's outgoing and the receiver's incoming "
                      "link, each first come first served, a buffering switch between"},
      {"traverse", significant(p.traverseSecondsPerCell, 3) + " s per visited cell + " +
                       significant(p.traverseTileSeconds * 1e3, 3) + " ms" +
                       " per tile; the real traversal of every tile"},
      {"display",
       significant(p.composeSecondsPerPixel * 1e9, 3) + " ns" +
           " per composed pixel; tile images (4 bytes/pixel, 8 for a part of a split "
           "tile; as runs of " +
           (scene.hasLitPixels()
                ? std::string("the lit pixels of their box, each frame drawn once by "
                              "the CPU point kernel")
                : std::string("min(box, splats) pixels")) +
           " where fewer bytes" +
           (p.compressImages && scene.compressionLevel() != 0
                ? std::string("; then as zstd level ") + std::to_string(scene.compressionLevel()) +
                      " frames, smaller by each frame's ratio measured on its pixels "
                      "in " +
                      std::to_string(kCompressionBlock) + "-pixel blocks, " +
                      significant(p.compressSecondsPerByte * 1e9, 3) +
                      " ns a byte to compress on the render, " +
                      significant(p.decompressSecondsPerByte * 1e9, 3) +
                      " ns to expand on one of the display's " +
                      std::to_string(p.displayImageThreads) + " image threads"
                : std::string("; not compressed")) +
           ") on the display's link (" +
           (p.displayBandwidthBytesPerSecond > 0.0
                ? fixed(p.displayBandwidthBytesPerSecond / 1e6, 0) + " MB/s"
                : std::string("as the others")) +
           "); " + std::to_string(p.framesInFlight) + " frames in flight, tile time-out " +
           significant(p.tileTimeoutSeconds) + " s"},
      {"render cache", significant(p.cacheMegabytes) + " MiB, cells unused for " +
                           significant(p.cacheTimeoutSeconds) + " s expire"},
      {"tiling", significant(options.tilesPerRender) + " tiles per render process" +
                     (options.tileCountTuned
                          ? std::string(" divided by a factor the display tunes on the frame "
                                        "rate (tiles/R column: its last choice)")
                          : std::string()) +
                     ", sides >= " + std::to_string(options.minTileSize) +
                     " px; each traverse keeps " +
                     (options.tileTasksAhead > 0 ? std::to_string(options.tileTasksAhead)
                                                 : "auto (" + autoTileTasksAheadRule() + ")") +
                     " tile requests at the display; heavy tiles split by their cells: " +
                     (!options.tileSplit ? std::string("off")
                      : options.tilePartSplats > 0
                          ? "parts of " + std::to_string(options.tilePartSplats) + " splats"
                          : "tiles too small to cut further, parts of one render's share "
                            "of last frame's splats, at least " +
                                std::to_string(kDefaultMinTilePartSplats) +
                                (options.tilePartTuned
                                     ? ", times a factor the display tunes on the frame rate "
                                       "(parts column: its last choice)"
                                     : std::string(", not tuned")))},
      {"sweep", "renders " + joinCounts(options.renders) + "; traverses " +
                    joinCounts(options.traverses) + "; data-sends " +
                    joinCounts(options.datasends) + " (auto: renders/4, at least 1); schedulers " +
                    schedulers + "; cost model " + costModels +
                    (options.balancedTiles ? ", cost tiles sized by last frame's work"
                                           : ", cost tiles equal") +
                    ", cost prefetch " + std::to_string(options.prefetchFrames) +
                    " frames ahead (8 MiB per tile at most)"},
      {"not modelled",
       "CPU sharing between processes (each has its own core), cell upload to "
       "the GPU, message CPU costs, PNG output"},
      {"figures",
       "frames/s and imbalance from frame 3 on, as the display's statistics; MiB are "
       "cell data sent by data-send processes for that frame; util = busy share of "
       "the steady span (render: mean/max)"},
  };
  lines.insert(lines.end(), extra.begin(), extra.end());
  return lines;
}

std::string formatTable(const std::vector<SweepRow>& rows) {
  return alignedTable(rows, false);
}

std::vector<LayoutRecommendation> recommendLayouts(const std::vector<SweepRow>& rows) {
  // Rows grouped by scheduler and render count, in the order they first appear.
  std::vector<std::pair<std::string, std::uint32_t>> keys;
  std::map<std::pair<std::string, std::uint32_t>, std::vector<const SweepRow*>> groups;
  for (const SweepRow& row : rows) {
    const auto key = std::make_pair(configName(row.config), row.config.renders);
    if (!groups.contains(key)) keys.push_back(key);
    groups[key].push_back(&row);
  }
  std::sort(keys.begin(), keys.end(), [](const auto& a, const auto& b) {
    return a.second != b.second ? a.second < b.second : a.first < b.first;
  });
  std::vector<LayoutRecommendation> result;
  for (const auto& key : keys) {
    const auto& group = groups[key];
    double best = 0.0;
    std::uint32_t mostTraverses = 0;
    for (const SweepRow* row : group) {
      best = std::max(best, row->framesPerSecondSteady);
      mostTraverses = std::max(mostTraverses, row->config.traverses);
    }
    const SweepRow* chosen = nullptr;
    for (const SweepRow* row : group) {
      if (row->framesPerSecondSteady < 0.95 * best) continue;
      if (chosen == nullptr || row->config.traverses < chosen->config.traverses ||
          (row->config.traverses == chosen->config.traverses &&
           row->config.datasends < chosen->config.datasends)) {
        chosen = row;
      }
    }
    if (chosen == nullptr) continue;
    LayoutRecommendation r;
    r.scheduler = key.first;
    r.renders = key.second;
    r.traverses = chosen->config.traverses;
    r.datasends = chosen->config.datasends;
    r.framesPerSecond = chosen->framesPerSecondSteady;
    r.bottleneck = chosen->bottleneck;
    r.bottleneckUtilisation = chosen->bottleneckUtilisation;
    if (r.bottleneck == "traverse") {
      r.advice = r.traverses == mostTraverses
                     ? "the traverse processes keep up no longer: sweep more than " +
                           std::to_string(mostTraverses)
                     : "traverse-bound: more traverse processes did not help";
    } else if (r.bottleneck == "display") {
      const bool link = chosen->utilisation.displayLink >= chosen->utilisation.displayCpu;
      r.advice = link ? "display-bound: its link carries the tile images; a faster display "
                        "link (--display-bandwidth-mbs) or a smaller frame raises the rate"
                      : "display-bound: composing tiles fills its CPU";
    } else if (r.bottleneck == "requests") {
      r.advice =
          "request-bound: tiles wait at the display while each traverse waits a "
          "request's round trip; more --tile-tasks-ahead (or traverse processes)";
    } else if (r.bottleneck == "network") {
      r.advice = "network-bound: more data-send processes or faster links";
    } else if (r.bottleneck == "render") {
      r.advice = chosen->utilisation.renderMean < 0.5 * chosen->utilisation.renderMax
                     ? "one render process is saturated while the mean is not: imbalance"
                     : "render-bound: more render processes";
    } else {
      r.advice = "no resource saturated: frames in flight wait on round trips";
    }
    result.push_back(std::move(r));
  }
  return result;
}

std::string formatRecommendations(const std::vector<LayoutRecommendation>& recommendations) {
  std::ostringstream out;
  out << "Recommended layout (fewest traverse, then data-send processes within 5 % of the best "
         "frame rate swept):\n";
  for (const LayoutRecommendation& r : recommendations) {
    char line[160];
    std::snprintf(line, sizeof line,
                  "  %-12s R=%-5u T=%-3u S=%-4u %8.2f frames/s  %s %.0f%%: ", r.scheduler.c_str(),
                  r.renders, r.traverses, r.datasends, r.framesPerSecond, r.bottleneck.c_str(),
                  r.bottleneckUtilisation * 100.0);
    out << line << r.advice << '\n';
  }
  return out.str();
}

std::string formatAssumptions(const Assumptions& assumptions) {
  std::size_t width = 0;
  for (const auto& [name, value] : assumptions) width = std::max(width, name.size());
  std::ostringstream out;
  for (const auto& [name, value] : assumptions) {
    out << "  " << name << ':' << std::string(width - name.size() + 1, ' ') << value << '\n';
  }
  return out.str();
}

std::string formatCsv(const std::vector<SweepRow>& rows) {
  std::ostringstream out;
  out << "scheduler,renders,traverses,datasends,tiles_per_render,tiles_per_frame,"
         "frames_per_second,frames_per_second_steady,frame_latency_seconds,imbalance_busy,"
         "imbalance_splats,imbalance_busy_run,bytes_first_frame,bytes_per_frame_steady,splats_per_"
         "frame,"
         "cache_hit_rate,cache_hit_rate_steady,render_utilisation_mean,render_utilisation_max,"
         "traverse_utilisation_mean,traverse_utilisation_max,network_utilisation_max,"
         "display_link_utilisation,display_cpu_utilisation,request_wait,bottleneck,"
         "bottleneck_utilisation,reissued_tiles,failed_tiles,packets_rendered,events,wall_"
         "seconds,image_bytes_per_frame_steady,image_bytes_uncompressed_per_frame_steady,part_size_"
         "factor,tiles_per_render_tuned,frames_per_second_later_loops,imbalance_busy_later_loops,"
         "plan_ms_per_frame\n";
  for (const SweepRow& row : rows) {
    const Utilisation& u = row.utilisation;
    out << configName(row.config) << ',' << row.config.renders << ',' << row.config.traverses << ','
        << row.config.datasends << ',' << number(row.config.tilesPerRender) << ','
        << number(row.tilesPerFrame) << ',' << number(row.framesPerSecond) << ','
        << number(row.framesPerSecondSteady) << ',' << number(row.meanFrameLatency) << ','
        << number(row.imbalanceBusy) << ',' << number(row.imbalanceSplats) << ','
        << number(row.imbalanceBusyRun) << ',' << number(row.bytesFirstFrame) << ','
        << number(row.bytesPerFrameSteady) << ',' << number(row.splatsPerFrame) << ','
        << number(row.cacheHitRate) << ',' << number(row.cacheHitRateSteady) << ','
        << number(u.renderMean) << ',' << number(u.renderMax) << ',' << number(u.traverseMean)
        << ',' << number(u.traverseMax) << ',' << number(u.networkMax) << ','
        << number(u.displayLink) << ',' << number(u.displayCpu) << ',' << number(u.requestWait)
        << ',' << row.bottleneck << ',' << number(row.bottleneckUtilisation) << ','
        << row.reissuedTiles << ',' << row.failedTiles << ',' << row.packetsRendered << ','
        << row.events << ',' << number(row.wallSeconds) << ','
        << number(row.imageBytesPerFrameSteady) << ','
        << number(row.imageBytesUncompressedPerFrameSteady) << ',' << row.partSizeFactor << ','
        << number(row.tilesPerRenderTuned) << ',' << number(row.framesPerSecondLaterLoops) << ','
        << number(row.imbalanceBusyLaterLoops) << ',' << number(row.planMsPerFrame) << '\n';
  }
  return out.str();
}

std::string formatReport(const std::vector<SweepRow>& rows, const Assumptions& assumptions,
                         const std::vector<std::string>& plots) {
  std::ostringstream out;
  out << "# Simulated scheduler sweep\n\n"
      << "Predicted by `pointillist-simulate`: the roles' own cores (the display's frame "
         "assembly and tile planner, the traverse's packet planner and cost function, the "
         "data-send's ledger, the render's cache and queue) driven in simulated time. Only "
         "durations are modelled; these are model figures, not measurements.\n\n"
         "## Assumptions\n\n";
  for (const auto& [name, value] : assumptions) out << "- **" << name << "**: " << value << '\n';
  out << "\n## Figures\n\n" << alignedTable(rows, true) << '\n';
  out << "## Recommended layouts\n\n```\n"
      << formatRecommendations(recommendLayouts(rows)) << "```\n\n";
  out << "- R, T, S: render, traverse and data-send processes (one display).\n"
         "- imb busy / imb splats: per frame max/mean over all render processes, mean over the "
         "steady frames (1 is perfect balance); imb run: the same of busy time summed over the "
         "steady frames (with frames in flight, a process idle in one frame may work on "
         "another).\n"
         "- MiB first / MiB/frame steady: top-level cell data sent to render processes for the "
         "first frame, and per frame from frame 3 on.\n"
         "- render util: busy share mean/max over render processes; bottleneck: the resource "
         "with the highest busy share (network = links of traverse, data-send and render "
         "processes; display = its CPU or its incoming link); requests = tiles waited at the "
         "display for a traverse's request over half the time while no traverse was 90% busy "
         "(request round trips); latency = nothing above 50%.\n";
  std::uint64_t reissued = 0, failed = 0;
  for (const SweepRow& row : rows) {
    reissued += row.reissuedTiles;
    failed += row.failedTiles;
  }
  if (reissued + failed > 0) {
    out << "- Tiles re-issued after the time-out: " << reissued << ", given up: " << failed
        << " (see the CSV per configuration).\n";
  }
  if (!plots.empty()) {
    out << "\n## Plots\n";
    for (const std::string& plot : plots) {
      out << "\n![" << plot.substr(0, plot.rfind('.')) << "](" << plot << ")\n";
    }
  }
  return out.str();
}

}  // namespace pointillist::simulator
