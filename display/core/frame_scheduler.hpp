#pragma once
// The display's bookkeeping of frames in flight (MPI-free): which tiles of
// which frames are waiting to be handed out, which are out and since when,
// which are done; re-issue of tiles that do not come back in time; frames
// released strictly in order.
#include <chrono>
#include <cstdint>
#include <deque>
#include <map>
#include <optional>
#include <vector>

#include "common/camera.hpp"

namespace pointillist::display {

struct TileState {
  TileRect rect;
  std::uint32_t attempts = 0;  // times handed out
  bool done = false;
  bool failed = false;
  std::chrono::steady_clock::time_point deadline;
  std::vector<std::uint32_t> holders;  // renders given the latest attempt
};

struct FrameState {
  std::uint64_t index = 0;
  Camera camera;
  std::vector<TileState> tiles;
  std::vector<std::uint32_t> order;  // dispatch order; empty: as listed
  std::uint32_t remaining = 0;
  std::chrono::steady_clock::time_point started;
  bool hasStarted = false;
};

struct TileTaskRef {
  std::uint64_t frame = 0;
  std::uint32_t tile = 0;
  std::uint32_t attempt = 0;
};

class FrameScheduler {
 public:
  using Clock = std::chrono::steady_clock;

  FrameScheduler(std::uint32_t framesInFlight, std::chrono::milliseconds tileTimeout,
                 std::uint32_t maxAttempts);

  // Adds a frame; its tiles are queued once it enters the window, in
  // `order` (indices into tiles) when given, else as listed.
  void addFrame(std::uint64_t index, const Camera& camera, std::vector<TileRect> tiles,
                std::vector<std::uint32_t> order = {});
  // The next tile to hand out, if any frame in the window has one waiting.
  std::optional<TileTaskRef> nextTask(Clock::time_point now);
  // A tile image arrived. Returns false when it is stale (frame gone, tile
  // already done, or the rect does not match); the image is then ignored.
  bool tileArrived(std::uint64_t frame, std::uint32_t tile, const TileRect& rect);
  // Whether tileArrived would take it now (it changes nothing).
  bool tileWaiting(std::uint64_t frame, std::uint32_t tile, const TileRect& rect) const;
  FrameState* frame(std::uint64_t index);
  // Tiles past their deadline go back to the queue, or fail after maxAttempts.
  // Returns how many were re-queued.
  std::uint32_t checkTimeouts(Clock::time_point now);
  // A render process is gone: every tile out that it holds (tilePlaced) goes
  // back to the queue at once, and so does a tile placed on it later (by a
  // traverse that had not heard of the loss yet). Tiles on the others keep
  // their deadline. Returns how many went back now.
  std::uint32_t renderLost(std::uint32_t render);
  // The earliest deadline of a tile that is out; nullopt when none is.
  std::optional<Clock::time_point> nextDeadline() const;
  // The oldest frame, when every tile of it is done or failed.
  std::optional<FrameState> popCompleteFrame();
  bool finished() const { return frames_.empty(); }
  // Tiles are queued to be handed out (some may have come back meanwhile).
  bool tasksQueued() const { return !queue_.empty(); }
  // The traverse sent attempt `attempt` of a tile (or a part of it) to render
  // `render`. Placements of an older attempt are ignored; one on a lost
  // render sends the tile back to the queue.
  void tilePlaced(std::uint64_t frame, std::uint32_t tile, std::uint32_t attempt,
                  std::uint32_t render);
  // Something came back from `render`: it is answering again.
  void renderAnswered(std::uint32_t render);
  // Renders holding a tile that went past its deadline, and silent since.
  // Suspicion lapses two tile timeouts after the last such tile, so that a
  // render whose answer was lost gets work again (and is suspected again if
  // it stays silent).
  std::vector<std::uint32_t> suspectRenders(Clock::time_point now) const;
  std::uint32_t reissued(std::uint64_t frame) const;
  std::uint32_t failed(std::uint64_t frame) const;

 private:
  void admitFrames();

  std::uint32_t framesInFlight_;
  std::chrono::milliseconds tileTimeout_;
  std::uint32_t maxAttempts_;
  std::deque<FrameState> frames_;  // in order; the first framesInFlight_ are active
  std::deque<TileTaskRef> queue_;
  std::size_t admitted_ = 0;  // frames_[0..admitted_) have their tiles queued
  std::map<std::uint64_t, std::uint32_t> reissued_;
  std::map<std::uint64_t, std::uint32_t> failed_;
  std::map<std::uint32_t, Clock::time_point> suspects_;  // render -> since
  std::vector<std::uint32_t> lost_;                      // renders gone
  // Puts a tile that is out back at the head of the queue (re-issued).
  void requeue(FrameState& state, std::uint32_t tile);
  bool queued(std::uint64_t frame, std::uint32_t tile) const;
};

}  // namespace pointillist::display
