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

TEST(FrameScheduler, AFrameWithNothingOnScreenCompletesAtOnce) {
  FrameScheduler scheduler(2, 100ms, 2);
  const Camera camera = makeCamera({0, 0, 5}, {0, 0, 0}, {0, 1, 0}, 45.0f, 0.1f, 10.0f, 8, 8);
  scheduler.addFrame(0, camera, {});
  EXPECT_EQ(scheduler.popCompleteFrame()->index, 0u);
}

}  // namespace
}  // namespace pointillist::display
