#pragma once
// How the display lays out each frame's tiles and, for the baseline schedulers,
// which render process draws each tile (MPI-free; the simulator drives it too).
//
//   cost        seed 003: tiles sized so each holds about the same work, as
//               measured on the last completed frame; the traverse picks the
//               render process with the cost function.
//   round-robin equal tiles handed out in turn.
//   static      equal tiles, tile i always to render i mod R.
//   equalizer   one strip per render, borders moved from last frame's times.
//   regions     one region per render, a k-d tree of cuts that split last
//               frame's work in proportion and keep their place and axis
//               from frame to frame (region_tiling.hpp); the traverse keeps a
//               tile on its region's render unless that one is overloaded.
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "common/camera.hpp"
#include "display/core/load_equalizer.hpp"
#include "display/core/region_tiling.hpp"

namespace pointillist::display {

enum class SchedulerKind { Cost, RoundRobin, Static, Equalizer, Regions };

// Throws UsageError naming the accepted names.
SchedulerKind parseSchedulerKind(const std::string& name);
std::string schedulerName(SchedulerKind kind);
v1::Scheduler schedulerMessage(SchedulerKind kind);
SchedulerKind schedulerKindOf(v1::Scheduler scheduler);  // UsageError for an unknown value

struct TilePlanOptions {
  SchedulerKind scheduler = SchedulerKind::Cost;
  std::uint32_t renders = 1;
  double tilesPerRender = 2.0;
  std::uint32_t minTileSize = 32;
  // Cost scheduler: size tiles by last frame's measured work (off: equal grid).
  bool balancedTiles = true;
};

class TilePlanner {
 public:
  explicit TilePlanner(const TilePlanOptions& options);

  // Tiles covering `area` exactly once. The cost scheduler's sized tiles
  // number tilesPerRender * renders / `tileDivisor` (the display's tuned
  // tile count, FrameRateTuner), at least one, or as many as the area holds
  // at the minimum side where that is fewer. Fewer tiles are the first cuts
  // of more (the same cuts, heaviest first).
  std::vector<TileRect> plan(const TileRect& area, std::uint64_t tileDivisor = 1);
  // For the last plan() of the regions scheduler, the render process (index
  // among renders) whose region each tile is; empty for the others.
  const std::vector<std::uint32_t>& homes() const { return homes_; }
  // The render process (index among renders) that draws tile `tileIndex` of
  // its frame, asked when the tile is handed out (round-robin deals in that
  // order); nullopt when the traverse decides (cost).
  std::optional<std::uint32_t> assign(std::uint32_t tileIndex);
  // Feedback from a completed frame, tiles in the order plan() gave them.
  void frameDone(std::span<const TileFeedback> tiles);
  // Render process `render` (index among renders) is gone: later frames are
  // planned for the others and no tile is assigned to it. The equalizer
  // starts again from even strips. UsageError when it was the last one.
  void retireRender(std::uint32_t render);
  std::uint32_t liveRenders() const { return static_cast<std::uint32_t>(live_.size()); }
  // The part size heavy tiles are split into: last frame's splats (or, before
  // a frame was measured, `unmeasured`, a guess) over the live renders, so a
  // tile holding two renders' share of a frame is split; at least `minimum`
  // (cost and regions only). The first frames split too, since where their
  // parts go sets where cells are cached from then on.
  std::uint64_t partSplats(std::uint64_t minimum, std::uint64_t unmeasured) const;

  const TilePlanOptions& options() const { return options_; }
  // Frames planned from now on use `kind` (a served client chose it); what
  // was measured so far still sizes their tiles.
  void setScheduler(SchedulerKind kind) { options_.scheduler = kind; }

 private:
  std::vector<TileRect> balancedSplit(const TileRect& area, std::uint32_t target);
  std::vector<TileRect> regionSplit(const TileRect& area);
  // The grid of the last frame's work for `area`, rebuilt in densityGrid_.
  const WorkDensity& densityFor(const TileRect& area);
  std::uint32_t tileTarget(std::uint64_t tileDivisor) const;

  TilePlanOptions options_;
  LoadEqualizer equalizer_;
  std::uint64_t roundRobin_ = 0;
  std::vector<TileFeedback> density_;  // last completed frame, splats spread over each rect
  // Kept from frame to frame: a fresh 4K grid faults in about 3000 pages.
  WorkDensity densityGrid_;
  bool equalizerStrips_ = false;     // the last plan used the equalizer's strips
  std::vector<std::uint32_t> live_;  // render indices still in the job
  RegionTiling regions_;
  std::vector<std::uint32_t> homes_;  // the last plan's, regions scheduler only
};

}  // namespace pointillist::display
