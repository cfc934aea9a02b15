// The display's tile layout per scheduler: exact cover always; for the cost
// scheduler, tiles sized so each holds about the same measured work.
#include "display/core/tile_planner.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <random>

#include "common/errors.hpp"
#include "tile_cover.hpp"

namespace pointillist::display {
namespace {

// Work that lives in one corner: splats per pixel are 100 in the left quarter
// of the area and 1 elsewhere.
std::uint64_t cornerWork(const TileRect& tile, const TileRect& area) {
  const std::uint32_t hotEnd = area.x() + area.width() / 4;
  std::uint64_t work = 0;
  for (std::uint32_t x = tile.x(); x < tile.x() + tile.width(); ++x) {
    work += (x < hotEnd ? 100u : 1u) * tile.height();
  }
  return work;
}

std::vector<TileFeedback> feedback(const std::vector<TileRect>& tiles, const TileRect& area) {
  std::vector<TileFeedback> result;
  for (const TileRect& tile : tiles) {
    const std::uint64_t splats = cornerWork(tile, area);
    result.push_back({tile, static_cast<double>(splats) * 1e-7, splats});
  }
  return result;
}

double maxOverMean(const std::vector<TileRect>& tiles, const TileRect& area) {
  std::uint64_t total = 0;
  std::uint64_t largest = 0;
  for (const TileRect& tile : tiles) {
    const std::uint64_t work = cornerWork(tile, area);
    total += work;
    largest = std::max(largest, work);
  }
  return static_cast<double>(largest) * static_cast<double>(tiles.size()) /
         static_cast<double>(total);
}

TEST(TilePlanner, EverySchedulerCoversTheAreaExactlyOnce) {
  std::mt19937 random(11);
  for (const auto kind : {SchedulerKind::Cost, SchedulerKind::RoundRobin, SchedulerKind::Static,
                          SchedulerKind::Equalizer, SchedulerKind::Regions}) {
    TilePlanner planner(
        {.scheduler = kind, .renders = 5, .tilesPerRender = 2.0, .minTileSize = 16});
    for (int trial = 0; trial < 40; ++trial) {
      const TileRect area = makeTileRect(static_cast<std::uint32_t>(random()) % 300,
                                         static_cast<std::uint32_t>(random()) % 200,
                                         1 + static_cast<std::uint32_t>(random()) % 900,
                                         1 + static_cast<std::uint32_t>(random()) % 600);
      const auto tiles = planner.plan(area);
      expectExactCover(area, tiles);
      planner.frameDone(feedback(tiles, area));
    }
  }
}

// The display's tuned tile count: the cost scheduler's tiles number
// tilesPerRender * renders over the divisor, still covering the area once,
// and the heavy region keeps the smaller tiles.
TEST(TilePlanner, ATileDivisorPlansFewerTilesThatStillCoverTheArea) {
  const TileRect area = makeTileRect(0, 0, 1280, 720);
  TilePlanner planner({.scheduler = SchedulerKind::Cost, .renders = 64, .tilesPerRender = 2.0});
  // Work in the left quarter only.
  std::vector<TileFeedback> measured;
  for (std::uint32_t x = 0; x < 1280; x += 80) {
    for (std::uint32_t y = 0; y < 720; y += 80) {
      measured.push_back({.rect = makeTileRect(x, y, 80, 80),
                          .seconds = x < 320 ? 1e-3 : 1e-6,
                          .splats = x < 320 ? 100'000u : 100u});
    }
  }
  planner.frameDone(measured);
  for (const std::uint64_t divisor : {1u, 2u, 4u, 8u, 128u, 100000u}) {
    const auto tiles = planner.plan(area, divisor);
    expectExactCover(area, tiles);
    EXPECT_EQ(tiles.size(), std::max<std::uint64_t>(1, 128 / divisor)) << "divisor " << divisor;
    if (divisor > 4) continue;
    std::size_t inHeavyPart = 0;
    for (const TileRect& tile : tiles) inHeavyPart += tile.x() + tile.width() <= 320;
    EXPECT_GT(inHeavyPart, tiles.size() / 2) << "divisor " << divisor;
  }
  // Other schedulers ignore it.
  TilePlanner grid({.scheduler = SchedulerKind::RoundRobin, .renders = 64, .tilesPerRender = 2.0});
  EXPECT_EQ(grid.plan(area, 4).size(), grid.plan(area, 1).size());
}

// The cost scheduler's cuts go to the heaviest tile first: a plan with fewer
// tiles is made of whole tiles of a plan with more (the tile tuner's levels
// differ by merges, not by new borders), each covering the box once. Where
// the minimum side stops the split short of the target (512 renders ask a
// 256x128 box for 1024 tiles; it holds at most 32 of 32x32), the plan is the
// tiles it holds, and dividing a target still above them changes nothing.
TEST(TilePlanner, FewerTilesAreTheFirstCutsOfMore) {
  const TileRect area = makeTileRect(0, 0, 256, 128);
  std::vector<TileFeedback> measured;
  for (std::uint32_t x = 0; x < 256; x += 16) {
    for (std::uint32_t y = 0; y < 128; y += 16) {
      measured.push_back({.rect = makeTileRect(x, y, 16, 16),
                          .seconds = 1e-6 * (1 + x + y),
                          .splats = 100u * (1 + x + y)});
    }
  }
  TilePlanner planner({.scheduler = SchedulerKind::Cost, .renders = 8, .tilesPerRender = 2.0});
  planner.frameDone(measured);
  std::vector<TileRect> finer = planner.plan(area, 1);
  EXPECT_EQ(finer.size(), 16u);
  expectExactCover(area, finer);
  for (const std::uint64_t divisor : {2u, 4u, 8u, 16u}) {
    const auto tiles = planner.plan(area, divisor);
    expectExactCover(area, tiles);
    EXPECT_EQ(tiles.size(), 16 / divisor) << "divisor " << divisor;
    for (const TileRect& fine : finer) {
      const auto holders = std::count_if(tiles.begin(), tiles.end(), [&](const TileRect& coarse) {
        return fine.x() >= coarse.x() && fine.y() >= coarse.y() &&
               fine.x() + fine.width() <= coarse.x() + coarse.width() &&
               fine.y() + fine.height() <= coarse.y() + coarse.height();
      });
      EXPECT_EQ(holders, 1) << "divisor " << divisor;
    }
    finer = tiles;
  }
  TilePlanner many({.scheduler = SchedulerKind::Cost, .renders = 512, .tilesPerRender = 2.0});
  many.frameDone(measured);
  const auto held = many.plan(area, 1);
  expectExactCover(area, held);
  EXPECT_GE(held.size(), 8u);  // cuts at the work's middle leave some tiles under 64 wide
  EXPECT_LE(held.size(), 32u);
  const auto halved = many.plan(area, 2);
  ASSERT_EQ(halved.size(), held.size());
  for (std::size_t i = 0; i < held.size(); ++i) {
    EXPECT_EQ(halved[i].SerializeAsString(), held[i].SerializeAsString()) << "tile " << i;
  }
}

TEST(TilePlanner, CostTilesFollowTheMeasuredWork) {
  const TileRect area = makeTileRect(0, 0, 1280, 720);
  TilePlanner balanced({.scheduler = SchedulerKind::Cost, .renders = 4, .tilesPerRender = 2.0});
  TilePlanner grid({.scheduler = SchedulerKind::Cost,
                    .renders = 4,
                    .tilesPerRender = 2.0,
                    .balancedTiles = false});
  // Without feedback the balanced split cuts by area, like the grid.
  auto tiles = balanced.plan(area);
  EXPECT_EQ(tiles.size(), 8u);
  expectExactCover(area, tiles);
  const auto gridTiles = grid.plan(area);
  EXPECT_GT(maxOverMean(gridTiles, area), 2.5);  // the hot corner is in one or two tiles

  balanced.frameDone(feedback(tiles, area));
  tiles = balanced.plan(area);
  expectExactCover(area, tiles);
  EXPECT_EQ(tiles.size(), 8u);
  // One frame of feedback is enough to spread the corner's work over tiles.
  EXPECT_LT(maxOverMean(tiles, area), 1.35);
  // Heaviest tile first, so long packets start early.
  for (std::size_t i = 1; i < tiles.size(); ++i) {
    EXPECT_GE(cornerWork(tiles[i - 1], area) * 105 / 100, cornerWork(tiles[i], area));
  }
}

TEST(TilePlanner, NewGroundStillGetsTiles) {
  // Feedback measured on the left half only; the right half (the view moved)
  // must still be split, not handed out as one huge tile.
  const TileRect area = makeTileRect(0, 0, 1000, 500);
  TilePlanner planner({.scheduler = SchedulerKind::Cost, .renders = 4, .tilesPerRender = 2.0});
  const TileFeedback left{makeTileRect(0, 0, 500, 500), 0.01, 100'000};
  planner.frameDone(std::span<const TileFeedback>(&left, 1));
  const auto tiles = planner.plan(area);
  expectExactCover(area, tiles);
  const auto onRight = std::count_if(tiles.begin(), tiles.end(),
                                     [](const TileRect& tile) { return tile.x() >= 500; });
  EXPECT_GE(onRight, 1);
  for (const TileRect& tile : tiles) {
    EXPECT_LE(tile.width() * tile.height(), 500u * 500u);
  }
}

TEST(TilePlanner, TinyAreasAreNotCutBelowTheMinimumTile) {
  TilePlanner planner({.scheduler = SchedulerKind::Cost, .renders = 8, .minTileSize = 32});
  const TileRect area = makeTileRect(10, 10, 70, 40);
  const auto tiles = planner.plan(area);
  expectExactCover(area, tiles);
  EXPECT_EQ(tiles.size(), 2u);  // 70 px splits once into 35 + 35; 40 px not at all
}

TEST(TilePlanner, BaselinesAssignRendersTheCostSchedulerLeavesItToTheTraverse) {
  TilePlanner roundRobin({.scheduler = SchedulerKind::RoundRobin, .renders = 3});
  EXPECT_EQ(roundRobin.assign(7), 0u);
  EXPECT_EQ(roundRobin.assign(7), 1u);
  EXPECT_EQ(roundRobin.assign(0), 2u);
  EXPECT_EQ(roundRobin.assign(0), 0u);
  TilePlanner fixed({.scheduler = SchedulerKind::Static, .renders = 3});
  EXPECT_EQ(fixed.assign(7), 1u);
  EXPECT_EQ(fixed.assign(7), 1u);
  TilePlanner cost({.scheduler = SchedulerKind::Cost, .renders = 3});
  EXPECT_FALSE(cost.assign(0).has_value());
}

TEST(TilePlanner, EqualizerStripsFollowTheStripTimes) {
  const TileRect area = makeTileRect(0, 0, 1200, 600);
  TilePlanner planner({.scheduler = SchedulerKind::Equalizer, .renders = 3});
  auto strips = planner.plan(area);
  ASSERT_EQ(strips.size(), 3u);
  EXPECT_EQ(strips[0].width(), 400u);
  // The first strip took three times as long: it narrows.
  const TileFeedback times[] = {{strips[0], 0.3, 3}, {strips[1], 0.1, 1}, {strips[2], 0.1, 1}};
  planner.frameDone(times);
  strips = planner.plan(area);
  expectExactCover(area, strips);
  EXPECT_LT(strips[0].width(), 400u);
}

TEST(TilePlanner, NamesRoundTripAndUnknownNamesAreRefused) {
  for (const auto kind : {SchedulerKind::Cost, SchedulerKind::RoundRobin, SchedulerKind::Static,
                          SchedulerKind::Equalizer, SchedulerKind::Regions}) {
    EXPECT_EQ(parseSchedulerKind(schedulerName(kind)), kind);
  }
  EXPECT_THROW(parseSchedulerKind("fastest"), UsageError);
  EXPECT_THROW(TilePlanner({.renders = 0}), UsageError);
}

// A lost render process: later plans are cut for the ones left, the baseline
// schedulers assign only live ones, and the last one cannot go.
TEST(TilePlanner, ARetiredRenderGetsNoTilesAndPlansShrink) {
  const TileRect area = makeTileRect(0, 0, 640, 360);
  TilePlanner roundRobin(
      {.scheduler = SchedulerKind::RoundRobin, .renders = 3, .tilesPerRender = 2.0});
  const std::size_t before = roundRobin.plan(area).size();
  roundRobin.retireRender(1);
  roundRobin.retireRender(1);  // twice: no change
  EXPECT_EQ(roundRobin.liveRenders(), 2u);
  const auto tiles = roundRobin.plan(area);
  EXPECT_LT(tiles.size(), before);  // two tiles per live render
  expectExactCover(area, tiles);
  for (int i = 0; i < 8; ++i) EXPECT_NE(roundRobin.assign(static_cast<std::uint32_t>(i)), 1u);
  TilePlanner fixed({.scheduler = SchedulerKind::Static, .renders = 3});
  fixed.retireRender(0);
  for (std::uint32_t i = 0; i < 6; ++i) EXPECT_NE(fixed.assign(i), 0u);
  fixed.retireRender(2);
  EXPECT_EQ(fixed.assign(5), 1u);
  EXPECT_THROW(fixed.retireRender(1), UsageError);
  TilePlanner equalizer({.scheduler = SchedulerKind::Equalizer, .renders = 3});
  equalizer.retireRender(2);
  expectExactCover(area, equalizer.plan(area));
}

}  // namespace
}  // namespace pointillist::display
