#pragma once
// Shared by the display's tiling tests: tiles cover an area exactly once.
#include <gtest/gtest.h>

#include <vector>

#include "common/camera.hpp"

namespace pointillist::display {

// Every pixel of `area` lies in exactly one tile, and every tile inside it.
// Empty tiles are allowed only when `allowEmpty` (a region tree with more
// leaves than pixels).
inline void expectExactCover(const TileRect& area, const std::vector<TileRect>& tiles,
                             bool allowEmpty = false) {
  std::vector<int> hits(static_cast<std::size_t>(area.width()) * area.height(), 0);
  for (const TileRect& tile : tiles) {
    if (allowEmpty && (tile.width() == 0 || tile.height() == 0)) continue;
    ASSERT_GT(tile.width(), 0u);
    ASSERT_GT(tile.height(), 0u);
    ASSERT_GE(tile.x(), area.x());
    ASSERT_GE(tile.y(), area.y());
    ASSERT_LE(tile.x() + tile.width(), area.x() + area.width());
    ASSERT_LE(tile.y() + tile.height(), area.y() + area.height());
    for (std::uint32_t y = tile.y(); y < tile.y() + tile.height(); ++y) {
      for (std::uint32_t x = tile.x(); x < tile.x() + tile.width(); ++x) {
        ++hits[(y - area.y()) * area.width() + (x - area.x())];
      }
    }
  }
  for (int count : hits) ASSERT_EQ(count, 1);
}

}  // namespace pointillist::display
