#pragma once
// Names and defaults of the settings a run hands every process once
// (v1::RunSettings), so the runtime, the simulator and their command lines
// share one default.
#include <cstdint>
#include <optional>
#include <string>

#include "pointillist.pb.h"

namespace pointillist {

// Seed 003's cost as written: the transfer adds to the queue (docs/scheduling.md).
inline constexpr v1::CostModel kDefaultCostModel = v1::COST_MODEL_PAPER;

// "paper" | "overlap"; a UsageError names the accepted ones.
v1::CostModel parseCostModel(const std::string& name);
const char* costModelName(v1::CostModel model);

// "cost" | "regions" | "round-robin" | "static" | "equalizer"; a UsageError names the accepted
// ones.
v1::Scheduler parseScheduler(const std::string& name);
// Tile requests a traverse process keeps at the display: with k, a traverse
// walks at most k tiles per request round trip, so it stands idle unless
// k >= 1 + round trip / walk (docs/scheduling.md §8.1, §10).
inline constexpr std::uint32_t kDefaultTileTasksAhead = 2;
inline constexpr std::uint32_t kMaxAutoTileTasksAhead = 8;
inline constexpr std::uint32_t kTilesPerAutoTileTask = 16;
// The run's count (RunSettings.tile_tasks_ahead; 0: kDefaultTileTasksAhead).
std::uint32_t tileTasksAhead(const v1::RunSettings& settings);
// "auto": one request per 16 tiles a traverse walks per frame, from 2 to 8.
// The more tiles per traverse, the smaller they are and the shorter each
// walk, so the more requests it takes to cover a round trip; the fewer, the
// more a frame's last tiles would wait at one traverse while another idles.
std::uint32_t autoTileTasksAhead(double tilesPerFrame, std::uint32_t traverses);
// The auto rule in words, for help texts and reports.
std::string autoTileTasksAheadRule();
// "auto" (0) | a count from 1 to 64; a UsageError names the accepted ones.
std::uint32_t parseTileTasksAhead(const std::string& text);
// --render-core-share: "auto" (0: from the machines the job runs on, see
// common/core_share.hpp) or a share in (0, 1] for every render process
// (1: each its own node, seed 003's cost function as written).
float parseRenderCoreShare(const std::string& text);
const char* schedulerName(v1::Scheduler scheduler);

// A tile needs the ranges it draws of each packet, and ranges at most this
// many splats apart are needed as one (docs/scheduling.md §19): a range costs
// the processes it passes through about half a microsecond of CPU in all, a
// gap its bytes. Over links the bytes cost more (32 B a splat is 0.26 us at
// 1 GbE); read in place on one machine they cost the pages mapped, far less.
inline constexpr std::uint32_t kNeedGapSplatsCopied = 8;
inline constexpr std::uint32_t kNeedGapSplatsInPlace = 256;
// The run's (RunSettings.need_gap_splats; unset: kNeedGapSplatsCopied).
std::uint32_t needGapSplats(const v1::RunSettings& settings);
// "auto" (nullopt: the handshake's choice) | a gap in splats from 0 (the
// drawn ranges only) to 65536; a UsageError names the accepted ones.
std::optional<std::uint32_t> parseNeedGapSplats(const std::string& text);

// Heavy tiles split by their data (RunSettings.no_tile_split): a part holds
// at least this many splats, so its fixed costs (a packet, a composed image)
// stay small beside its drawing.
inline constexpr std::uint64_t kDefaultMinTilePartSplats = 4096;
// "auto" (the display's part size, tuned on the frame rate) | "share" (one
// render's share of last frame's splats, untuned) | "off" | a part size in
// splats (>= 1), into no_tile_split, tile_part_splats and tile_part_untuned;
// a UsageError names the accepted ones.
void parseTileSplit(const std::string& text, v1::RunSettings& settings);
std::string tileSplitName(const v1::RunSettings& settings);
// Whether a frame drawn with these settings may have split tiles: only where
// composing parts by the minimum word is exact, that is points drawn by the
// cpu kernel, without eye-dome lighting, and without the eye-space depth the
// render cache asks for. The scheduler is the caller's to check.
bool tileSplitAllowed(const v1::RunSettings& run, const v1::FrameSettings& frame);

// What draws: "auto" | "gl" | "cpu"; a UsageError names the accepted ones.
v1::Renderer parseRenderer(const std::string& name);
const char* rendererName(v1::Renderer renderer);
// The renderer that draws `mode`: auto is the cpu point kernel for points and
// OSMesa for the rest; a UsageError when the cpu kernel is asked for another mode.
v1::Renderer resolveRenderer(v1::Renderer renderer, v1::RenderMode mode);

// Eye-dome lighting (--edl): CloudCompare's and Potree's defaults.
inline constexpr float kDefaultEdlStrength = 1.0f;
inline constexpr float kDefaultEdlRadius = 1.4f;  // pixels
inline constexpr float kMaxEdlRadius = 16.0f;
// Pixels a tile is drawn beyond its rectangle so that the pass sees every
// neighbour it samples: ceil(radius). The traverse culls with the same margin.
std::uint32_t edlHaloPixels(float radius);
// UsageError naming the problem: strength not in (0, 100], radius not in
// [1, kMaxEdlRadius] (below 1 px the samples would be the pixel itself), or
// the blended mode (its depth buffer holds the blend pass's pushed-back depths).
void checkEdl(v1::RenderMode mode, float strength, float radius);

// The settings one frame is drawn with: the run's, with the fields `frame`
// sets (a served client's mode, level of detail, scheduler) in their place.
v1::RunSettings frameRunSettings(const v1::RunSettings& run, const v1::FrameSettings& frame);
// UsageError when the run's dataset has no instanced sections (--mode
// instanced needs a dataset built with --instanced); `dataset` names it.
void checkInstancedSections(const v1::RunSettings& run, const std::string& dataset);
// The same for RENDER_MODE_STATISTICAL and statistical_hierarchy.
void checkStatisticalHierarchy(const v1::RunSettings& run, const std::string& dataset);
// UsageError naming what a frame cannot ask of this run: a mode the run's
// renderer cannot draw or that EDL cannot shade, a mode not built yet,
// instanced on a dataset without sections, a level of detail that is not a
// positive finite number of pixels.
void checkFrameSettings(const v1::RunSettings& run, const v1::FrameSettings& frame);

}  // namespace pointillist
