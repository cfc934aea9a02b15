#include "display/core/tile_planner.hpp"

#include <algorithm>
#include <cmath>
#include <numeric>

#include "common/errors.hpp"
#include "common/run_settings.hpp"
#include "display/core/tiling.hpp"

namespace pointillist::display {
namespace {

double area(const TileRect& rect) {
  return static_cast<double>(rect.width()) * static_cast<double>(rect.height());
}

double overlapArea(const TileRect& a, const TileRect& b) {
  const auto x0 = std::max(a.x(), b.x());
  const auto y0 = std::max(a.y(), b.y());
  const auto x1 = std::min(a.x() + a.width(), b.x() + b.width());
  const auto y1 = std::min(a.y() + a.height(), b.y() + b.height());
  if (x1 <= x0 || y1 <= y0) return 0.0;
  return static_cast<double>(x1 - x0) * static_cast<double>(y1 - y0);
}

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

std::vector<TileRect> TilePlanner::plan(const TileRect& area) {
  equalizerStrips_ = false;
  if (area.width() == 0 || area.height() == 0) return {};
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
  const auto target = static_cast<std::uint32_t>(
      std::max(1.0, std::round(options_.tilesPerRender * static_cast<double>(live_.size()))));
  if (options_.scheduler == SchedulerKind::Cost && options_.balancedTiles) {
    return balancedSplit(area, target);
  }
  return splitIntoTiles(area, target, options_.minTileSize);
}

std::optional<std::uint32_t> TilePlanner::assign(std::uint32_t tileIndex) {
  switch (options_.scheduler) {
    case SchedulerKind::RoundRobin:
      return live_[roundRobin_++ % live_.size()];
    case SchedulerKind::Static:
    case SchedulerKind::Equalizer:
      return live_[tileIndex % live_.size()];
    case SchedulerKind::Cost:
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
  if (options_.scheduler == SchedulerKind::Cost) density_.assign(tiles.begin(), tiles.end());
}

double TilePlanner::estimatedWork(const TileRect& rect) const {
  // Splats of the last completed frame, spread evenly over each tile they came
  // from. Pixels no tile measured (the view moved onto new ground) are taken
  // at the mean measured density: their work is unknown, not absent. A small
  // floor keeps measured-empty ground splittable.
  double work = 0.0;
  double measuredArea = 0.0;
  double measuredWork = 0.0;
  double coveredArea = 0.0;
  for (const TileFeedback& tile : density_) {
    const double tileArea = area(tile.rect);
    if (tileArea <= 0.0) continue;
    measuredArea += tileArea;
    measuredWork += static_cast<double>(tile.splats);
    const double shared = overlapArea(rect, tile.rect);
    if (shared > 0.0) {
      work += static_cast<double>(tile.splats) * shared / tileArea;
      coveredArea += shared;
    }
  }
  if (measuredArea <= 0.0 || measuredWork <= 0.0) return area(rect);
  const double meanDensity = measuredWork / measuredArea;
  const double unmeasured = std::max(0.0, area(rect) - coveredArea);
  return work + meanDensity * (unmeasured + 0.02 * area(rect));
}

std::vector<TileRect> TilePlanner::balancedSplit(const TileRect& area, std::uint32_t target) const {
  // Repeatedly halve the heaviest tile at the cut that splits its estimated
  // work evenly (a k-d split of the measured work), so no tile holds much more
  // than total/target. Tiles too small to cut are left whole.
  const std::uint32_t minSide = std::max<std::uint32_t>(1, options_.minTileSize);
  struct Piece {
    TileRect rect;
    double work = 0.0;
    bool splittable = true;
  };
  std::vector<Piece> pieces{{area, estimatedWork(area), true}};
  while (pieces.size() < target) {
    auto heaviest = pieces.end();
    for (auto it = pieces.begin(); it != pieces.end(); ++it) {
      if (it->splittable && (heaviest == pieces.end() || it->work > heaviest->work)) heaviest = it;
    }
    if (heaviest == pieces.end()) break;
    const TileRect rect = heaviest->rect;
    const std::uint32_t length = std::max(rect.width(), rect.height());
    if (length < 2 * minSide) {
      heaviest->splittable = false;
      continue;
    }
    // Work on the low side grows with the cut: bisect for half the work.
    std::uint32_t low = minSide;
    std::uint32_t high = length - minSide;
    const double half = heaviest->work / 2.0;
    while (low < high) {
      const std::uint32_t middle = low + (high - low) / 2;
      if (estimatedWork(cut(rect, middle).first) < half) {
        low = middle + 1;
      } else {
        high = middle;
      }
    }
    const auto [first, second] = cut(rect, low);
    *heaviest = {first, estimatedWork(first), true};
    pieces.push_back({second, estimatedWork(second), true});
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

}  // namespace pointillist::display
