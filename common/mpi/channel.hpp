#pragma once
// The typed channel: the only code in Pointillist that calls MPI.
//
// A message is a protobuf header on its kind's tag, optionally followed by a raw
// byte payload (points, pixels) on the kind's payload tag, sent straight from the
// caller's memory in chunks of at most maxChunkBytes (MPI counts are int).
// A header too large to go eagerly travels on the payload tag ahead of the
// chunks, after a small prefix on the kind's tag: the receiver posts for all
// of a message as soon as it matches the first part, so no probe ever meets
// a stray part. MPI's non-overtaking rule per (source, tag) keeps them in order.
//
// Waiting never sits in a blocking MPI call: Open MPI busy-polls inside
// MPI_Recv/MPI_Wait (a full core per idle rank, even with mpi_yield_when_idle),
// so every wait here polls with MPI_Test/MPI_Iprobe and sleeps with back-off.
#include <mpi.h>

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <memory>
#include <optional>
#include <set>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include <google/protobuf/message_lite.h>

#include "common/errors.hpp"
#include "common/messages.hpp"
#include "common/uninitialized_allocator.hpp"

namespace pointillist {

// Throws TransportError with MPI_Error_string's text when code != MPI_SUCCESS.
void checkMpi(int code, const char* call);

// Sleeps between polls, growing from minSleep to maxSleep while nothing happens.
// Longest sleep between polls while a bulk transfer of ours is in flight.
inline constexpr std::chrono::microseconds kTransferPoll{50};
// How long tryReceive waits for a payload after its header before it returns
// and lets the payload arrive while the caller goes on.
inline constexpr std::chrono::milliseconds kPayloadPatience{50};

class Backoff {
 public:
  Backoff();
  void wait();
  // Sleeps at most `cap`: while a bulk transfer is under way, its fragments
  // move only when this process calls into MPI, so it must not sleep long.
  void wait(std::chrono::microseconds cap);
  void reset() { sleep_ = minSleep_; }

 private:
  std::chrono::microseconds minSleep_;
  std::chrono::microseconds maxSleep_;
  std::chrono::microseconds sleep_;
};

// Left unwritten on resize: a received payload is written by MPI at once, and
// zeroing it first cost a render process a tenth of its time.
using PayloadBytes = std::vector<std::byte, UninitializedAllocator<std::byte>>;

// A received message: protobuf header bytes and the raw payload, if any.
struct Envelope {
  int source = -1;
  MessageKind kind = MessageKind::Test;
  std::string header;
  PayloadBytes payload;
  // Time from the header's arrival to the payload's: the transfer time of the
  // payload (large payloads move only once the receiver has posted for them).
  double payloadSeconds = 0.0;

  // Parses the header as M; a malformed header is a ProtocolError.
  template <class M>
  M as() const {
    M message;
    if (!message.ParseFromString(header)) {
      throw ProtocolError(std::string("malformed ") + messageKindName(kind) +
                          " message from rank " + std::to_string(source) + " (" +
                          std::to_string(header.size()) + " bytes)");
    }
    return message;
  }
};

// A send in flight. Owns the header bytes (and the payload, when given by value)
// until MPI is done with them; the destructor waits, so a SendHandle can never
// leave MPI reading freed memory.
class SendHandle {
 public:
  SendHandle() = default;
  SendHandle(SendHandle&&) noexcept;
  SendHandle& operator=(SendHandle&&) noexcept;
  SendHandle(const SendHandle&) = delete;
  SendHandle& operator=(const SendHandle&) = delete;
  ~SendHandle();

  bool test();  // true when complete
  void wait();
  bool waitFor(std::chrono::milliseconds timeout);  // false when still pending
  // Gives up a send no peer will take (its receiver has ended).
  void cancel();
  // Gives up a send to a lost peer without touching it again: MPI may still
  // hold its buffers, so the header and payload move to `keep`, which the
  // caller holds until the end of the process.
  void abandon(std::vector<std::shared_ptr<const void>>& keep);
  bool empty() const { return requests_.empty(); }
  int destination() const { return destination_; }

 private:
  friend class Channel;
  std::vector<MPI_Request> requests_;
  int destination_ = -1;
  std::unique_ptr<std::string> header_;
  std::shared_ptr<const void> ownedPayload_;
};

class Channel {
 public:
  static constexpr std::size_t kDefaultMaxChunkBytes = std::size_t{1} << 30;

  // Does not take ownership of the communicator.
  explicit Channel(MPI_Comm comm, std::size_t maxChunkBytes = kDefaultMaxChunkBytes);
  // Receives in flight name this channel's buffers.
  Channel(const Channel&) = delete;
  Channel& operator=(const Channel&) = delete;

  int rank() const { return rank_; }
  int size() const { return size_; }
  MPI_Comm comm() const { return comm_; }
  std::size_t maxChunkBytes() const { return maxChunkBytes_; }
  // How long a payload may take after its header: `base` plus the payload at
  // 10 MB/s. Past it the sender is taken as lost (PeerSilentError).
  void setPayloadTimeout(std::chrono::milliseconds base) { payloadTimeout_ = base; }
  // From now on messages from `rank` (a lost process) are taken off the
  // wire and dropped, payloads not waited for.
  void ignore(int rank) { ignored_.insert(rank); }
  bool ignored(int rank) const { return ignored_.contains(rank); }

  // Starts a send; the payload must stay alive until the handle completes.
  SendHandle post(int dest, MessageKind kind, const google::protobuf::MessageLite& header,
                  std::span<const std::byte> payload = {});
  // Starts a send that keeps the payload alive itself.
  SendHandle post(int dest, MessageKind kind, const google::protobuf::MessageLite& header,
                  std::shared_ptr<const std::vector<std::byte>> payload);
  // Starts a send of `payload`, which `owner` keeps alive until the send is done.
  SendHandle post(int dest, MessageKind kind, const google::protobuf::MessageLite& header,
                  std::span<const std::byte> payload, std::shared_ptr<const void> owner);
  // Sends and waits for local completion (buffers reusable).
  void send(int dest, MessageKind kind, const google::protobuf::MessageLite& header,
            std::span<const std::byte> payload = {});

  // Receives one message if a whole one is waiting (any kind when kind is
  // empty). A payload that does not follow its header within a moment (a
  // link cut mid-message) is left to arrive while the caller goes on; later
  // calls deliver it, in order among the messages of its sender.
  std::optional<Envelope> tryReceive(int source = MPI_ANY_SOURCE,
                                     std::optional<MessageKind> kind = std::nullopt);
  // Waits (polling, not spinning) until a message arrives or the timeout passes.
  std::optional<Envelope> receive(int source, std::optional<MessageKind> kind,
                                  std::chrono::milliseconds timeout);
  // Like receive, but a timeout is a TimeoutError naming what was awaited.
  Envelope receiveOrThrow(int source, std::optional<MessageKind> kind,
                          std::chrono::milliseconds timeout);

  // A barrier that sleeps while it waits.
  void barrier(std::chrono::milliseconds timeout);

  // Polls a request to completion without spinning.
  static void waitFor(MPI_Request& request, std::chrono::milliseconds timeout, const char* what);

 private:
  // A message being received: its first part is in, the rest is posted.
  struct Incoming {
    Envelope envelope;
    std::unique_ptr<std::string> frame;  // a large header's bytes while they arrive
    std::vector<MPI_Request> requests;   // that header, then the payload's chunks
    std::chrono::steady_clock::time_point started;
    std::chrono::milliseconds allowed{};
    bool complete = false;
  };

  static int payloadTag(MessageKind kind);
  // Receives the probed message's first part and posts the receives of the
  // rest (a large header, the payload's chunks).
  Incoming startReceive(MPI_Message& message, MPI_Status& status);
  // Tests the rest; past its allowance the sender is taken as lost.
  bool progress(Incoming& incoming);
  // Cancels what is still posted for it (a lost or silent sender).
  static void abandon(Incoming& incoming);
  // The oldest whole message matching the filter that no unfinished earlier
  // one of its sender (also matching) must precede.
  std::optional<Envelope> takeArrived(int source, std::optional<MessageKind> kind);

  MPI_Comm comm_;
  int rank_ = 0;
  int size_ = 0;
  std::size_t maxChunkBytes_;
  std::chrono::milliseconds payloadTimeout_{std::chrono::minutes(5)};
  std::set<int> ignored_;
  std::deque<Incoming> incoming_;  // arrival order
};

}  // namespace pointillist
