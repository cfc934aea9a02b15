#pragma once
// Frames clients asked for and the job has not started yet. Clients are
// served in turn (one frame each per round), so a client with a long path
// never starves one moving the mouse; a client's newer single camera replaces
// its queued single cameras, so it never waits behind stale frames. Bounded
// per client and in all: a request that would exceed the bounds is refused
// whole.
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "common/camera_path.hpp"
#include "pointillist.pb.h"
#include "service_v1.pb.h"

namespace pointillist::service {

struct QueuedFrame {
  std::string clientId;
  std::uint64_t requestId = 0;
  std::uint32_t pathIndex = 0;
  std::uint32_t pathLength = 1;
  bool single = true;  // a render request (supersedable), not a frame of a path
  CameraKey key;
  v1::FrameFormat format;                   // complete: width, height, encoding, quality
  pointillist::v1::FrameSettings settings;  // the client's mode and level of detail
  std::chrono::steady_clock::time_point requested;
};

struct FrameQueueLimits {
  std::size_t perClient = 1000;
  std::size_t total = 4000;
};

class FrameQueue {
 public:
  explicit FrameQueue(FrameQueueLimits limits = {}) : limits_(limits) {}

  // Queues a render request's frame. Returns the client's queued single
  // frames it replaced (their clients are told), oldest first. Throws
  // RequestError(ERROR_BUSY) when the client's queue is full.
  std::vector<QueuedFrame> pushSingle(QueuedFrame frame);
  // Queues a path's frames in order; refused whole (ERROR_BUSY) when they do not fit.
  void pushPath(std::vector<QueuedFrame> frames);
  // The next frame, taking clients in turn.
  std::optional<QueuedFrame> pop();
  // Forgets a client's queued frames (it left); returns how many.
  std::size_t dropClient(const std::string& clientId);

  std::size_t size() const { return size_; }
  std::size_t queued(const std::string& clientId) const;
  bool empty() const { return size_ == 0; }

 private:
  void checkRoom(const std::string& clientId, std::size_t adding) const;

  FrameQueueLimits limits_;
  std::map<std::string, std::deque<QueuedFrame>> byClient_;
  std::deque<std::string> turn_;  // clients with queued frames, next first
  std::size_t size_ = 0;
};

}  // namespace pointillist::service
