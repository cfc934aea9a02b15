#include "service/zmq/service_client.hpp"

#include <regex>

#include "service/zmq/curve_keys.hpp"
#include "service/zmq/service_front_end.hpp"

namespace pointillist::service {
namespace {

zmq::message_t serialized(const google::protobuf::MessageLite& message) {
  const std::string bytes = message.SerializeAsString();
  return zmq::message_t(bytes.data(), bytes.size());
}

std::vector<zmq::message_t> receiveParts(zmq::socket_t& socket) {
  std::vector<zmq::message_t> parts;
  while (true) {
    zmq::message_t part;
    if (!socket.recv(part, zmq::recv_flags::dontwait)) break;
    const bool more = part.more();
    parts.push_back(std::move(part));
    if (!more) break;
  }
  return parts;
}

bool waitReadable(zmq::socket_t& socket, std::chrono::milliseconds timeout) {
  zmq::pollitem_t item{socket.handle(), 0, ZMQ_POLLIN, 0};
  return zmq::poll(&item, 1, timeout) > 0;
}

}  // namespace

std::string reachableStreamEndpoint(const std::string& advertised, const std::string& control) {
  static const std::regex wildcard(R"(^tcp://(0\.0\.0\.0|\*|\[::\]|::):([0-9]+)$)");
  static const std::regex host(R"(^tcp://(.+):([0-9]+|\*)$)");
  std::smatch wild, controlHost;
  if (std::regex_match(advertised, wild, wildcard) &&
      std::regex_match(control, controlHost, host)) {
    return "tcp://" + controlHost[1].str() + ":" + wild[2].str();
  }
  return advertised;
}

ServiceClient::ServiceClient(const std::string& controlEndpoint, const std::string& name,
                             std::chrono::milliseconds timeout, const CurveClientKeys* curve)
    : timeout_(timeout),
      context_(1),
      control_(context_, zmq::socket_type::dealer),
      stream_(context_, zmq::socket_type::dealer) {
  control_.set(zmq::sockopt::linger, 0);
  stream_.set(zmq::sockopt::linger, 0);
  stream_.set(zmq::sockopt::rcvhwm, 16);
  if (curve != nullptr) {
    const std::string publicKey = curvePublicKey(curve->secretKey);
    for (zmq::socket_t* socket : {&control_, &stream_}) {
      socket->set(zmq::sockopt::curve_serverkey, curve->serverPublicKey);
      socket->set(zmq::sockopt::curve_publickey, publicKey);
      socket->set(zmq::sockopt::curve_secretkey, curve->secretKey);
    }
  }
  control_.connect(controlEndpoint);
  v1::Request request;
  request.mutable_hello()->set_client_name(name);
  hello_ = call(std::move(request)).hello();

  stream_.set(zmq::sockopt::routing_id, hello_.client_id());
  stream_.connect(reachableStreamEndpoint(hello_.stream_endpoint(), controlEndpoint));
  v1::Request attach;
  attach.set_version(v1::SERVICE_VERSION_CURRENT);
  attach.set_client_id(hello_.client_id());
  attach.set_request_id(nextRequestId_++);
  attach.mutable_attach();
  stream_.send(serialized(attach), zmq::send_flags::none);
  const auto deadline = std::chrono::steady_clock::now() + timeout_;
  while (true) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
        deadline - std::chrono::steady_clock::now());
    if (left.count() <= 0 || !waitReadable(stream_, left)) {
      throw TimeoutError("no answer to attach on the frames stream " + hello_.stream_endpoint());
    }
    auto parts = receiveParts(stream_);
    if (parts.size() != 3 || parts[0].to_string() != kStreamReplyTag) continue;
    v1::Reply reply;
    if (!reply.ParseFromArray(parts[1].data(), static_cast<int>(parts[1].size()))) {
      throw ProtocolError("the frames stream answered attach with something that is not a Reply");
    }
    if (reply.has_error()) throw ServiceError(reply.error().code(), reply.error().message());
    if (reply.has_attached()) break;
  }
}

v1::Reply ServiceClient::exchange(const v1::Request& request) {
  // [""] first, as REQ would send, so the server's reply envelope matches.
  control_.send(zmq::message_t(), zmq::send_flags::sndmore);
  control_.send(serialized(request), zmq::send_flags::none);
  const auto deadline = std::chrono::steady_clock::now() + timeout_;
  while (true) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
        deadline - std::chrono::steady_clock::now());
    if (left.count() <= 0 || !waitReadable(control_, left)) {
      throw TimeoutError("the service did not answer within " + std::to_string(timeout_.count()) +
                         " ms");
    }
    auto parts = receiveParts(control_);
    if (parts.empty()) continue;
    v1::Reply reply;
    if (!reply.ParseFromArray(parts.back().data(), static_cast<int>(parts.back().size()))) {
      throw ProtocolError("the service answered with something that is not a Reply");
    }
    // A late answer to an earlier, timed-out request is skipped.
    if (reply.request_id() != request.request_id() && request.request_id() != 0) continue;
    return reply;
  }
}

v1::Reply ServiceClient::call(v1::Request request) {
  request.set_version(v1::SERVICE_VERSION_CURRENT);
  if (!request.has_hello()) request.set_client_id(hello_.client_id());
  request.set_request_id(nextRequestId_++);
  v1::Reply reply = exchange(request);
  if (reply.has_error()) throw ServiceError(reply.error().code(), reply.error().message());
  return reply;
}

v1::DatasetInfo ServiceClient::info() {
  v1::Request request;
  request.mutable_info();
  return call(std::move(request)).info();
}

std::uint64_t ServiceClient::render(const v1::CameraKey& camera, const v1::FrameFormat& format,
                                    v1::RenderAccepted* accepted) {
  v1::Request request;
  *request.mutable_render()->mutable_camera() = camera;
  *request.mutable_render()->mutable_format() = format;
  const std::uint64_t id = nextRequestId_;
  const v1::Reply reply = call(std::move(request));
  if (accepted != nullptr) *accepted = reply.accepted();
  return id;
}

std::uint64_t ServiceClient::path(const v1::PathRequest& path, v1::RenderAccepted* accepted) {
  v1::Request request;
  *request.mutable_path() = path;
  const std::uint64_t id = nextRequestId_;
  const v1::Reply reply = call(std::move(request));
  if (accepted != nullptr) *accepted = reply.accepted();
  return id;
}

v1::OptionsReply ServiceClient::setOptions(const v1::SetOptionsRequest& options) {
  v1::Request request;
  *request.mutable_set_options() = options;
  return call(std::move(request)).options();
}

v1::Statistics ServiceClient::stats() {
  v1::Request request;
  request.mutable_stats();
  return call(std::move(request)).stats();
}

void ServiceClient::shutdown(const std::string& reason) {
  v1::Request request;
  request.mutable_shutdown()->set_reason(reason);
  call(std::move(request));
}

std::optional<ReceivedFrame> ServiceClient::receiveFrame(std::chrono::milliseconds timeout,
                                                         int wakeFd) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (true) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
        deadline - std::chrono::steady_clock::now());
    if (left.count() < 0) return std::nullopt;
    if (wakeFd >= 0) {
      zmq::pollitem_t items[] = {{stream_.handle(), 0, ZMQ_POLLIN, 0},
                                 {nullptr, wakeFd, ZMQ_POLLIN, 0}};
      if (zmq::poll(items, 2, left) == 0 || (items[1].revents & ZMQ_POLLIN) != 0) {
        return std::nullopt;
      }
    } else if (!waitReadable(stream_, left)) {
      return std::nullopt;
    }
    auto parts = receiveParts(stream_);
    if (parts.size() != 3 || parts[0].to_string() != kStreamFrameTag) continue;
    ReceivedFrame frame;
    frame.received = std::chrono::steady_clock::now();
    if (!frame.header.ParseFromArray(parts[1].data(), static_cast<int>(parts[1].size()))) {
      throw ProtocolError("a frame on the stream has a header that does not parse");
    }
    const auto* bytes = static_cast<const std::uint8_t*>(parts[2].data());
    frame.pixels.assign(bytes, bytes + parts[2].size());
    return frame;
  }
}

}  // namespace pointillist::service
