// Mini frusta: the box of interest and tiles that cover it exactly once.
#include <gtest/gtest.h>

#include <random>

#include "display/core/tiling.hpp"

namespace pointillist::display {
namespace {

using namespace std::chrono_literals;

void expectExactCover(const TileRect& area, const std::vector<TileRect>& tiles) {
  std::vector<int> hits(static_cast<std::size_t>(area.width()) * area.height(), 0);
  for (const TileRect& tile : tiles) {
    ASSERT_GT(tile.width(), 0u);
    ASSERT_GT(tile.height(), 0u);
    for (std::uint32_t y = tile.y(); y < tile.y() + tile.height(); ++y) {
      for (std::uint32_t x = tile.x(); x < tile.x() + tile.width(); ++x) {
        ASSERT_GE(x, area.x());
        ASSERT_LT(x, area.x() + area.width());
        ASSERT_GE(y, area.y());
        ASSERT_LT(y, area.y() + area.height());
        ++hits[(y - area.y()) * area.width() + (x - area.x())];
      }
    }
  }
  for (int count : hits) ASSERT_EQ(count, 1);
}

TEST(Tiling, TilesCoverTheBoxOfInterestExactlyOnce) {
  std::mt19937 random(5);
  for (int trial = 0; trial < 200; ++trial) {
    const TileRect area = makeTileRect(static_cast<std::uint32_t>(random()) % 300,
                                       static_cast<std::uint32_t>(random()) % 200,
                                       1 + static_cast<std::uint32_t>(random()) % 700,
                                       1 + static_cast<std::uint32_t>(random()) % 500);
    const std::uint32_t target = 1 + static_cast<std::uint32_t>(random()) % 40;
    const auto tiles = splitIntoTiles(area, target, 16);
    expectExactCover(area, tiles);
    if (area.width() >= 16 * 8 && area.height() >= 16 * 8) {
      EXPECT_GE(tiles.size() * 2 + 2, target) << "roughly the requested count";
      EXPECT_LE(tiles.size(), target * 2 + 2);
    }
    for (const auto& tile : tiles) {
      if (area.width() >= 16) {
        EXPECT_GE(tile.width(), 8u);
      }
    }
  }
}

TEST(Tiling, BoxOfInterestContainsTheProjectedBox) {
  const glm::vec3 low(-1, -1, -1), high(1, 1, 1);
  const Camera camera = cameraForBounds(low, high, 640, 480, 30.0f, 20.0f, 2.0f);
  const auto area = boxOfInterest(camera, low, high, 0.0f);
  ASSERT_TRUE(area.has_value());
  EXPECT_LT(area->width(), 640u);  // far away: a part of the frame
  for (int corner = 0; corner < 8; ++corner) {
    const glm::vec3 p((corner & 1) ? high.x : low.x, (corner & 2) ? high.y : low.y,
                      (corner & 4) ? high.z : low.z);
    const glm::vec4 w = projectToWindow(camera, p);
    EXPECT_GE(w.x, static_cast<float>(area->x()));
    EXPECT_LE(w.x, static_cast<float>(area->x() + area->width()));
    EXPECT_GE(w.y, static_cast<float>(area->y()));
    EXPECT_LE(w.y, static_cast<float>(area->y() + area->height()));
  }
  // Looking away: nothing to draw. Eye inside: the whole frame.
  const Camera away = makeCamera({0, 0, 10}, {0, 0, 20}, {0, 1, 0}, 45.0f, 0.1f, 100.0f, 64, 64);
  EXPECT_FALSE(boxOfInterest(away, low, high, 0.0f).has_value());
  const Camera inside = makeCamera({0, 0, 0}, {0, 0, 1}, {0, 1, 0}, 45.0f, 0.1f, 100.0f, 64, 64);
  const auto all = boxOfInterest(inside, low, high, 0.0f);
  ASSERT_TRUE(all.has_value());
  EXPECT_EQ(all->width(), 64u);
  EXPECT_EQ(all->height(), 64u);
}

}  // namespace
}  // namespace pointillist::display
