// The reactive re-split: strips cover the area once and converge to equal times.
#include <gtest/gtest.h>

#include "display/core/load_equalizer.hpp"

namespace pointillist::display {
namespace {

TEST(LoadEqualizer, StripsCoverTheAreaExactlyOnce) {
  LoadEqualizer equalizer(4);
  const TileRect area = makeTileRect(10, 20, 301, 100);
  const auto strips = equalizer.split(area);
  ASSERT_EQ(strips.size(), 4u);
  std::uint32_t x = area.x();
  for (const auto& strip : strips) {
    EXPECT_EQ(strip.x(), x);
    EXPECT_EQ(strip.y(), area.y());
    EXPECT_EQ(strip.height(), area.height());
    x += strip.width();
  }
  EXPECT_EQ(x, area.x() + area.width());
}

TEST(LoadEqualizer, ConvergesToEqualTimesForAnUnevenScene) {
  // Work density over the screen: the left fifth is ten times as costly.
  const auto costOf = [](double from, double to) {
    const auto dense = [](double a, double b) { return std::max(0.0, std::min(b, 0.2) - a); };
    const double heavy = from < 0.2 ? dense(from, to) : 0.0;
    return 10.0 * heavy + ((to - from) - heavy);
  };
  LoadEqualizer equalizer(4, 0.5);
  double firstImbalance = 0.0, lastImbalance = 0.0;
  for (int frame = 0; frame < 30; ++frame) {
    const auto& b = equalizer.borders();
    std::vector<double> times;
    for (std::size_t i = 0; i + 1 < b.size(); ++i) times.push_back(costOf(b[i], b[i + 1]));
    const double mean = (times[0] + times[1] + times[2] + times[3]) / 4.0;
    const double imbalance = *std::max_element(times.begin(), times.end()) / mean;
    if (frame == 0) firstImbalance = imbalance;
    lastImbalance = imbalance;
    equalizer.update(times);
  }
  EXPECT_GT(firstImbalance, 2.0);
  EXPECT_LT(lastImbalance, 1.1);
  for (std::size_t i = 1; i < equalizer.borders().size(); ++i) {
    EXPECT_GT(equalizer.borders()[i], equalizer.borders()[i - 1]);
  }
}

}  // namespace
}  // namespace pointillist::display
