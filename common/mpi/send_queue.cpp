#include "common/mpi/send_queue.hpp"

namespace pointillist {

void SendQueue::post(const Outbox& outbox) {
  for (const Outgoing& outgoing : outbox.entries()) {
    for (int dest : outgoing.destinations) {
      if (lost_.contains(dest)) continue;
      sends_.push_back(channel_.post(dest, outgoing.kind, *outgoing.message));
    }
  }
}

void SendQueue::post(int dest, MessageKind kind, const google::protobuf::MessageLite& header) {
  if (lost_.contains(dest)) return;
  sends_.push_back(channel_.post(dest, kind, header));
}

void SendQueue::post(int dest, MessageKind kind, const google::protobuf::MessageLite& header,
                     std::span<const std::byte> payload, std::shared_ptr<const void> owner) {
  if (lost_.contains(dest)) return;
  sends_.push_back(channel_.post(dest, kind, header, payload, std::move(owner)));
}

void SendQueue::reap() {
  // Sends to one peer complete in order; a stuck one at the front only delays
  // freeing the others, never their delivery.
  while (!sends_.empty() && sends_.front().test()) sends_.pop_front();
}

void SendQueue::drain(std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (!sends_.empty()) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
        deadline - std::chrono::steady_clock::now());
    if (!sends_.front().waitFor(std::max(left, std::chrono::milliseconds(0)))) {
      sends_.front().cancel();
    }
    sends_.pop_front();
  }
}

void SendQueue::forget(int rank) {
  if (!lost_.insert(rank).second) return;
  std::deque<SendHandle> kept;
  for (SendHandle& send : sends_) {
    if (send.destination() == rank) {
      send.abandon(abandoned_);
    } else {
      kept.push_back(std::move(send));
    }
  }
  sends_ = std::move(kept);
}

}  // namespace pointillist
