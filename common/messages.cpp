#include "common/messages.hpp"

namespace pointillist {

const char* messageKindName(MessageKind kind) {
  switch (kind) {
    case MessageKind::Handshake:
      return "Handshake";
    case MessageKind::HandshakeReply:
      return "HandshakeReply";
    case MessageKind::Ready:
      return "Ready";
    case MessageKind::Shutdown:
      return "Shutdown";
    case MessageKind::ShutdownAck:
      return "ShutdownAck";
    case MessageKind::ErrorReport:
      return "ErrorReport";
    case MessageKind::Heartbeat:
      return "Heartbeat";
    case MessageKind::PeerLost:
      return "PeerLost";
    case MessageKind::WorkRequest:
      return "WorkRequest";
    case MessageKind::TileTask:
      return "TileTask";
    case MessageKind::NoWork:
      return "NoWork";
    case MessageKind::RenderPacket:
      return "RenderPacket";
    case MessageKind::SendOrder:
      return "SendOrder";
    case MessageKind::DataPacket:
      return "DataPacket";
    case MessageKind::TileImage:
      return "TileImage";
    case MessageKind::RenderReport:
      return "RenderReport";
    case MessageKind::Test:
      return "Test";
  }
  return "unknown";
}

}  // namespace pointillist
