#pragma once
// A discrete-event model of one Pointillist job (seed 003 §4-5) that drives
// the roles' own cores in simulated time: the display's FrameAssembly, each
// traverse process's PacketPlanner, each data-send process's SendLedger and
// each render process's RenderCore, exchanging the protocol's messages. Every
// decision is theirs; the simulator only models time. Modelled instead of run:
//   traverse  seconds per visited cell * cells visited (+ one per cell found by
//             the prefetch walk) + a per-tile overhead;
//   render    a per-packet overhead + the rect's pixels * T_px + splats * T_s,
//             one packet at a time;
//   network   every message takes latency L; bulk bytes (cell data, render
//             packets, tile images) serialise on the sender's outgoing and the
//             receiver's incoming link at bandwidth B (one NIC per process);
//   display   composing a tile costs seconds per pixel on its one CPU.
// Results are deterministic for fixed inputs.
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "common/run_settings.hpp"
#include "display/core/frame_stats.hpp"
#include "display/core/tile_planner.hpp"
#include "simulator/scene.hpp"
#include "traverse/core/render_model.hpp"

namespace pointillist::simulator {

// The model's rates. Defaults are measured on the development machine (2-core
// Xeon; points drawn by the CPU point kernel, the default renderer, fitted from
// a job's tiles.csv by --calibrate, docs/scheduling.md §15) or are those of the
// runtime's options. OSMesa (llvmpipe) points were about 2e-7 s a splat and
// 1 ms a packet.
struct ModelParameters {
  double secondsPerSplat = 1.16e-8;        // T_s
  double packetOverheadSeconds = 1.0e-5;   // T_p: per render packet
  double packetSecondsPerPixel = 1.67e-9;  // T_px: clearing, read-back, sending
  double bandwidthBytesPerSecond = 117e6;  // 1 GbE payload
  // The display's own link (tile images come in on it); 0: as the others.
  double displayBandwidthBytesPerSecond = 0.0;
  double latencySeconds = 50e-6;
  double traverseSecondsPerCell = 1e-7;  // Scene::measureTraverseSecondsPerCell() measures it
  double traverseTileSeconds = 20e-6;    // per tile task (messages, packet building)
  double composeSecondsPerPixel = 1e-9;  // display blit of a tile image
  // Tile images as zstd frames (the job's --image-compression: on where the
  // display is on another machine, as in the model), smaller by the ratio the
  // scene measured for each frame (Scene::imageCompression); a render
  // compresses every image before sending, the display expands it.
  bool compressImages = true;
  double compressSecondsPerByte = 3.0e-9;    // a render, zstd level 3
  double decompressSecondsPerByte = 1.0e-9;  // the display
  // Threads expanding them at the display (its --image-threads: the cores,
  // at most 8), beside the one that composes.
  std::uint32_t displayImageThreads = 8;
  double cacheMegabytes = 1024.0;  // render cache cap (--cache-mb)
  double cacheTimeoutSeconds = 30.0;
  std::uint32_t framesInFlight = 3;
  double tileTimeoutSeconds = 10.0;
  std::uint32_t maxAttempts = 3;
};

// Throws UsageError naming the first parameter out of range.
void validateParameters(const ModelParameters& parameters);

// What drawing `packet` takes a render process: T_p + T_px * pixels + T_s * splats.
double packetSeconds(const ModelParameters& parameters, const v1::RenderPacket& packet);

struct SimulationConfig {
  display::SchedulerKind scheduler = display::SchedulerKind::Cost;
  std::uint32_t renders = 1;
  std::uint32_t traverses = 1;
  std::uint32_t datasends = 1;
  double tilesPerRender = 2.0;
  std::uint32_t minTileSize = 32;
  // Cost scheduler only: how the traverse counts missing data, and whether
  // tiles are sized by last frame's work (the display's --equal-tiles off).
  traverse::CostModel costModel = traverse::costModelOf(kDefaultCostModel);
  bool balancedTiles = true;
  // Cost scheduler: the traverse orders what each tile's rect needs this many
  // frames on for the render it chose (the display's --prefetch-frames; 0: off).
  std::uint32_t prefetchFrames = 0;
  // Tile requests each traverse keeps at the display (the display's
  // --tile-tasks-ahead; 0: auto, autoTileTasksAhead).
  std::uint32_t tileTasksAhead = 0;
  // Heavy tiles split by their data (the display's --tile-split): off, or
  // the part size in splats (0: the display's choice per frame).
  bool tileSplit = true;
  std::uint64_t tilePartSplats = 0;
  // The display's part size tuned on the frame rate (--tile-split auto); off:
  // one render's share of last frame's splats as it is (share).
  bool tilePartTuned = true;
  // The cost scheduler's tile count tuned on the frame rate (the display
  // divides tilesPerRender by 1, 2, 4, ...) where --tiles-per-render is not given.
  bool tileCountTuned = true;
  // A render process that stops drawing after some packets (the render's
  // --stall-index / --stall-after): its tiles must be re-issued elsewhere.
  std::optional<std::uint32_t> stalledRender;
  std::uint64_t stallAfterPackets = 0;
};

// "cost", "cost/paper", "cost/equal", "round-robin", ...
std::string configName(const SimulationConfig& config);

// Throws UsageError for counts of zero and the like.
void validateConfig(const SimulationConfig& config);

// What happened to one frame, for checks beyond the display's statistics.
struct FrameTrace {
  std::uint64_t frame = 0;
  std::uint32_t tilesPlanned = 0;
  std::uint32_t tilesComposed = 0;    // tile images the display accepted
  std::uint32_t packetsRendered = 0;  // render packets finished for this frame (re-issues count)
  std::uint32_t extraParts = 0;       // packets beyond one per tile: split tiles' other parts
  std::uint32_t backgroundTiles = 0;  // tiles a traverse found empty: no packet, no pixels
  std::uint64_t bytesMoved = 0;       // cell data sent by data-send processes for this frame
  std::uint64_t bytesOrdered = 0;     // what the traverses ordered (missingBytes of their choices)
  std::uint64_t bytesPrefetched = 0;  // of what they ordered, ahead along the camera path
};

// Busy share of the steady-state span (frames from steadyFrom on).
struct Utilisation {
  double renderMean = 0.0;
  double renderMax = 0.0;
  double traverseMean = 0.0;
  double traverseMax = 0.0;
  double networkMax = 0.0;   // busiest link of a traverse, data-send or render process
  double displayLink = 0.0;  // the display's incoming link (tile images)
  double displayCpu = 0.0;   // composing
  // Tiles waited at the display for a traverse's request (none was in).
  double requestWait = 0.0;
};

struct SimulationResult {
  SimulationConfig config;
  // The display's statistics of the simulated run, in simulated seconds, with
  // bytes_sent per frame = cell data actually sent for that frame.
  display::RunStats stats;
  display::KeyFigures figures;
  std::vector<FrameTrace> frames;  // in the order the display completed them
  Utilisation utilisation;
  // render, traverse, network, display, requests (traverses idle for a
  // request's round trip while tiles wait), or latency
  std::string bottleneck;
  double bottleneckUtilisation = 0.0;
  double meanFrameLatency = 0.0;  // steady frames: first tile handed out to composed
  double tilesPerFrame = 0.0;
  // Wall time of the display's tile layout (TilePlanner::plan) on this
  // machine, per frame: display CPU the model does not charge.
  double planMsPerFrame = 0.0;
  std::uint64_t packetsRendered = 0;
  std::uint64_t bytesMoved = 0;       // all cell data sent
  std::uint64_t duplicateOrders = 0;  // cells data-send skipped (already sent)
  std::uint64_t droppedPrefetches = 0;
  std::uint64_t events = 0;
};

SimulationResult simulate(const Scene& scene, const SimulationConfig& config,
                          const ModelParameters& parameters);

}  // namespace pointillist::simulator
