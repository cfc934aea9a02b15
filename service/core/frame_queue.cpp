#include "service/core/frame_queue.hpp"

#include <algorithm>

#include "service/core/request_validation.hpp"

namespace pointillist::service {

void FrameQueue::checkRoom(const std::string& clientId, std::size_t adding) const {
  const std::size_t mine = queued(clientId);
  if (mine + adding > limits_.perClient || size_ + adding > limits_.total) {
    throw RequestError(v1::ERROR_BUSY, "queue full: " + std::to_string(mine) +
                                           " frame(s) of this client and " + std::to_string(size_) +
                                           " in all are waiting (limits " +
                                           std::to_string(limits_.perClient) + " per client, " +
                                           std::to_string(limits_.total) + " in all)");
  }
}

std::vector<QueuedFrame> FrameQueue::pushSingle(QueuedFrame frame) {
  frame.single = true;
  auto& queue = byClient_[frame.clientId];
  std::vector<QueuedFrame> superseded;
  for (auto it = queue.begin(); it != queue.end();) {
    if (it->single) {
      superseded.push_back(std::move(*it));
      it = queue.erase(it);
      --size_;
    } else {
      ++it;
    }
  }
  try {
    checkRoom(frame.clientId, 1);
  } catch (...) {
    // Refused: the superseded frames stay as they were.
    for (auto& old : superseded) queue.push_back(std::move(old));
    size_ += superseded.size();
    if (queue.empty()) byClient_.erase(frame.clientId);
    throw;
  }
  // The newest camera takes the place of the oldest it replaced, so moving
  // the mouse does not push a client back behind its own path frames.
  if (superseded.empty()) {
    if (queue.empty()) turn_.push_back(frame.clientId);
    queue.push_back(std::move(frame));
  } else {
    queue.push_front(std::move(frame));
  }
  ++size_;
  return superseded;
}

void FrameQueue::pushPath(std::vector<QueuedFrame> frames) {
  if (frames.empty()) return;
  const std::string clientId = frames.front().clientId;
  checkRoom(clientId, frames.size());
  auto& queue = byClient_[clientId];
  if (queue.empty()) turn_.push_back(clientId);
  for (auto& frame : frames) {
    frame.single = false;
    queue.push_back(std::move(frame));
  }
  size_ += frames.size();
}

std::optional<QueuedFrame> FrameQueue::pop() {
  while (!turn_.empty()) {
    const std::string clientId = turn_.front();
    turn_.pop_front();
    auto found = byClient_.find(clientId);
    if (found == byClient_.end() || found->second.empty()) continue;
    QueuedFrame frame = std::move(found->second.front());
    found->second.pop_front();
    --size_;
    if (found->second.empty()) {
      byClient_.erase(found);
    } else {
      turn_.push_back(clientId);
    }
    return frame;
  }
  return std::nullopt;
}

std::size_t FrameQueue::dropClient(const std::string& clientId) {
  const auto found = byClient_.find(clientId);
  if (found == byClient_.end()) return 0;
  const std::size_t dropped = found->second.size();
  size_ -= dropped;
  byClient_.erase(found);
  turn_.erase(std::remove(turn_.begin(), turn_.end(), clientId), turn_.end());
  return dropped;
}

std::size_t FrameQueue::queued(const std::string& clientId) const {
  const auto found = byClient_.find(clientId);
  return found == byClient_.end() ? 0 : found->second.size();
}

}  // namespace pointillist::service
