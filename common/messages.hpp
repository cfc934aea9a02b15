#pragma once
// Message kinds and the outbox: how the roles' MPI-free cores say what to send.
//
// A core takes a message and `now` and appends what should go out to an
// Outbox; the MPI role posts every entry with the typed channel, and the
// simulator delivers the same entries in simulated time. The protobuf
// messages are the ones in proto/pointillist.proto.
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include "common/errors.hpp"
#include "pointillist.pb.h"

namespace pointillist {

// One tag per message kind. Values are part of the protocol: never renumber.
enum class MessageKind : int {
  Handshake = 1,
  HandshakeReply = 2,
  Ready = 3,
  Shutdown = 4,
  ShutdownAck = 5,
  ErrorReport = 6,
  Heartbeat = 7,
  PeerLost = 8,
  WorkRequest = 10,
  TileTask = 11,
  NoWork = 12,
  RenderPacket = 13,
  SendOrder = 14,
  DataPacket = 15,
  TileImage = 16,
  RenderReport = 17,
  Test = 100,
};

const char* messageKindName(MessageKind kind);

// The kind each message type travels as.
template <class M>
constexpr MessageKind kindOf() {
  if constexpr (std::is_same_v<M, v1::WorkRequest>)
    return MessageKind::WorkRequest;
  else if constexpr (std::is_same_v<M, v1::TileTask>)
    return MessageKind::TileTask;
  else if constexpr (std::is_same_v<M, v1::RenderPacket>)
    return MessageKind::RenderPacket;
  else if constexpr (std::is_same_v<M, v1::SendOrder>)
    return MessageKind::SendOrder;
  else if constexpr (std::is_same_v<M, v1::DataPacketHeader>)
    return MessageKind::DataPacket;
  else if constexpr (std::is_same_v<M, v1::TileImageHeader>)
    return MessageKind::TileImage;
  else if constexpr (std::is_same_v<M, v1::RenderReport>)
    return MessageKind::RenderReport;
  else
    static_assert(sizeof(M) == 0, "this message type travels on no tag of its own");
}

// One message for one or more peers (world ranks); shared, never copied per peer.
struct Outgoing {
  MessageKind kind = MessageKind::Test;
  std::vector<int> destinations;
  std::shared_ptr<const google::protobuf::MessageLite> message;

  // The message as its type; a ProtocolError when the kind does not match.
  template <class M>
  const M& as() const {
    if (kind != kindOf<M>()) {
      throw ProtocolError(std::string("an outgoing ") + messageKindName(kind) +
                          " message read as " + messageKindName(kindOf<M>()));
    }
    return static_cast<const M&>(*message);
  }
};

// What a core wants sent, in the order it must leave: a peer sees the messages
// one core sends it in outbox order (the channel keeps order per sender).
class Outbox {
 public:
  template <class M>
  void send(int destination, M message) {
    send(std::vector<int>{destination}, std::move(message));
  }
  template <class M>
  void send(std::vector<int> destinations, M message) {
    if (destinations.empty()) return;
    entries_.push_back(Outgoing{kindOf<M>(), std::move(destinations),
                                std::make_shared<const M>(std::move(message))});
  }

  std::span<const Outgoing> entries() const { return entries_; }
  bool empty() const { return entries_.empty(); }
  // Hands the entries over and leaves the outbox empty.
  std::vector<Outgoing> take() { return std::exchange(entries_, {}); }

 private:
  std::vector<Outgoing> entries_;
};

}  // namespace pointillist
