#include "display/core/frame_scheduler.hpp"

#include <algorithm>

#include "common/errors.hpp"

namespace pointillist::display {

FrameScheduler::FrameScheduler(std::uint32_t framesInFlight, std::chrono::milliseconds tileTimeout,
                               std::uint32_t maxAttempts)
    : framesInFlight_(std::max<std::uint32_t>(1, framesInFlight)),
      tileTimeout_(tileTimeout),
      maxAttempts_(std::max<std::uint32_t>(1, maxAttempts)) {}

void FrameScheduler::addFrame(std::uint64_t index, const Camera& camera,
                              std::vector<TileRect> tiles, std::vector<std::uint32_t> order) {
  if (!order.empty()) {
    std::vector<std::uint32_t> sorted = order;
    std::sort(sorted.begin(), sorted.end());
    for (std::uint32_t i = 0; i < sorted.size(); ++i) {
      if (sorted[i] != i || sorted.size() != tiles.size()) {
        throw UsageError("frame " + std::to_string(index) +
                         ": the tile order is not a permutation of its tiles");
      }
    }
  }
  FrameState state;
  state.order = std::move(order);
  state.index = index;
  state.camera = camera;
  state.tiles.reserve(tiles.size());
  for (const TileRect& rect : tiles) {
    TileState tile;
    tile.rect = rect;
    state.tiles.push_back(tile);
  }
  state.remaining = static_cast<std::uint32_t>(tiles.size());
  frames_.push_back(std::move(state));
  admitFrames();
}

void FrameScheduler::admitFrames() {
  while (admitted_ < frames_.size() && admitted_ < framesInFlight_) {
    FrameState& state = frames_[admitted_++];
    for (std::uint32_t i = 0; i < state.tiles.size(); ++i) {
      queue_.push_back({state.index, state.order.empty() ? i : state.order[i], 0});
    }
  }
}

FrameState* FrameScheduler::frame(std::uint64_t index) {
  for (FrameState& state : frames_) {
    if (state.index == index) return &state;
  }
  return nullptr;
}

std::optional<TileTaskRef> FrameScheduler::nextTask(Clock::time_point now) {
  while (!queue_.empty()) {
    TileTaskRef task = queue_.front();
    queue_.pop_front();
    FrameState* state = frame(task.frame);
    if (state == nullptr) continue;
    TileState& tile = state->tiles.at(task.tile);
    if (tile.done || tile.failed) continue;
    if (!state->hasStarted) {
      state->hasStarted = true;
      state->started = now;
    }
    task.attempt = tile.attempts++;
    tile.deadline = now + tileTimeout_;
    tile.holders.clear();
    return task;
  }
  return std::nullopt;
}

bool FrameScheduler::tileWaiting(std::uint64_t frameIndex, std::uint32_t tileIndex,
                                 const TileRect& rect) const {
  const auto state = std::find_if(frames_.begin(), frames_.end(),
                                  [&](const FrameState& f) { return f.index == frameIndex; });
  if (state == frames_.end() || tileIndex >= state->tiles.size()) return false;
  const TileState& tile = state->tiles[tileIndex];
  return !tile.done && !tile.failed && tile.rect.x() == rect.x() && tile.rect.y() == rect.y() &&
         tile.rect.width() == rect.width() && tile.rect.height() == rect.height();
}

bool FrameScheduler::tileArrived(std::uint64_t frameIndex, std::uint32_t tileIndex,
                                 const TileRect& rect) {
  if (!tileWaiting(frameIndex, tileIndex, rect)) return false;
  FrameState* state = frame(frameIndex);
  state->tiles[tileIndex].done = true;
  --state->remaining;
  return true;
}

std::uint32_t FrameScheduler::checkTimeouts(Clock::time_point now) {
  std::uint32_t requeued = 0;
  for (std::size_t i = 0; i < admitted_ && i < frames_.size(); ++i) {
    FrameState& state = frames_[i];
    for (std::uint32_t index = 0; index < state.tiles.size(); ++index) {
      TileState& tile = state.tiles[index];
      if (tile.done || tile.failed || tile.attempts == 0 || now < tile.deadline) continue;
      if (queued(state.index, index)) continue;
      for (const std::uint32_t render : tile.holders) suspects_[render] = now;
      if (tile.attempts >= maxAttempts_) {
        tile.failed = true;
        --state.remaining;
        ++failed_[state.index];
        continue;
      }
      requeue(state, index);
      ++requeued;
    }
  }
  return requeued;
}

bool FrameScheduler::queued(std::uint64_t frameIndex, std::uint32_t tile) const {
  return std::any_of(queue_.begin(), queue_.end(), [&](const TileTaskRef& task) {
    return task.frame == frameIndex && task.tile == tile;
  });
}

void FrameScheduler::requeue(FrameState& state, std::uint32_t tile) {
  // Re-issued tiles go ahead of fresh ones, oldest frame first: their frame
  // is the one holding everything up.
  const auto before = std::find_if(queue_.begin(), queue_.end(), [&](const TileTaskRef& task) {
    return task.attempt == 0 || task.frame > state.index;
  });
  queue_.insert(before, {state.index, tile, state.tiles[tile].attempts});
  ++reissued_[state.index];
}

std::uint32_t FrameScheduler::renderLost(std::uint32_t render) {
  if (std::find(lost_.begin(), lost_.end(), render) == lost_.end()) lost_.push_back(render);
  suspects_.erase(render);
  std::uint32_t requeued = 0;
  for (std::size_t i = 0; i < admitted_ && i < frames_.size(); ++i) {
    FrameState& state = frames_[i];
    for (std::uint32_t index = 0; index < state.tiles.size(); ++index) {
      const TileState& tile = state.tiles[index];
      if (tile.done || tile.failed || tile.attempts == 0) continue;
      if (std::find(tile.holders.begin(), tile.holders.end(), render) == tile.holders.end()) {
        continue;
      }
      if (queued(state.index, index)) continue;
      requeue(state, index);
      ++requeued;
    }
  }
  return requeued;
}

std::optional<FrameScheduler::Clock::time_point> FrameScheduler::nextDeadline() const {
  std::optional<Clock::time_point> earliest;
  for (std::size_t i = 0; i < admitted_ && i < frames_.size(); ++i) {
    for (const TileState& tile : frames_[i].tiles) {
      if (tile.done || tile.failed || tile.attempts == 0) continue;
      if (!earliest || tile.deadline < *earliest) earliest = tile.deadline;
    }
  }
  return earliest;
}

std::optional<FrameState> FrameScheduler::popCompleteFrame() {
  if (frames_.empty() || admitted_ == 0 || frames_.front().remaining != 0) return std::nullopt;
  FrameState state = std::move(frames_.front());
  frames_.pop_front();
  --admitted_;
  admitFrames();
  return state;
}

void FrameScheduler::tilePlaced(std::uint64_t frameIndex, std::uint32_t tileIndex,
                                std::uint32_t attempt, std::uint32_t render) {
  FrameState* state = frame(frameIndex);
  if (state == nullptr || tileIndex >= state->tiles.size()) return;
  TileState& tile = state->tiles[tileIndex];
  if (tile.done || tile.failed || attempt + 1 != tile.attempts) return;
  if (std::find(tile.holders.begin(), tile.holders.end(), render) == tile.holders.end()) {
    tile.holders.push_back(render);
  }
  const bool gone = std::find(lost_.begin(), lost_.end(), render) != lost_.end();
  if (gone && !queued(frameIndex, tileIndex)) requeue(*state, tileIndex);
}

void FrameScheduler::renderAnswered(std::uint32_t render) {
  suspects_.erase(render);
}

std::vector<std::uint32_t> FrameScheduler::suspectRenders(Clock::time_point now) const {
  std::vector<std::uint32_t> renders;
  for (const auto& [render, since] : suspects_) {
    if (now - since < 2 * tileTimeout_) renders.push_back(render);
  }
  return renders;
}

std::uint32_t FrameScheduler::reissued(std::uint64_t frameIndex) const {
  const auto found = reissued_.find(frameIndex);
  return found == reissued_.end() ? 0 : found->second;
}

std::uint32_t FrameScheduler::failed(std::uint64_t frameIndex) const {
  const auto found = failed_.find(frameIndex);
  return found == failed_.end() ? 0 : found->second;
}

}  // namespace pointillist::display
