// The work-density grid that sizes tiles, and the regions scheduler's k-d
// tree of one region per render process: exact cover, work in proportion to
// leaves, and regions that stay put when the work does.
#include "display/core/region_tiling.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <random>

#include "display/core/tile_planner.hpp"
#include "display/core/work_density.hpp"
#include "tile_cover.hpp"

namespace pointillist::display {
namespace {

std::uint32_t below(std::mt19937& random, std::uint32_t bound) {
  return static_cast<std::uint32_t>(random() % bound);
}

double area(const TileRect& rect) {
  return static_cast<double>(rect.width()) * rect.height();
}

double overlap(const TileRect& a, const TileRect& b) {
  const auto x0 = std::max(a.x(), b.x());
  const auto y0 = std::max(a.y(), b.y());
  const auto x1 = std::min(a.x() + a.width(), b.x() + b.width());
  const auto y1 = std::min(a.y() + a.height(), b.y() + b.height());
  return x1 <= x0 || y1 <= y0 ? 0.0 : static_cast<double>(x1 - x0) * (y1 - y0);
}

// The estimate as the display made it before the grid, pixel by pixel: each
// tile's splats spread over it, unmeasured pixels at the mean, a 2 % floor.
double bruteWork(const TileRect& rect, const std::vector<TileFeedback>& tiles) {
  double work = 0.0, measuredArea = 0.0, measuredWork = 0.0, covered = 0.0;
  for (const TileFeedback& tile : tiles) {
    measuredArea += area(tile.rect);
    measuredWork += static_cast<double>(tile.splats);
    const double shared = overlap(rect, tile.rect);
    work += static_cast<double>(tile.splats) * shared / area(tile.rect);
    covered += shared;
  }
  const double mean = measuredWork / measuredArea;
  return work + mean * (area(rect) - covered + 0.02 * area(rect));
}

std::vector<TileFeedback> randomFeedback(std::mt19937& random, std::uint32_t width,
                                         std::uint32_t height) {
  // A grid of tiles over the left part of the frame, each with its own density.
  std::vector<TileFeedback> tiles;
  for (std::uint32_t y = 0; y + 37 <= height; y += 37) {
    for (std::uint32_t x = 0; x + 53 <= width * 2 / 3; x += 53) {
      tiles.push_back({makeTileRect(x, y, 53, 37), 0.0, below(random, 50'000)});
    }
  }
  return tiles;
}

TEST(WorkDensity, EqualsThePixelEstimateOnItsGridAndStaysCloseBetween) {
  std::mt19937 random(5);
  const std::uint32_t width = 640, height = 360;
  const auto tiles = randomFeedback(random, width, height);
  const WorkDensity exact(width, height, tiles);  // one cell per pixel fits
  ASSERT_EQ(exact.cellSide(), 1u);
  const WorkDensity coarse(width, height, tiles, 20'000);
  ASSERT_GT(coarse.cellSide(), 2u);
  for (int trial = 0; trial < 300; ++trial) {
    const std::uint32_t x = below(random, width), y = below(random, height);
    const TileRect rect =
        makeTileRect(x, y, 1 + below(random, width - x), 1 + below(random, height - y));
    const double expected = bruteWork(rect, tiles);
    EXPECT_NEAR(exact.work(rect), expected, 1e-6 * expected + 1e-6);
    // Coarse cells keep whole-cell sums exact; only partial cells are spread.
    const double edge = 2.0 * (rect.width() + rect.height()) * coarse.cellSide();
    const double densest = 50'000.0 / (53 * 37) * 1.02;
    EXPECT_NEAR(coarse.work(rect), expected, edge * densest);
  }
  // The whole frame's work is what was measured plus the unmeasured at the mean.
  const TileRect frame = makeTileRect(0, 0, width, height);
  EXPECT_NEAR(coarse.work(frame), bruteWork(frame, tiles), 1e-6 * bruteWork(frame, tiles));
  // No measurement: work is area.
  EXPECT_EQ(WorkDensity().work(makeTileRect(3, 4, 10, 20)), 200.0);
  // A floor on the cell side (the planner's, for large tiles) holds, and the
  // frame's work stays whole.
  const WorkDensity floored(width, height, tiles, 1u << 19, 10);
  EXPECT_EQ(floored.cellSide(), 10u);
  EXPECT_NEAR(floored.work(frame), bruteWork(frame, tiles), 1e-6 * bruteWork(frame, tiles));
}

// The planner rebuilds one grid every frame (its buffers stay): a grid
// rebuilt from another size, measurement and cell side holds what a fresh
// one holds, to the bit, and a rebuild with no measurement is area again.
TEST(WorkDensity, ARebuiltGridEqualsAFreshOne) {
  std::mt19937 random(9);
  WorkDensity reused(1920, 1080, randomFeedback(random, 1920, 1080), 1u << 19, 2);
  const struct {
    std::uint32_t width, height;
    std::size_t maxCells;
    std::uint32_t side;
  } grids[] = {{640, 360, 1u << 19, 1}, {1280, 720, 20'000, 1}, {320, 200, 1u << 19, 10}};
  for (const auto& grid : grids) {
    const auto tiles = randomFeedback(random, grid.width, grid.height);
    reused.rebuild(grid.width, grid.height, tiles, grid.maxCells, grid.side);
    const WorkDensity fresh(grid.width, grid.height, tiles, grid.maxCells, grid.side);
    ASSERT_EQ(reused.cellSide(), fresh.cellSide());
    for (int trial = 0; trial < 200; ++trial) {
      const std::uint32_t x = below(random, grid.width), y = below(random, grid.height);
      const TileRect rect =
          makeTileRect(x, y, 1 + below(random, grid.width - x), 1 + below(random, grid.height - y));
      EXPECT_EQ(reused.work(rect), fresh.work(rect)) << grid.width << "x" << grid.height;
    }
  }
  reused.rebuild(640, 360, {});
  EXPECT_FALSE(reused.measured());
  EXPECT_EQ(reused.work(makeTileRect(3, 4, 10, 20)), 200.0);
}

TEST(WorkDensity, CutsAtTheShareOfTheWork) {
  // Left half 9 splats per pixel, right half 1: half the work lies left of x = 56.
  const std::vector<TileFeedback> tiles{{makeTileRect(0, 0, 100, 10), 0.0, 9000},
                                        {makeTileRect(100, 0, 100, 10), 0.0, 1000}};
  const WorkDensity density(200, 10, tiles);
  const TileRect rect = makeTileRect(0, 0, 200, 10);
  const std::uint32_t cut = density.cutAt(rect, true, 0.5, 1, 199);
  EXPECT_NEAR(cut, 56, 1);
  EXPECT_NEAR(density.work(makeTileRect(0, 0, cut, 10)) / density.work(rect), 0.5, 0.01);
}

TEST(RegionTiling, CoversTheAreaExactlyWithOneRegionPerLeaf) {
  std::mt19937 random(7);
  RegionTiling tiling;
  const auto tiles = randomFeedback(random, 1280, 720);
  const WorkDensity density(1280, 720, tiles);
  for (std::uint32_t leaves : {1u, 2u, 3u, 7u, 64u, 255u, 1024u}) {
    for (int trial = 0; trial < 6; ++trial) {
      const std::uint32_t x = below(random, 600), y = below(random, 300);
      const TileRect area = makeTileRect(x, y, 1 + below(random, 680), 1 + below(random, 420));
      const auto regions = tiling.split(area, leaves, density, 8);
      ASSERT_EQ(regions.size(), leaves);
      expectExactCover(area, regions, true);
      const auto empty = std::count_if(regions.begin(), regions.end(), [](const TileRect& r) {
        return r.width() == 0 || r.height() == 0;
      });
      // A leaf goes without pixels only when the area has fewer pixels than leaves.
      if (area.width() * area.height() >= 4 * leaves) {
        EXPECT_EQ(empty, 0) << leaves;
      }
    }
  }
}

TEST(RegionTiling, RegionsHoldEqualWorkAndStayPutWhenTheWorkDoes) {
  std::mt19937 random(9);
  const auto tiles = randomFeedback(random, 1280, 720);
  const WorkDensity density(1280, 720, tiles);
  const TileRect frame = makeTileRect(0, 0, 1280, 720);
  RegionTiling tiling;
  const std::uint32_t leaves = 37;
  const auto regions = tiling.split(frame, leaves, density, 8);
  double total = 0.0, largest = 0.0;
  for (const TileRect& region : regions) {
    total += density.work(region);
    largest = std::max(largest, density.work(region));
  }
  EXPECT_LT(largest / (total / leaves), 1.15);
  // Same work, a slightly smaller area: every region keeps most of its pixels.
  const auto again = tiling.split(makeTileRect(0, 0, 1270, 712), leaves, density, 8);
  for (std::uint32_t leaf = 0; leaf < leaves; ++leaf) {
    EXPECT_GT(overlap(regions[leaf], again[leaf]), 0.7 * area(regions[leaf])) << leaf;
  }
}

TEST(TilePlanner, RegionsGiveEveryLiveRenderOneTileOfItsOwn) {
  TilePlanner planner({.scheduler = SchedulerKind::Regions, .renders = 6});
  const TileRect area = makeTileRect(20, 10, 400, 300);
  auto tiles = planner.plan(area);
  ASSERT_EQ(tiles.size(), 6u);
  ASSERT_EQ(planner.homes().size(), 6u);
  auto homes = planner.homes();
  std::sort(homes.begin(), homes.end());
  EXPECT_EQ(homes, (std::vector<std::uint32_t>{0, 1, 2, 3, 4, 5}));
  expectExactCover(area, tiles);
  EXPECT_FALSE(planner.assign(0).has_value());  // the frame keeps its homes

  planner.retireRender(2);
  tiles = planner.plan(area);
  ASSERT_EQ(tiles.size(), 5u);
  EXPECT_EQ(std::count(planner.homes().begin(), planner.homes().end(), 2u), 0);
  // Other schedulers have no homes.
  TilePlanner cost({.scheduler = SchedulerKind::Cost, .renders = 6});
  cost.plan(area);
  EXPECT_TRUE(cost.homes().empty());
}

}  // namespace
}  // namespace pointillist::display
