#include "display/core/tile_planner.hpp"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <queue>

#include "common/errors.hpp"
#include "common/run_settings.hpp"
#include "display/core/tiling.hpp"

namespace pointillist::display {
namespace {

// The two halves of `rect` cut `offset` pixels along its longer side.
std::pair<TileRect, TileRect> cut(const TileRect& rect, std::uint32_t offset) {
  if (rect.width() >= rect.height()) {
    return {makeTileRect(rect.x(), rect.y(), offset, rect.height()),
            makeTileRect(rect.x() + offset, rect.y(), rect.width() - offset, rect.height())};
  }
  return {makeTileRect(rect.x(), rect.y(), rect.width(), offset),
          makeTileRect(rect.x(), rect.y() + offset, rect.width(), rect.height() - offset)};
}

}  // namespace

SchedulerKind parseSchedulerKind(const std::string& name) {
  return schedulerKindOf(parseScheduler(name));
}

v1::Scheduler schedulerMessage(SchedulerKind kind) {
  switch (kind) {
    case SchedulerKind::Cost:
      return v1::SCHEDULER_COST;
    case SchedulerKind::RoundRobin:
      return v1::SCHEDULER_ROUND_ROBIN;
    case SchedulerKind::Static:
      return v1::SCHEDULER_STATIC;
    case SchedulerKind::Equalizer:
      return v1::SCHEDULER_EQUALIZER;
    case SchedulerKind::Regions:
      return v1::SCHEDULER_REGIONS;
  }
  return v1::SCHEDULER_COST;
}

SchedulerKind schedulerKindOf(v1::Scheduler scheduler) {
  switch (scheduler) {
    case v1::SCHEDULER_ROUND_ROBIN:
      return SchedulerKind::RoundRobin;
    case v1::SCHEDULER_STATIC:
      return SchedulerKind::Static;
    case v1::SCHEDULER_EQUALIZER:
      return SchedulerKind::Equalizer;
    case v1::SCHEDULER_COST:
      return SchedulerKind::Cost;
    case v1::SCHEDULER_REGIONS:
      return SchedulerKind::Regions;
    default:
      break;
  }
  throw UsageError("unknown scheduler " + std::to_string(scheduler));
}

std::string schedulerName(SchedulerKind kind) {
  return pointillist::schedulerName(schedulerMessage(kind));
}

TilePlanner::TilePlanner(const TilePlanOptions& options)
    : options_(options), equalizer_(std::max<std::uint32_t>(1, options.renders)) {
  if (options.renders == 0) throw UsageError("tile planning needs at least one render process");
  if (!(options.tilesPerRender > 0.0)) throw UsageError("--tiles-per-render must be positive");
  for (std::uint32_t render = 0; render < options.renders; ++render) live_.push_back(render);
}

void TilePlanner::retireRender(std::uint32_t render) {
  const auto found = std::find(live_.begin(), live_.end(), render);
  if (found == live_.end()) return;
  if (live_.size() == 1) throw UsageError("the last render process cannot be retired");
  live_.erase(found);
  equalizer_ = LoadEqualizer(static_cast<std::uint32_t>(live_.size()));
  equalizerStrips_ = false;
}

std::uint32_t TilePlanner::tileTarget(std::uint64_t tileDivisor) const {
  return static_cast<std::uint32_t>(
      std::max(1.0, std::round(options_.tilesPerRender * static_cast<double>(live_.size()) /
                               static_cast<double>(std::max<std::uint64_t>(1, tileDivisor)))));
}

std::vector<TileRect> TilePlanner::plan(const TileRect& area, std::uint64_t tileDivisor) {
  equalizerStrips_ = false;
  homes_.clear();
  if (area.width() == 0 || area.height() == 0) return {};
  if (options_.scheduler == SchedulerKind::Regions) return regionSplit(area);
  if (options_.scheduler == SchedulerKind::Equalizer) {
    auto strips = equalizer_.split(area);
    const bool emptyStrip = std::any_of(strips.begin(), strips.end(), [](const TileRect& tile) {
      return tile.width() == 0 || tile.height() == 0;
    });
    if (!emptyStrip) {
      equalizerStrips_ = true;
      return strips;
    }
  }
  if (options_.scheduler == SchedulerKind::Cost && options_.balancedTiles) {
    return balancedSplit(area, tileTarget(tileDivisor));
  }
  return splitIntoTiles(area, tileTarget(1), options_.minTileSize);
}

std::optional<std::uint32_t> TilePlanner::assign(std::uint32_t tileIndex) {
  switch (options_.scheduler) {
    case SchedulerKind::RoundRobin:
      return live_[roundRobin_++ % live_.size()];
    case SchedulerKind::Static:
    case SchedulerKind::Equalizer:
      return live_[tileIndex % live_.size()];
    case SchedulerKind::Cost:
    case SchedulerKind::Regions:  // homes(), kept per frame by the caller
      break;
  }
  return std::nullopt;
}

void TilePlanner::frameDone(std::span<const TileFeedback> tiles) {
  if (options_.scheduler == SchedulerKind::Equalizer && equalizerStrips_ &&
      tiles.size() == equalizer_.strips()) {
    std::vector<double> seconds;
    seconds.reserve(tiles.size());
    for (const TileFeedback& tile : tiles) seconds.push_back(tile.seconds);
    equalizer_.update(seconds);
  }
  if (options_.scheduler == SchedulerKind::Cost || options_.scheduler == SchedulerKind::Regions) {
    density_.assign(tiles.begin(), tiles.end());
  }
}

std::uint64_t TilePlanner::partSplats(std::uint64_t minimum, std::uint64_t unmeasured) const {
  std::uint64_t splats = 0;
  for (const TileFeedback& tile : density_) splats += tile.splats;
  if (splats == 0) splats = unmeasured;
  const double renders = std::max<double>(1.0, static_cast<double>(live_.size()));
  return std::max(minimum, static_cast<std::uint64_t>(static_cast<double>(splats) / renders));
}

std::vector<TileRect> TilePlanner::balancedSplit(const TileRect& area, std::uint32_t target) {
  // Repeatedly halve the heaviest tile at the cut that splits its estimated
  // work evenly (a k-d split of the measured work), so no tile holds much more
  // than total/target. Tiles too small to cut are left whole.
  const std::uint32_t minSide = std::max<std::uint32_t>(1, options_.minTileSize);
  struct Piece {
    TileRect rect;
    double work = 0.0;
  };
  const WorkDensity& density = densityFor(area);
  std::vector<Piece> pieces{{area, density.work(area)}};
  // Pieces that may still be cut, heaviest on top and, among equals, the
  // first in `pieces`: a plan with fewer tiles is a prefix of one with more.
  const auto lighter = [&pieces](std::uint32_t a, std::uint32_t b) {
    if (pieces[a].work != pieces[b].work) return pieces[a].work < pieces[b].work;
    return a > b;
  };
  std::priority_queue<std::uint32_t, std::vector<std::uint32_t>, decltype(lighter)> open(lighter);
  open.push(0);
  while (pieces.size() < target && !open.empty()) {
    const std::uint32_t heaviest = open.top();
    open.pop();
    const TileRect rect = pieces[heaviest].rect;
    const std::uint32_t length = std::max(rect.width(), rect.height());
    if (length < 2 * minSide) continue;  // stays whole
    const std::uint32_t offset =
        density.cutAt(rect, rect.width() >= rect.height(), 0.5, minSide, length - minSide);
    const auto [first, second] = cut(rect, offset);
    pieces[heaviest] = {first, density.work(first)};
    pieces.push_back({second, density.work(second)});
    open.push(heaviest);
    open.push(static_cast<std::uint32_t>(pieces.size() - 1));
  }
  // Heaviest first, so the longest packets start early and the light ones fill
  // the gaps at the end of the frame.
  std::stable_sort(pieces.begin(), pieces.end(),
                   [](const Piece& a, const Piece& b) { return a.work > b.work; });
  std::vector<TileRect> tiles;
  tiles.reserve(pieces.size());
  for (const Piece& piece : pieces) tiles.push_back(piece.rect);
  return tiles;
}

std::vector<TileRect> TilePlanner::regionSplit(const TileRect& area) {
  const WorkDensity& density = densityFor(area);
  const auto leaves = static_cast<std::uint32_t>(live_.size());
  const std::vector<TileRect> rects = regions_.split(area, leaves, density, options_.minTileSize);
  struct Region {
    TileRect rect;
    std::uint32_t home = 0;
    double work = 0.0;
  };
  std::vector<Region> regions;
  regions.reserve(rects.size());
  for (std::uint32_t leaf = 0; leaf < leaves; ++leaf) {
    if (rects[leaf].width() == 0 || rects[leaf].height() == 0) continue;
    regions.push_back({rects[leaf], live_[leaf], density.work(rects[leaf])});
  }
  // Heaviest first, as the cost scheduler hands them out.
  std::stable_sort(regions.begin(), regions.end(),
                   [](const Region& a, const Region& b) { return a.work > b.work; });
  std::vector<TileRect> tiles;
  tiles.reserve(regions.size());
  for (const Region& region : regions) {
    tiles.push_back(region.rect);
    homes_.push_back(region.home);
  }
  return tiles;
}

const WorkDensity& TilePlanner::densityFor(const TileRect& area) {
  // The grid spans the frame as far as this area and the last frame's tiles reach.
  std::uint32_t width = area.x() + area.width();
  std::uint32_t height = area.y() + area.height();
  for (const TileFeedback& tile : density_) {
    width = std::max(width, tile.rect.x() + tile.rect.width());
    height = std::max(height, tile.rect.y() + tile.rect.height());
  }
  // Cells a 32nd of the mean tile's side: the cuts stay as fine, and large
  // tiles (few render processes) do not pay for a grid of small ones.
  const double tiles = std::max(1.0, options_.tilesPerRender * static_cast<double>(live_.size()));
  const double meanSide = std::sqrt(static_cast<double>(area.width()) * area.height() / tiles);
  const auto side = static_cast<std::uint32_t>(std::clamp(meanSide / 32.0, 1.0, 64.0));
  densityGrid_.rebuild(width, height, density_, 1u << 19, side);
  return densityGrid_;
}

}  // namespace pointillist::display
