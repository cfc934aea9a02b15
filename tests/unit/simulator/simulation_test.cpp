// The scheduler simulator: the real tile planner, frame scheduler, cost
// function and render cache driven in simulated time on a small generated city.
// The checks are properties of the model, never wall-clock timings.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <memory>
#include <numeric>
#include <sstream>

#include "common/errors.hpp"
#include "simulator/calibration.hpp"
#include "simulator/simulation.hpp"
#include "simulator/sweep.hpp"
#include "test_city.hpp"
#include "traverse/core/packet_planner.hpp"

namespace pointillist::simulator {
namespace {

using display::SchedulerKind;

const SchedulerKind kAllSchedulers[] = {SchedulerKind::Cost, SchedulerKind::RoundRobin,
                                        SchedulerKind::Static, SchedulerKind::Equalizer,
                                        SchedulerKind::Regions};

ViewOptions testView(std::uint32_t frames = 10) {
  ViewOptions view;
  view.cameraPath = "orbit";
  view.frames = frames;
  view.size = "320x180";
  return view;
}

std::unique_ptr<Scene> makeScene(const ViewOptions& view) {
  DatasetContent content = fixtures::smallCityContent(40'000, 11);
  const SceneBounds bounds = datasetBounds(content.manifest);
  std::vector<Camera> cameras = viewCameras(view, bounds);
  const std::size_t loopFrames = view.loops > 1 ? cameras.size() / view.loops : 0;
  return std::make_unique<Scene>("test-city", std::move(content.cells), std::move(content.topLevel),
                                 bounds, std::move(cameras), traverse::TraversalSettings{},
                                 loopFrames);
}

const Scene& cityScene() {
  static const std::unique_ptr<Scene> scene = makeScene(testView());
  return *scene;
}

// Fixed rates (no timing of this machine) so every result is reproducible.
ModelParameters fixedParameters() {
  ModelParameters p;
  p.traverseSecondsPerCell = 1e-7;
  return p;
}

SimulationConfig config(SchedulerKind scheduler, std::uint32_t renders, std::uint32_t traverses = 1,
                        std::uint32_t datasends = 1) {
  SimulationConfig c;
  c.scheduler = scheduler;
  c.renders = renders;
  c.traverses = traverses;
  c.datasends = datasends;
  return c;
}

std::uint64_t totalBytes(const SimulationResult& result) {
  return std::accumulate(result.frames.begin(), result.frames.end(), std::uint64_t{0},
                         [](std::uint64_t sum, const FrameTrace& f) { return sum + f.bytesMoved; });
}

// Every tile of every frame drawn once, composed once; frames done in order.
void expectEveryTileOnce(const SimulationResult& result, std::size_t frames) {
  const std::string label = configName(result.config) +
                            " R=" + std::to_string(result.config.renders) +
                            " T=" + std::to_string(result.config.traverses);
  ASSERT_EQ(result.frames.size(), frames) << label;
  ASSERT_EQ(result.stats.frames.size(), frames) << label;
  std::uint64_t packets = 0;
  for (std::size_t i = 0; i < frames; ++i) {
    const FrameTrace& trace = result.frames[i];
    EXPECT_EQ(trace.frame, i) << label << ": frames completed out of order";
    EXPECT_GT(trace.tilesPlanned, 0u) << label;
    EXPECT_EQ(trace.tilesComposed, trace.tilesPlanned) << label << " frame " << i;
    // A tile the traverse found empty is answered without a packet.
    EXPECT_EQ(trace.packetsRendered, trace.tilesPlanned - trace.backgroundTiles + trace.extraParts)
        << label << " frame " << i;
    EXPECT_EQ(result.stats.frames[i].failedTiles, 0u) << label;
    EXPECT_EQ(result.stats.frames[i].reissuedTiles, 0u) << label;
    if (i > 0) {
      EXPECT_GE(result.stats.frames[i].endSeconds, result.stats.frames[i - 1].endSeconds);
    }
    packets += trace.tilesPlanned - trace.backgroundTiles + trace.extraParts;
  }
  EXPECT_EQ(result.packetsRendered, packets) << label;
  EXPECT_EQ(result.stats.lateTiles, 0u) << label;
}

TEST(Simulator, EveryTileOfEveryFrameIsRenderedOnceAndFramesCompleteInOrder) {
  const Scene& scene = cityScene();
  for (SchedulerKind scheduler : kAllSchedulers) {
    for (std::uint32_t renders : {1u, 3u, 8u}) {
      for (std::uint32_t traverses : {1u, 2u}) {
        const auto result =
            simulate(scene, config(scheduler, renders, traverses, 2), fixedParameters());
        expectEveryTileOnce(result, scene.cameras().size());
        EXPECT_GT(result.figures.framesPerSecondSteady, 0.0);
      }
    }
  }
}

TEST(Simulator, MoreRenderProcessesNeverLoseTiles) {
  const Scene& scene = cityScene();
  for (SchedulerKind scheduler : kAllSchedulers) {
    for (std::uint32_t renders : {2u, 5u, 16u, 64u, 200u}) {
      const auto result =
          simulate(scene, config(scheduler, renders, 3, autoDatasends(renders)), fixedParameters());
      expectEveryTileOnce(result, scene.cameras().size());
    }
  }
}

TEST(Simulator, OneRenderProcessIsPerfectlyBalanced) {
  for (SchedulerKind scheduler : kAllSchedulers) {
    const auto result = simulate(cityScene(), config(scheduler, 1, 2), fixedParameters());
    EXPECT_DOUBLE_EQ(result.figures.imbalanceBusy, 1.0) << configName(result.config);
    EXPECT_DOUBLE_EQ(result.figures.imbalanceSplats, 1.0) << configName(result.config);
  }
}

// A path played twice (--loops 2): the second loop finds its frames' data
// already sent. (Its splats differ a little: tiles are sized by the last
// frame's work, and a cell is drawn by every tile it reaches.)
TEST(Simulator, ASecondLoopFindsItsDataSentAndMovesLittle) {
  ViewOptions view = testView(10);
  view.loops = 2;
  const auto scene = makeScene(view);
  ASSERT_EQ(scene->cameras().size(), 20u);
  ASSERT_EQ(scene->loopFrames(), 10u);
  const auto result = simulate(*scene, config(SchedulerKind::Cost, 4, 2), fixedParameters());
  ASSERT_EQ(result.stats.frames.size(), 20u);
  std::vector<std::uint64_t> bytes(20);
  for (const display::FrameRecord& f : result.stats.frames) bytes.at(f.frame) = f.bytesOrdered;
  const display::KeyFigures& k = result.figures;
  EXPECT_EQ(k.laterLoopsFrom, 10u);
  const double firstLoop = std::accumulate(bytes.begin() + 3, bytes.begin() + 10, 0.0) / 7.0;
  EXPECT_GT(k.framesPerSecondLaterLoops, 0.0);
  EXPECT_LT(k.bytesPerFrameLaterLoops, 0.02 * static_cast<double>(k.bytesFirstFrame));
  EXPECT_LT(k.bytesPerFrameLaterLoops, firstLoop);
}

TEST(Simulator, ResultsAreDeterministic) {
  for (SchedulerKind scheduler : kAllSchedulers) {
    const auto c = config(scheduler, 6, 3, 2);
    const auto first = simulate(cityScene(), c, fixedParameters());
    const auto second = simulate(cityScene(), c, fixedParameters());
    // Every per-frame figure, per-render splat count and busy time.
    EXPECT_EQ(first.stats.toJson(), second.stats.toJson()) << configName(c);
    EXPECT_EQ(first.events, second.events);
  }
}

TEST(Simulator, CostSchedulerMovesLessDataThanRoundRobinOnACoherentOrbit) {
  // A slow orbit (24 frames a turn). With more render processes than the tile
  // count divides evenly, round-robin hands the same screen area (hence the
  // same cells) to a different process every frame; the cost function keeps
  // tiles where their data is. (With few processes and tiles a multiple of
  // them, round-robin degenerates to a static assignment and moves little.)
  static const std::unique_ptr<Scene> orbit = makeScene(testView(24));
  for (std::uint32_t renders : {24u, 32u}) {
    const auto cost =
        simulate(*orbit, config(SchedulerKind::Cost, renders, 2, 6), fixedParameters());
    const auto roundRobin =
        simulate(*orbit, config(SchedulerKind::RoundRobin, renders, 2, 6), fixedParameters());
    EXPECT_LT(totalBytes(cost), totalBytes(roundRobin)) << renders << " render processes";
    EXPECT_LT(1.5 * cost.figures.bytesPerFrameSteady, roundRobin.figures.bytesPerFrameSteady)
        << renders << " render processes";
    EXPECT_GT(cost.figures.cacheHitRateSteady, roundRobin.figures.cacheHitRateSteady);
  }
}

TEST(Simulator, DoublingTheTimePerSplatHalvesTheFrameRateWhenRenderBound) {
  // One render process, an instant network, no overheads: only drawing counts.
  ModelParameters p = fixedParameters();
  p.packetOverheadSeconds = 0.0;
  p.bandwidthBytesPerSecond = 1e13;
  p.latencySeconds = 1e-7;
  p.traverseSecondsPerCell = 0.0;
  p.traverseTileSeconds = 0.0;
  p.composeSecondsPerPixel = 0.0;
  for (SchedulerKind scheduler : {SchedulerKind::Cost, SchedulerKind::Static}) {
    const auto c = config(scheduler, 1, 2);
    const auto fast = simulate(cityScene(), c, p);
    p.secondsPerSplat *= 2.0;
    const auto slow = simulate(cityScene(), c, p);
    p.secondsPerSplat /= 2.0;
    EXPECT_EQ(fast.bottleneck, "render");
    const double ratio = slow.figures.framesPerSecondSteady / fast.figures.framesPerSecondSteady;
    EXPECT_NEAR(ratio, 0.5, 0.05) << configName(c);
  }
}

TEST(Simulator, FirstFrameMovesAtLeastItsWorkingSet) {
  const Scene& scene = cityScene();
  const std::uint64_t workingSet = scene.frameWorkingSetBytes(0);
  ASSERT_GT(workingSet, 0u);
  for (SchedulerKind scheduler : kAllSchedulers) {
    for (std::uint32_t renders : {1u, 4u}) {
      // One traverse: frame 0's tiles are traversed (and ordered) before frame 1's.
      const auto result = simulate(scene, config(scheduler, renders, 1, 2), fixedParameters());
      EXPECT_GE(result.figures.bytesFirstFrame, workingSet) << configName(result.config);
      EXPECT_LE(result.figures.bytesFirstFrame, renders * scene.datasetBytes());
    }
  }
  // One render process, no prefetch: the drawn ranges and at most the gaps
  // the tiles join between them, never a splat twice.
  auto c = config(SchedulerKind::Cost, 1, 1, 3);
  c.prefetchFrames = 0;
  const auto single = simulate(scene, c, fixedParameters());
  EXPECT_GE(single.figures.bytesFirstFrame, workingSet);
  EXPECT_LE(single.figures.bytesFirstFrame, scene.frameWorkingSetBytes(0, kNeedGapSplatsCopied));
  EXPECT_LE(totalBytes(single), scene.datasetBytes());
}

TEST(Simulator, CostSchedulerPrefetchesAlongTheCameraPathOnlyWhenAsked) {
  auto c = config(SchedulerKind::Cost, 6, 2, 2);
  c.prefetchFrames = 3;
  const auto prefetching = simulate(cityScene(), c, fixedParameters());
  c.prefetchFrames = 0;
  const auto plain = simulate(cityScene(), c, fixedParameters());
  std::uint64_t prefetched = 0;
  for (const FrameTrace& trace : prefetching.frames) prefetched += trace.bytesPrefetched;
  EXPECT_GT(prefetched, 0u);
  for (const FrameTrace& trace : plain.frames) EXPECT_EQ(trace.bytesPrefetched, 0u);
  expectEveryTileOnce(prefetching, cityScene().cameras().size());
  // Other schedulers never prefetch (the display sends no lookahead camera).
  const auto roundRobin =
      simulate(cityScene(), config(SchedulerKind::RoundRobin, 6, 2, 2), fixedParameters());
  for (const FrameTrace& trace : roundRobin.frames) EXPECT_EQ(trace.bytesPrefetched, 0u);
}

TEST(Simulator, SlowNetworkMakesTheNetworkOrDisplayTheBottleneck) {
  ModelParameters p = fixedParameters();
  p.bandwidthBytesPerSecond = 2e5;  // 200 kB/s
  const auto slow = simulate(cityScene(), config(SchedulerKind::RoundRobin, 4, 2, 1), p);
  EXPECT_TRUE(slow.bottleneck == "network" || slow.bottleneck == "display") << slow.bottleneck;
  p.bandwidthBytesPerSecond = 1e12;
  p.secondsPerSplat = 1e-5;
  const auto fast = simulate(cityScene(), config(SchedulerKind::RoundRobin, 4, 2, 1), p);
  EXPECT_EQ(fast.bottleneck, "render");
  EXPECT_GT(fast.utilisation.renderMax, 0.9);
}

TEST(Simulator, TileTasksAheadHideTheRequestRoundTrip) {
  // Many small tiles and a long latency: with one request at a time every
  // tile waits a round trip at its traverse, which then stands idle.
  ModelParameters p = fixedParameters();
  p.latencySeconds = 500e-6;
  p.bandwidthBytesPerSecond = 1e12;
  p.displayBandwidthBytesPerSecond = 1e12;
  p.secondsPerSplat = 1e-9;
  p.packetOverheadSeconds = 1e-5;
  SimulationConfig c = config(SchedulerKind::Cost, 32, 1, 4);
  c.minTileSize = 8;
  c.tileTasksAhead = 1;
  const auto one = simulate(cityScene(), c, p);
  c.tileTasksAhead = 3;
  const auto three = simulate(cityScene(), c, p);
  expectEveryTileOnce(three, cityScene().cameras().size());
  EXPECT_GT(three.utilisation.traverseMax, 1.5 * one.utilisation.traverseMax);
  EXPECT_GT(three.figures.framesPerSecondSteady, 1.5 * one.figures.framesPerSecondSteady);
  // The simulator names the cause: tiles wait at the display for requests
  // while the traverse is far from busy.
  EXPECT_EQ(one.bottleneck, "requests");
  EXPECT_GT(one.utilisation.requestWait, 0.5);
  EXPECT_LT(one.utilisation.traverseMax, 0.9);
  EXPECT_LT(three.utilisation.requestWait, one.utilisation.requestWait);
  // auto, for 32 renders' 64-odd tiles on one traverse: 2.
  c.tileTasksAhead = 0;
  const auto automatic = simulate(cityScene(), c, p);
  expectEveryTileOnce(automatic, cityScene().cameras().size());
  EXPECT_GT(automatic.figures.framesPerSecondSteady, one.figures.framesPerSecondSteady);
}

TEST(Simulator, TheDisplaysOwnLinkCanBeFasterThanTheOthers) {
  ModelParameters p = fixedParameters();
  p.bandwidthBytesPerSecond = 1e7;  // 10 MB/s: tile images alone fill the display's link
  // Whole tiles: parts of split ones spread cells over more renders, which
  // on links this slow makes the data the bottleneck instead.
  SimulationConfig c = config(SchedulerKind::Cost, 8, 2, 2);
  c.tileSplit = false;
  const auto shared = simulate(cityScene(), c, p);
  EXPECT_EQ(shared.bottleneck, "display") << shared.bottleneck;
  EXPECT_GT(shared.utilisation.displayLink, 0.5);
  p.displayBandwidthBytesPerSecond = 1e10;
  const auto fast = simulate(cityScene(), c, p);
  EXPECT_LT(fast.utilisation.displayLink, 0.1);
  EXPECT_GT(fast.figures.framesPerSecondSteady, shared.figures.framesPerSecondSteady);
}

TEST(Simulator, ASmallRenderCacheEvictsAndStillCompletesEveryFrame) {
  ModelParameters p = fixedParameters();
  const auto roomy = simulate(cityScene(), config(SchedulerKind::RoundRobin, 3, 2, 2), p);
  p.cacheMegabytes = 0.05;  // far below one frame's data: cells come and go
  const auto tight = simulate(cityScene(), config(SchedulerKind::RoundRobin, 3, 2, 2), p);
  expectEveryTileOnce(tight, cityScene().cameras().size());
  EXPECT_GT(totalBytes(tight), totalBytes(roomy));
  EXPECT_LT(tight.figures.cacheHitRate, roomy.figures.cacheHitRate);
}

TEST(Simulator, ManyFramesInFlightAndShortTimeoutsReissueButNeverDoubleCompose) {
  ModelParameters p = fixedParameters();
  p.secondsPerSplat = 1e-4;  // tiles take far longer than the time-out
  p.tileTimeoutSeconds = 0.05;
  p.maxAttempts = 2;
  const auto result = simulate(cityScene(), config(SchedulerKind::Cost, 2, 2), p);
  ASSERT_EQ(result.frames.size(), cityScene().cameras().size());
  std::uint64_t reissued = 0;
  for (std::size_t i = 0; i < result.frames.size(); ++i) {
    const FrameTrace& trace = result.frames[i];
    EXPECT_EQ(trace.frame, i);
    const auto& record = result.stats.frames[i];
    // Each tile is composed once or given up, however often it was drawn.
    EXPECT_EQ(trace.tilesComposed + record.failedTiles, trace.tilesPlanned);
    EXPECT_GE(trace.packetsRendered + trace.backgroundTiles, trace.tilesComposed);
    reissued += record.reissuedTiles;
  }
  EXPECT_GT(reissued, 0u);
}

// The same RenderCore and PacketPlanner as the runtime: a render process that
// stops drawing holds up its tiles until they are re-issued, gets no more work
// once its queue (or, sooner, its silence: PacketPlanner tests) gives it
// away, and every frame completes.
// Render 0 of three stops after two packets; tiles time out after 0.5 s.
// Every frame completes with no tile lost, some were re-issued, and nothing
// came from the stalled process after its two packets. Returns the re-issues.
std::uint64_t expectStallSurvived(SimulationConfig c, SimulationResult& result) {
  ModelParameters p = fixedParameters();
  p.tileTimeoutSeconds = 0.5;
  c.stalledRender = 0;
  c.stallAfterPackets = 2;
  result = simulate(cityScene(), c, p);
  EXPECT_EQ(result.frames.size(), cityScene().cameras().size());
  std::uint64_t reissued = 0;
  for (std::size_t i = 0; i < result.frames.size(); ++i) {
    EXPECT_EQ(result.stats.frames[i].failedTiles, 0u) << "frame " << i;
    EXPECT_EQ(result.frames[i].tilesComposed, result.frames[i].tilesPlanned);
    reissued += result.stats.frames[i].reissuedTiles;
  }
  EXPECT_GT(reissued, 0u);
  const int stalledRank = 1 + 2 + 1;
  std::size_t fromStalled = 0;
  for (const auto& tile : result.stats.tiles) fromStalled += tile.renderRank == stalledRank;
  EXPECT_EQ(fromStalled, 2u);
  return reissued;
}

TEST(Simulator, AStalledRenderHoldsUpOnlyItsOwnTilesAndEveryFrameCompletes) {
  SimulationConfig c = config(SchedulerKind::Cost, 3, 2, 1);
  // Unsplit tiles: split ones spread over every render by design, so more of
  // the first frames' work meets the stall (the next test).
  c.tileSplit = false;
  SimulationResult result;
  const std::uint64_t reissued = expectStallSurvived(c, result);
  // Without that, a third of every frame's tiles would go to it and be
  // re-issued, frame after frame.
  std::uint64_t tiles = 0;
  for (const auto& frame : result.frames) tiles += frame.tilesPlanned;
  EXPECT_LT(reissued * 6, tiles) << reissued << " of " << tiles << " tiles re-issued";
  const std::size_t lastFrames = result.frames.size() / 3;
  for (std::size_t i = result.frames.size() - lastFrames; i < result.frames.size(); ++i) {
    EXPECT_EQ(result.stats.frames[i].reissuedTiles, 0u) << "frame " << i;
  }
}

// Parts of split tiles go to every render that can take them at once; those
// that meet the stall are re-issued, and no frame loses a tile.
TEST(Simulator, SplitTilesMeetingAStalledRenderStillCompleteEveryFrame) {
  SimulationConfig c = config(SchedulerKind::Cost, 3, 2, 1);
  c.tilePartSplats = 2000;
  SimulationResult result;
  expectStallSurvived(c, result);
  std::uint64_t extraParts = 0;
  for (const FrameTrace& frame : result.frames) extraParts += frame.extraParts;
  EXPECT_GT(extraParts, 0u);
  EXPECT_GT(result.stats.splitTiles, 0u);
}

// One default cost model, shared with the runtime's command line and core.
TEST(Simulator, UsesTheRuntimesDefaultCostModel) {
  const traverse::CostModel runtime = traverse::costModelOf(kDefaultCostModel);
  EXPECT_EQ(SimulationConfig{}.costModel, runtime);
  EXPECT_EQ(SweepOptions{}.costModels, std::vector<traverse::CostModel>{runtime});
  EXPECT_EQ(traverse::RenderModel(1, {}).costModel(), runtime);
  EXPECT_EQ(configName(SimulationConfig{}), "cost");
}

TEST(Simulator, RejectsBadConfigurationsAndParameters) {
  EXPECT_THROW(simulate(cityScene(), config(SchedulerKind::Cost, 0), fixedParameters()),
               UsageError);
  EXPECT_THROW(simulate(cityScene(), config(SchedulerKind::Cost, 2, 0), fixedParameters()),
               UsageError);
  EXPECT_THROW(simulate(cityScene(), config(SchedulerKind::Cost, 2, 1, 0), fixedParameters()),
               UsageError);
  ModelParameters p = fixedParameters();
  p.bandwidthBytesPerSecond = 0.0;
  EXPECT_THROW(simulate(cityScene(), config(SchedulerKind::Cost, 2), p), UsageError);
  p = fixedParameters();
  p.secondsPerSplat = -1.0;
  EXPECT_THROW(validateParameters(p), UsageError);
  p = fixedParameters();
  p.framesInFlight = 0;
  EXPECT_THROW(validateParameters(p), UsageError);
}

TEST(SimulatorSweep, ConfigurationsCoverTheCrossProductWithAutomaticDataSends) {
  SweepOptions options;
  options.renders = {8, 64};
  options.traverses = {1, 4};
  options.schedulers = {SchedulerKind::Cost, SchedulerKind::Static};
  options.costModels = {traverse::CostModel::Overlap, traverse::CostModel::Paper};
  const auto configs = sweepConfigs(options);
  ASSERT_EQ(configs.size(), 2u * 2u * 3u);  // cost twice (two cost models), static once
  EXPECT_EQ(configs[0].traverses, 1u);
  EXPECT_EQ(configs[0].renders, 8u);
  EXPECT_EQ(configs[0].datasends, 2u);
  EXPECT_EQ(configName(configs[0]), "cost/overlap");
  EXPECT_EQ(configName(configs[1]), "cost");
  EXPECT_EQ(configName(configs[2]), "static");
  EXPECT_EQ(configs[3].datasends, 16u);
  EXPECT_EQ(configs.back().traverses, 4u);
  EXPECT_EQ(autoDatasends(1), 1u);
  options.renders.clear();
  EXPECT_THROW(sweepConfigs(options), UsageError);
}

TEST(SimulatorSweep, RowsComeBackInOrderWithTableCsvAndReport) {
  SweepOptions options;
  options.renders = {2, 9};
  options.traverses = {2};
  options.datasends = {0};
  options.parameters = fixedParameters();
  options.jobs = 2;
  std::size_t progressCalls = 0;
  const auto rows =
      runSweep(cityScene(), options, [&](std::size_t done, std::size_t total, const SweepRow&) {
        ++progressCalls;
        EXPECT_LE(done, total);
      });
  ASSERT_EQ(rows.size(), 8u);
  EXPECT_EQ(progressCalls, rows.size());
  EXPECT_EQ(rows[0].config.renders, 2u);
  EXPECT_EQ(rows[4].config.renders, 9u);
  EXPECT_EQ(rows[1].config.scheduler, SchedulerKind::RoundRobin);
  for (const SweepRow& row : rows) {
    EXPECT_GT(row.framesPerSecondSteady, 0.0);
    EXPECT_GE(row.imbalanceBusy, 1.0);
    const std::string kinds[] = {"render", "traverse", "network", "display", "latency"};
    EXPECT_NE(std::find(std::begin(kinds), std::end(kinds), row.bottleneck), std::end(kinds))
        << row.bottleneck;
  }
  // The same rows on one thread: the thread count changes nothing.
  options.jobs = 1;
  const auto serial = runSweep(cityScene(), options);
  for (std::size_t i = 0; i < rows.size(); ++i) {
    EXPECT_EQ(rows[i].framesPerSecondSteady, serial[i].framesPerSecondSteady);
    EXPECT_EQ(rows[i].bytesPerFrameSteady, serial[i].bytesPerFrameSteady);
  }

  const std::string table = formatTable(rows);
  EXPECT_EQ(std::count(table.begin(), table.end(), '\n'), 9);  // header + rows
  const std::string csv = formatCsv(rows);
  EXPECT_EQ(std::count(csv.begin(), csv.end(), '\n'), 9);
  const auto commas = [](const std::string& line) {
    return std::count(line.begin(), line.end(), ',');
  };
  std::istringstream lines(csv);
  std::string header, line;
  std::getline(lines, header);
  while (std::getline(lines, line)) EXPECT_EQ(commas(line), commas(header));
  const Assumptions assumptions = describeAssumptions(cityScene(), testView(), options);
  const std::string report = formatReport(rows, assumptions, {"fps.png"});
  EXPECT_NE(report.find("render T_s"), std::string::npos);
  EXPECT_NE(report.find("![fps](fps.png)"), std::string::npos);
  EXPECT_NE(formatAssumptions(assumptions).find("network:"), std::string::npos);
}

using fixtures::TempDir;

void writeFile(const std::filesystem::path& file, const std::string& text) {
  std::filesystem::create_directories(file.parent_path());
  std::ofstream(file) << text;
}

TEST(SimulatorSweep, RecommendsTheFewestProcessesWithinFivePercentAndNamesTheBottleneck) {
  const auto row = [](std::uint32_t renders, std::uint32_t traverses, double fps,
                      const char* bottleneck) {
    SweepRow r;
    r.config = config(SchedulerKind::Cost, renders, traverses, autoDatasends(renders));
    r.framesPerSecondSteady = fps;
    r.bottleneck = bottleneck;
    r.bottleneckUtilisation = 0.9;
    r.utilisation.displayLink = 0.9;
    return r;
  };
  const std::vector<SweepRow> rows{row(64, 1, 40.0, "traverse"),  row(64, 2, 77.0, "render"),
                                   row(64, 4, 80.0, "render"),    row(256, 1, 30.0, "traverse"),
                                   row(256, 2, 60.0, "traverse"), row(256, 4, 90.0, "traverse"),
                                   row(1024, 2, 50.0, "display"), row(1024, 4, 50.0, "display")};
  const auto layouts = recommendLayouts(rows);
  ASSERT_EQ(layouts.size(), 3u);
  EXPECT_EQ(layouts[0].renders, 64u);
  EXPECT_EQ(layouts[0].traverses, 2u);  // 77 is within 5 % of 80
  EXPECT_EQ(layouts[1].traverses, 4u);
  EXPECT_NE(layouts[1].advice.find("sweep more than 4"), std::string::npos);
  EXPECT_EQ(layouts[2].traverses, 2u);
  EXPECT_NE(layouts[2].advice.find("display link"), std::string::npos);
  const std::string text = formatRecommendations(layouts);
  EXPECT_NE(text.find("R=1024"), std::string::npos);
}

TEST(SimulatorCalibration, TimePerSplatComesFromBusySecondsOfTheRuns) {
  TempDir dir;
  // Two schedulers' runs: 3 M splats in 0.7 s busy over 20 tiles in all.
  writeFile(dir.path() / "cost/per_frame_render.csv",
            "frame,render_rank,splats,busy_seconds\n0,4,1000000,0.2\n0,5,1000000,0.3\n");
  writeFile(dir.path() / "cost/frames.csv", "frame,start,end,seconds,splats,tiles\n0,0,1,1,2,8\n");
  writeFile(dir.path() / "cost/figures.csv",
            "frames,frames_per_second_steady,imbalance_busy\n1,6.5,1.25\n");
  writeFile(dir.path() / "cost/stats.json", "{\n  \"layout\": \"1,2,1,4\",\n}\n");
  writeFile(dir.path() / "static/per_frame_render.csv",
            "frame,render_rank,splats,busy_seconds\n0,4,1000000,0.2\n");
  writeFile(dir.path() / "static/frames.csv", "frame,tiles\n0,12\n");
  const Calibration all = calibrateFromRuns(dir.path(), 0.01);
  ASSERT_EQ(all.runs.size(), 2u);
  EXPECT_EQ(all.runs[0].name, "cost");
  EXPECT_EQ(all.runs[0].layout, "1,2,1,4");
  EXPECT_DOUBLE_EQ(all.runs[0].framesPerSecondSteady, 6.5);
  EXPECT_EQ(all.runs[1].tiles, 12u);
  EXPECT_NEAR(all.secondsPerSplat, (0.7 - 20 * 0.01) / 3e6, 1e-15);
  // One run directory works too; the overhead never takes more than half.
  const Calibration one = calibrateFromRuns(dir.path() / "static", 1.0);
  EXPECT_NEAR(one.secondsPerSplat, 0.1 / 1e6, 1e-15);

  EXPECT_THROW(calibrateFromRuns(dir.path() / "missing", 0.0), InputError);
  writeFile(dir.path() / "empty/notes.txt", "nothing here\n");
  EXPECT_THROW(calibrateFromRuns(dir.path() / "empty", 0.0), InputError);
  writeFile(dir.path() / "bad/per_frame_render.csv", "frame,render_rank,busy_seconds\n0,4,0.5\n");
  EXPECT_THROW(calibrateFromRuns(dir.path() / "bad", 0.0), InputError);
}

TEST(SimulatorCalibration, PacketTimesAreFittedFromTheTilesDrawn) {
  // Exact data: 20 us a packet, 2 ns a pixel, 10 ns a splat.
  std::vector<PacketSample> samples;
  for (int i = 0; i < 40; ++i) {
    const double pixels = 256.0 * (1 + i % 7), splats = 1000.0 * (1 + (i * 5) % 11);
    samples.push_back({20e-6 + 2e-9 * pixels + 1e-8 * splats, splats, pixels});
  }
  const PacketTimeFit exact = fitPacketTimes(samples);
  EXPECT_NEAR(exact.secondsPerPacket, 20e-6, 1e-12);
  EXPECT_NEAR(exact.secondsPerPixel, 2e-9, 1e-15);
  EXPECT_NEAR(exact.secondsPerSplat, 1e-8, 1e-15);
  EXPECT_NEAR(exact.rSquared, 1.0, 1e-9);
  EXPECT_EQ(exact.samples, 40u);

  // Time that falls with pixels would give T_px < 0: that term is dropped and
  // the packet overhead and T_s refitted, never a negative rate.
  std::vector<PacketSample> falling;
  for (int i = 0; i < 40; ++i) {
    const double pixels = 256.0 * (1 + i % 7), splats = 1000.0 * (1 + (i * 5) % 11);
    falling.push_back({1e-3 - 1e-7 * pixels + 1e-8 * splats, splats, pixels});
  }
  const PacketTimeFit kept = fitPacketTimes(falling);
  EXPECT_EQ(kept.secondsPerPixel, 0.0);
  EXPECT_GT(kept.secondsPerPacket, 0.0);
  EXPECT_GT(kept.secondsPerSplat, 0.0);
  EXPECT_LT(kept.rSquared, 1.0);

  // Without a splat drawn there is no T_s to fit.
  EXPECT_THROW(fitPacketTimes(std::vector<PacketSample>{{2e-3, 0, 64}}), InputError);

  // From a run directory: the tiles.csv lines with a render time (an empty
  // tile answered by its traverse has none), which then give T_s too.
  TempDir dir;
  writeFile(dir.path() / "per_frame_render.csv",
            "frame,render_rank,splats,busy_seconds\n0,4,3000,0.5\n");
  std::string tiles = "frame,tile,render_seconds,splats,pixels\n0,9,0,0,1024\n";
  for (const PacketSample& s : samples) {
    tiles += "0,1," + std::to_string(s.seconds) + "," + std::to_string(s.splats) + "," +
             std::to_string(s.pixels) + "\n";
  }
  writeFile(dir.path() / "tiles.csv", tiles);
  const Calibration fromRun = calibrateFromRuns(dir.path(), 1e-3);
  ASSERT_TRUE(fromRun.fit.has_value());
  EXPECT_EQ(fromRun.fit->samples, 40u);
  EXPECT_NEAR(fromRun.secondsPerSplat, 1e-8, 1e-10);  // to_string keeps 6 decimals
  EXPECT_NEAR(fromRun.fit->secondsPerPacket, 20e-6, 1e-6);
  writeFile(dir.path() / "tiles.csv", "frame,tile,render_seconds,splats\n0,1,0.001,10\n");
  EXPECT_THROW(calibrateFromRuns(dir.path(), 1e-3), InputError);  // no pixels column
}

}  // namespace
}  // namespace pointillist::simulator
