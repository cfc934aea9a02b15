// Key figures of a run: per-frame imbalance against imbalance over the run.
#include "display/core/frame_stats.hpp"

#include <gtest/gtest.h>

namespace pointillist::display {
namespace {

FrameRecord frame(std::uint64_t index, double end, std::map<int, double> busy) {
  FrameRecord record;
  record.frame = index;
  record.startSeconds = end - 0.1;
  record.endSeconds = end;
  for (const auto& [rank, seconds] : busy) {
    record.busySecondsPerRender[rank] = seconds;
    record.splatsPerRender[rank] = static_cast<std::uint64_t>(seconds * 1e6);
    record.splats += static_cast<std::uint64_t>(seconds * 1e6);
  }
  return record;
}

TEST(FrameStats, PipelinedFramesAreUnevenPerFrameButEvenOverTheRun) {
  // Two render processes take turns: each frame is drawn by one of them alone,
  // yet over the run both were busy the same time.
  RunStats stats;
  stats.layout = "1,1,1,2";
  // 17 frames: the steady ones (3..16) are an even count, 7 for each.
  for (std::uint64_t i = 0; i < 17; ++i) {
    const int rank = 4 + static_cast<int>(i % 2);
    stats.frames.push_back(
        frame(i, 0.1 * static_cast<double>(i + 1), {{rank, 0.05}, {9 - rank, 0.0}}));
  }
  const KeyFigures k = stats.keyFigures();
  EXPECT_EQ(k.renderProcesses, 2u);
  EXPECT_NEAR(k.imbalanceBusy, 2.0, 1e-9);
  EXPECT_NEAR(k.imbalanceBusyRun, 1.0, 1e-9);
}

TEST(FrameStats, ARenderThatNeverWorkedCountsAgainstTheRun) {
  RunStats stats;
  stats.layout = "1,1,1,4";  // four render processes, one never drew anything
  for (std::uint64_t i = 0; i < 16; ++i) {
    stats.frames.push_back(
        frame(i, 0.1 * static_cast<double>(i + 1), {{4, 0.03}, {5, 0.03}, {6, 0.03}}));
  }
  const KeyFigures k = stats.keyFigures();
  EXPECT_NEAR(k.imbalanceBusyRun, 4.0 / 3.0, 1e-9);
}

TEST(FrameStats, ARenderLostBeforeAFrameBeganHasNoShareInItsBalance) {
  RunStats stats;
  stats.layout = "1,1,1,3";
  // Renders 4-6; render 6 is lost at 1.0 s and the others split the work.
  stats.frames.push_back(frame(0, 0.5, {{4, 0.1}, {5, 0.1}, {6, 0.1}}));
  stats.frames.push_back(frame(1, 1.5, {{4, 0.1}, {5, 0.1}, {6, 0.0}}));
  stats.lost.push_back({"render", 6, 1.0, "no word from it for 5.0 s", true});
  EXPECT_DOUBLE_EQ(*stats.balance(stats.frames[0]).busy, 1.0);
  EXPECT_DOUBLE_EQ(*stats.balance(stats.frames[1]).busy, 1.0);  // two processes left, even
  stats.lost.back().seconds = 1.45;  // lost while frame 1 was being drawn: it counts
  EXPECT_DOUBLE_EQ(*stats.balance(stats.frames[1]).busy, 1.5);
}

}  // namespace
}  // namespace pointillist::display
