#pragma once
// Sends in flight of one process. Roles post and forget; the serve loop reaps
// finished sends and polls closely while any is in flight (a large message
// moves only while both sides call into MPI).
#include <chrono>
#include <cstddef>
#include <deque>
#include <memory>
#include <set>
#include <span>
#include <vector>

#include "common/messages.hpp"
#include "common/mpi/channel.hpp"

namespace pointillist {

class SendQueue {
 public:
  explicit SendQueue(Channel& channel) : channel_(channel) {}
  SendQueue(const SendQueue&) = delete;
  SendQueue& operator=(const SendQueue&) = delete;

  // Every entry of the outbox to every one of its destinations, in order.
  void post(const Outbox& outbox);
  void post(int dest, MessageKind kind, const google::protobuf::MessageLite& header);
  // A header with a payload that `owner` keeps alive until the send is done.
  void post(int dest, MessageKind kind, const google::protobuf::MessageLite& header,
            std::span<const std::byte> payload, std::shared_ptr<const void> owner);

  // Frees the sends that have completed (oldest first).
  void reap();
  bool pending() const { return !sends_.empty(); }
  std::size_t size() const { return sends_.size(); }
  // Waits for every send; a send no peer takes within `timeout` is given up
  // (its receiver has gone), so that an ending process never hangs.
  void drain(std::chrono::milliseconds timeout);

  // `rank` is lost: its sends in flight are abandoned and later ones to it
  // are dropped, so that nothing waits for it and no memory piles up for it.
  void forget(int rank);
  bool forgotten(int rank) const { return lost_.contains(rank); }

 private:
  Channel& channel_;
  std::deque<SendHandle> sends_;
  std::set<int> lost_;
  // Buffers of abandoned sends: MPI may still name them.
  std::vector<std::shared_ptr<const void>> abandoned_;
};

}  // namespace pointillist
