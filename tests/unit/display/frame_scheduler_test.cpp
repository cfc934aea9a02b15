// The display's frames in flight: tiles handed out, late ones re-issued,
// frames released in order.
#include "display/core/frame_scheduler.hpp"

#include <gtest/gtest.h>

namespace pointillist::display {
namespace {

using namespace std::chrono_literals;

TEST(FrameScheduler, HandsOutTilesOfFramesInFlightAndReleasesFramesInOrder) {
  FrameScheduler scheduler(2, 1000ms, 3);
  const Camera camera = makeCamera({0, 0, 5}, {0, 0, 0}, {0, 1, 0}, 45.0f, 0.1f, 10.0f, 8, 8);
  for (std::uint64_t f = 0; f < 3; ++f) {
    scheduler.addFrame(f, camera, {makeTileRect(0, 0, 4, 8), makeTileRect(4, 0, 4, 8)});
  }
  const auto now = FrameScheduler::Clock::now();
  std::vector<TileTaskRef> tasks;
  while (auto task = scheduler.nextTask(now)) tasks.push_back(*task);
  ASSERT_EQ(tasks.size(), 4u) << "two frames in flight, two tiles each";
  // Frame 1 completes first but is held until frame 0 is done.
  EXPECT_TRUE(scheduler.tileArrived(1, 0, makeTileRect(0, 0, 4, 8)));
  EXPECT_TRUE(scheduler.tileArrived(1, 1, makeTileRect(4, 0, 4, 8)));
  EXPECT_FALSE(scheduler.popCompleteFrame().has_value());
  EXPECT_TRUE(scheduler.tileArrived(0, 0, makeTileRect(0, 0, 4, 8)));
  EXPECT_FALSE(scheduler.tileArrived(0, 0, makeTileRect(0, 0, 4, 8))) << "duplicate ignored";
  EXPECT_FALSE(scheduler.tileArrived(0, 1, makeTileRect(0, 0, 4, 8))) << "wrong rect ignored";
  EXPECT_TRUE(scheduler.tileArrived(0, 1, makeTileRect(4, 0, 4, 8)));
  EXPECT_EQ(scheduler.popCompleteFrame()->index, 0u);
  EXPECT_EQ(scheduler.popCompleteFrame()->index, 1u);
  // Frame 2 entered the window.
  int frame2 = 0;
  while (auto task = scheduler.nextTask(now)) frame2 += task->frame == 2 ? 1 : 0;
  EXPECT_EQ(frame2, 2);
  EXPECT_FALSE(scheduler.tileArrived(0, 0, makeTileRect(0, 0, 4, 8))) << "frame already gone";
}

TEST(FrameScheduler, ReissuesLateTilesThenGivesUp) {
  FrameScheduler scheduler(1, 100ms, 2);
  const Camera camera = makeCamera({0, 0, 5}, {0, 0, 0}, {0, 1, 0}, 45.0f, 0.1f, 10.0f, 8, 8);
  scheduler.addFrame(0, camera, {makeTileRect(0, 0, 8, 8)});
  const auto t = FrameScheduler::Clock::now();
  ASSERT_EQ(scheduler.nextTask(t)->attempt, 0u);
  EXPECT_EQ(scheduler.checkTimeouts(t + 50ms), 0u);
  EXPECT_EQ(scheduler.checkTimeouts(t + 150ms), 1u);
  const auto retry = scheduler.nextTask(t + 150ms);
  ASSERT_TRUE(retry.has_value());
  EXPECT_EQ(retry->attempt, 1u);
  EXPECT_EQ(scheduler.reissued(0), 1u);
  // Second deadline passes: attempts are used up, the tile fails, the frame completes.
  EXPECT_EQ(scheduler.checkTimeouts(t + 300ms), 0u);
  EXPECT_EQ(scheduler.failed(0), 1u);
  const auto frame = scheduler.popCompleteFrame();
  ASSERT_TRUE(frame.has_value());
  EXPECT_TRUE(frame->tiles[0].failed);
  EXPECT_TRUE(scheduler.finished());
}

// A render holding an overdue tile is suspected until it answers, or until
// two timeouts after the last of its tiles went overdue.
TEST(FrameScheduler, SuspectsTheRenderHoldingAnOverdueTileUntilItAnswers) {
  FrameScheduler scheduler(1, 100ms, 3);
  const Camera camera = makeCamera({0, 0, 5}, {0, 0, 0}, {0, 1, 0}, 45.0f, 0.1f, 10.0f, 8, 8);
  scheduler.addFrame(0, camera, {makeTileRect(0, 0, 4, 8), makeTileRect(4, 0, 4, 8)});
  const auto t = FrameScheduler::Clock::now();
  const auto a = scheduler.nextTask(t);
  const auto b = scheduler.nextTask(t);
  ASSERT_TRUE(a && b);
  scheduler.tilePlaced(0, a->tile, 0, 2);
  scheduler.tilePlaced(0, a->tile, 0, 3);  // split: parts on two renders
  scheduler.tilePlaced(0, b->tile, 0, 1);
  scheduler.tilePlaced(0, b->tile, 5, 0);  // no such attempt: ignored
  EXPECT_TRUE(scheduler.tileArrived(0, b->tile, makeTileRect(4, 0, 4, 8)));
  EXPECT_TRUE(scheduler.suspectRenders(t + 50ms).empty());
  EXPECT_EQ(scheduler.checkTimeouts(t + 150ms), 1u);
  EXPECT_EQ(scheduler.suspectRenders(t + 150ms), (std::vector<std::uint32_t>{2, 3}))
      << "the tile that came back in time suspects no one";
  // The re-issue goes to render 1 and is placed there; render 2 answers.
  const auto again = scheduler.nextTask(t + 150ms);
  ASSERT_TRUE(again.has_value());
  scheduler.tilePlaced(0, again->tile, 0, 2);  // the old attempt: not a holder now
  scheduler.tilePlaced(0, again->tile, 1, 1);
  scheduler.renderAnswered(2);
  EXPECT_EQ(scheduler.suspectRenders(t + 200ms), (std::vector<std::uint32_t>{3}));
  // Render 3 never answers: its suspicion lapses two timeouts on.
  EXPECT_EQ(scheduler.suspectRenders(t + 340ms), (std::vector<std::uint32_t>{3}));
  EXPECT_TRUE(scheduler.suspectRenders(t + 360ms).empty());
  // The second attempt goes overdue on render 1 alone.
  EXPECT_EQ(scheduler.checkTimeouts(t + 260ms), 1u);
  EXPECT_EQ(scheduler.suspectRenders(t + 260ms), (std::vector<std::uint32_t>{1, 3}));
}

// A lost render's tiles go back at once; the others' keep their deadline.
TEST(FrameScheduler, ALostRendersTilesGoBackAndOnlyThose) {
  FrameScheduler scheduler(2, 1000ms, 3);
  const Camera camera = makeCamera({0, 0, 5}, {0, 0, 0}, {0, 1, 0}, 45.0f, 0.1f, 10.0f, 8, 8);
  for (std::uint64_t f = 0; f < 2; ++f) {
    scheduler.addFrame(f, camera, {makeTileRect(0, 0, 4, 8), makeTileRect(4, 0, 4, 8)});
  }
  const auto t = FrameScheduler::Clock::now();
  std::vector<TileTaskRef> tasks;
  while (auto task = scheduler.nextTask(t)) tasks.push_back(*task);
  ASSERT_EQ(tasks.size(), 4u);
  scheduler.tilePlaced(0, 0, 0, 0);
  scheduler.tilePlaced(0, 1, 0, 1);
  scheduler.tilePlaced(1, 0, 0, 0);
  scheduler.tilePlaced(1, 0, 0, 1);  // split over both
  scheduler.tilePlaced(1, 1, 0, 0);
  EXPECT_EQ(scheduler.renderLost(1), 2u);
  EXPECT_EQ(scheduler.reissued(0), 1u);
  EXPECT_EQ(scheduler.reissued(1), 1u);
  std::vector<std::pair<std::uint64_t, std::uint32_t>> again;
  while (auto task = scheduler.nextTask(t)) again.emplace_back(task->frame, task->tile);
  EXPECT_EQ(again, (std::vector<std::pair<std::uint64_t, std::uint32_t>>{{0, 1}, {1, 0}}))
      << "the oldest frame first";
  EXPECT_EQ(scheduler.renderLost(1), 0u) << "nothing is held by it any more";
  // A placement on it that was on its way goes back at once.
  scheduler.tilePlaced(0, 1, 1, 1);
  EXPECT_EQ(scheduler.nextTask(t)->tile, 1u);
  EXPECT_EQ(scheduler.checkTimeouts(t + 500ms), 0u);
}

TEST(FrameScheduler, AFrameWithNothingOnScreenCompletesAtOnce) {
  FrameScheduler scheduler(2, 100ms, 2);
  const Camera camera = makeCamera({0, 0, 5}, {0, 0, 0}, {0, 1, 0}, 45.0f, 0.1f, 10.0f, 8, 8);
  scheduler.addFrame(0, camera, {});
  EXPECT_EQ(scheduler.popCompleteFrame()->index, 0u);
}

}  // namespace
}  // namespace pointillist::display
