// Key figures of a run: per-frame imbalance against imbalance over the run.
#include "display/core/frame_stats.hpp"

#include <gtest/gtest.h>

#include "common/errors.hpp"

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
    stats.addFrame(frame(i, 0.1 * static_cast<double>(i + 1), {{rank, 0.05}, {9 - rank, 0.0}}));
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
    stats.addFrame(frame(i, 0.1 * static_cast<double>(i + 1), {{4, 0.03}, {5, 0.03}, {6, 0.03}}));
  }
  const KeyFigures k = stats.keyFigures();
  EXPECT_NEAR(k.imbalanceBusyRun, 4.0 / 3.0, 1e-9);
}

TEST(FrameStats, ARenderLostBeforeAFrameBeganHasNoShareInItsBalance) {
  RunStats stats;
  stats.layout = "1,1,1,3";
  // Renders 4-6; render 6 is lost at 1.0 s and the others split the work.
  stats.addFrame(frame(0, 0.5, {{4, 0.1}, {5, 0.1}, {6, 0.1}}));
  stats.addFrame(frame(1, 1.5, {{4, 0.1}, {5, 0.1}, {6, 0.0}}));
  stats.lost.push_back({"render", 6, 1.0, "no word from it for 5.0 s", true});
  EXPECT_DOUBLE_EQ(*stats.balance(stats.frames[0]).busy, 1.0);
  EXPECT_DOUBLE_EQ(*stats.balance(stats.frames[1]).busy, 1.0);  // two processes left, even
  stats.lost.back().seconds = 1.45;  // lost while frame 1 was being drawn: it counts
  EXPECT_DOUBLE_EQ(*stats.balance(stats.frames[1]).busy, 1.5);
}

// A long run's per-tile detail stays bounded and thins evenly; the latest
// record (cumulative counters) is always the last one kept.
TEST(FrameStats, DetailThinsEvenlyPastItsLimitAndKeepsTheLatest) {
  DetailThinning thinning;
  std::vector<int> kept;
  for (int record = 1; record <= 1000; ++record) {
    thinning.append(kept, record, 16);
    ASSERT_LE(kept.size(), 17u);
    ASSERT_LE(kept.capacity(), 17u);  // never room for more than the bound
    ASSERT_EQ(kept.back(), record);
    for (std::size_t i = 0; i + 1 < kept.size(); ++i) {
      ASSERT_EQ(kept[i], static_cast<int>((i + 1) * thinning.stride)) << "record " << record;
    }
  }
  EXPECT_EQ(thinning.stride, 64u);  // 1000 records in at most 16 + the latest
  RunStats stats;
  stats.tileLimit = 4;
  for (std::uint64_t frame = 0; frame < 100; ++frame) stats.addTile({.frame = frame});
  EXPECT_LE(stats.tiles.size(), 5u);
  EXPECT_EQ(stats.tiles.back().frame, 99u);
}

// Thinning the per-frame detail of a long run leaves its figures exact: the
// same frames with every record kept and with 16 kept give equal key figures.
TEST(FrameStats, KeyFiguresStayExactWhenTheFramesThin) {
  RunStats whole, thin;
  whole.layout = thin.layout = "1,1,1,3";
  thin.frameLimit = 16;
  thin.reserveDetail(std::vector<int>{4, 5, 6});
  EXPECT_TRUE(thin.frames.empty());
  for (std::uint64_t i = 0; i < 1000; ++i) {
    const double t = 0.02 * static_cast<double>(i + 1);
    FrameRecord record = frame(i, t,
                               {{4, 0.001 * static_cast<double>(i % 7)},
                                {5, 0.002},
                                {6, 0.001 * static_cast<double>(i % 3)}});
    record.bytesOrdered = i < 3 ? 1'000'000 : 1000 + i;
    record.reissuedTiles = i % 100 == 0 ? 1 : 0;
    if (i == 500) whole.lost.push_back({"render", 6, t - 0.2, "no word", true});
    if (i == 500) thin.lost.push_back(whole.lost.back());
    whole.addFrame(record);
    thin.addFrame(record);
  }
  whole.totalSeconds = thin.totalSeconds = 20.0;
  EXPECT_LE(thin.frames.size(), 17u);
  EXPECT_EQ(thin.frames.back().frame, 999u);
  EXPECT_EQ(whole.frames.size(), 1000u);
  const KeyFigures a = whole.keyFigures();
  const KeyFigures b = thin.keyFigures();
  EXPECT_EQ(b.frames, 1000u);
  EXPECT_EQ(b.steadyFrom, 3u);
  EXPECT_DOUBLE_EQ(b.framesPerSecond, a.framesPerSecond);
  EXPECT_DOUBLE_EQ(b.framesPerSecondSteady, a.framesPerSecondSteady);
  EXPECT_DOUBLE_EQ(b.splatsPerFrame, a.splatsPerFrame);
  EXPECT_DOUBLE_EQ(b.imbalanceBusy, a.imbalanceBusy);
  EXPECT_DOUBLE_EQ(b.imbalanceSplats, a.imbalanceSplats);
  EXPECT_DOUBLE_EQ(b.imbalanceBusyRun, a.imbalanceBusyRun);
  EXPECT_EQ(b.bytesTotal, a.bytesTotal);
  EXPECT_EQ(b.bytesFirstFrame, 1'000'000u);
  EXPECT_DOUBLE_EQ(b.bytesPerFrameSteady, a.bytesPerFrameSteady);
  EXPECT_EQ(b.reissuedTiles, 10u);
  EXPECT_DOUBLE_EQ(b.drawPerFrame, a.drawPerFrame);
  EXPECT_DOUBLE_EQ(b.renders.at(5).splatsPerSecondSteady, a.renders.at(5).splatsPerSecondSteady);
  // Records changed in place count again only while nothing was thinned.
  whole.frames[0].bytesOrdered = 7;
  whole.recountFrames();
  EXPECT_EQ(whole.keyFigures().bytesFirstFrame, 7u);
  EXPECT_THROW(thin.recountFrames(), UsageError);
}

// A short run's steady state begins before frame 3: the figures come from
// the first frames kept whole.
TEST(FrameStats, ShortRunsBeginTheirSteadyStateEarlier) {
  RunStats stats;
  stats.layout = "1,1,1,2";
  for (std::uint64_t i = 0; i < 8; ++i) {
    FrameRecord record = frame(i, static_cast<double>(i + 1), {{4, 0.1}, {5, 0.1}});
    record.bytesOrdered = 100 * (i + 1);
    record.bytesOrderedHeldElsewhere = 10 * (i + 1);
    stats.addFrame(record);
  }
  const KeyFigures k = stats.keyFigures();
  EXPECT_EQ(k.steadyFrom, 2u);
  EXPECT_DOUBLE_EQ(k.framesPerSecondSteady, 6.0 / 6.0);  // frames 2..7, ended 2 s .. 8 s
  EXPECT_DOUBLE_EQ(k.bytesPerFrameSteady, (300.0 + 400 + 500 + 600 + 700 + 800) / 6.0);
  EXPECT_DOUBLE_EQ(k.bytesHeldElsewherePerFrameSteady, (30.0 + 40 + 50 + 60 + 70 + 80) / 6.0);
  EXPECT_EQ(k.imbalanceFrames, 6u);
}

// A path played twice: the second loop's figures are its own frames' and
// stay exact when the detail thins; one loop gives none.
TEST(FrameStats, LaterLoopsHaveFiguresOfTheirOwn) {
  RunStats looped, once;
  looped.layout = once.layout = "1,1,1,2";
  looped.loopFrames = 10;
  looped.frameLimit = 4;
  for (std::uint64_t i = 0; i < 20; ++i) {
    FrameRecord record = frame(i, 0.5 * static_cast<double>(i + 1), {{4, 0.2}, {5, 0.1}});
    record.bytesOrdered = i < 10 ? 1000 : 10 * i;
    record.bytesOrderedHeldElsewhere = i < 10 ? 500 : i;
    record.imageBytes = 7;
    looped.addFrame(record);
    once.addFrame(record);
  }
  const KeyFigures k = looped.keyFigures();
  EXPECT_EQ(k.laterLoopsFrom, 10u);
  EXPECT_DOUBLE_EQ(k.framesPerSecondLaterLoops, 10.0 / (10.0 - 5.0));  // ended 5.5 s .. 10 s
  EXPECT_DOUBLE_EQ(k.bytesPerFrameLaterLoops, 10.0 * (10 + 19) / 2.0);
  EXPECT_DOUBLE_EQ(k.bytesHeldElsewherePerFrameLaterLoops, (10 + 19) / 2.0);
  EXPECT_DOUBLE_EQ(k.imageBytesPerFrameLaterLoops, 7.0);
  EXPECT_NEAR(k.imbalanceBusyLaterLoops, 0.2 / 0.15, 1e-12);
  // The steady figures still start at frame 3, over both loops.
  EXPECT_EQ(k.steadyFrom, 3u);
  EXPECT_DOUBLE_EQ(k.bytesPerFrameSteady, once.keyFigures().bytesPerFrameSteady);
  EXPECT_EQ(once.keyFigures().laterLoopsFrom, 0u);
  EXPECT_DOUBLE_EQ(once.keyFigures().bytesPerFrameLaterLoops, 0.0);
  EXPECT_NE(looped.summary().find("later loops (from frame 10"), std::string::npos);
  EXPECT_EQ(once.summary().find("later loops"), std::string::npos);
}

}  // namespace
}  // namespace pointillist::display
