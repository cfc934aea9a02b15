#include "service/core/frame_queue.hpp"

#include <gtest/gtest.h>

#include "service/core/request_validation.hpp"

namespace pointillist::service {
namespace {

QueuedFrame frame(const std::string& client, std::uint64_t request, std::uint32_t index = 0) {
  QueuedFrame out;
  out.clientId = client;
  out.requestId = request;
  out.pathIndex = index;
  return out;
}

std::vector<QueuedFrame> path(const std::string& client, std::uint64_t request, std::uint32_t n) {
  std::vector<QueuedFrame> frames;
  for (std::uint32_t i = 0; i < n; ++i) frames.push_back(frame(client, request, i));
  return frames;
}

TEST(FrameQueue, ANewerCameraSupersedesTheClientsQueuedCameras) {
  FrameQueue queue;
  EXPECT_TRUE(queue.pushSingle(frame("a", 1)).empty());
  EXPECT_TRUE(queue.pushSingle(frame("b", 2)).empty());
  const auto superseded = queue.pushSingle(frame("a", 3));
  ASSERT_EQ(superseded.size(), 1u);
  EXPECT_EQ(superseded[0].requestId, 1u);
  EXPECT_EQ(queue.size(), 2u);
  // Request 3 kept request 1's place: a's turn comes first.
  EXPECT_EQ(queue.pop()->requestId, 3u);
  EXPECT_EQ(queue.pop()->requestId, 2u);
  EXPECT_FALSE(queue.pop());
}

TEST(FrameQueue, CamerasDoNotSupersedePathFramesOrOtherClients) {
  FrameQueue queue;
  queue.pushPath(path("a", 1, 3));
  EXPECT_TRUE(queue.pushSingle(frame("b", 2)).empty());
  EXPECT_TRUE(queue.pushSingle(frame("a", 3)).empty());
  EXPECT_EQ(queue.size(), 5u);
  EXPECT_EQ(queue.queued("a"), 4u);
}

TEST(FrameQueue, ClientsTakeTurns) {
  FrameQueue queue;
  queue.pushPath(path("long", 1, 4));
  queue.pushSingle(frame("mouse", 2));
  queue.pushPath(path("other", 3, 2));
  std::vector<std::string> order;
  while (auto next = queue.pop()) order.push_back(next->clientId);
  EXPECT_EQ(order,
            (std::vector<std::string>{"long", "mouse", "other", "long", "other", "long", "long"}));
  EXPECT_TRUE(queue.empty());
}

TEST(FrameQueue, PathFramesStayInOrder) {
  FrameQueue queue;
  queue.pushPath(path("a", 1, 5));
  for (std::uint32_t i = 0; i < 5; ++i) EXPECT_EQ(queue.pop()->pathIndex, i);
}

TEST(FrameQueue, BoundedPerClientAndInAllWithoutPartialPaths) {
  FrameQueue queue(FrameQueueLimits{4, 6});
  queue.pushPath(path("a", 1, 3));
  EXPECT_THROW(queue.pushPath(path("a", 2, 2)), RequestError);
  EXPECT_EQ(queue.queued("a"), 3u);  // nothing of the refused path was queued
  queue.pushPath(path("b", 3, 3));
  try {
    queue.pushSingle(frame("c", 4));
    FAIL() << "the queue is full";
  } catch (const RequestError& error) {
    EXPECT_EQ(error.code(), v1::ERROR_BUSY);
  }
  EXPECT_EQ(queue.size(), 6u);
  EXPECT_EQ(queue.queued("c"), 0u);
}

TEST(FrameQueue, ARefusedCameraLeavesTheSupersededOnesQueued) {
  FrameQueue queue(FrameQueueLimits{10, 2});
  queue.pushSingle(frame("a", 1));
  queue.pushPath(path("b", 2, 1));
  // Replacing a's camera keeps the total: accepted.
  EXPECT_EQ(queue.pushSingle(frame("a", 3)).size(), 1u);
  EXPECT_EQ(queue.size(), 2u);
  EXPECT_EQ(queue.pop()->requestId, 3u);
}

TEST(FrameQueue, DroppingAClientForgetsItsFramesOnly) {
  FrameQueue queue;
  queue.pushPath(path("gone", 1, 3));
  queue.pushSingle(frame("stays", 2));
  EXPECT_EQ(queue.dropClient("gone"), 3u);
  EXPECT_EQ(queue.dropClient("never-seen"), 0u);
  EXPECT_EQ(queue.size(), 1u);
  EXPECT_EQ(queue.pop()->clientId, "stays");
  EXPECT_FALSE(queue.pop());
}

}  // namespace
}  // namespace pointillist::service
