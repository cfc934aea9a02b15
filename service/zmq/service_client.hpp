#pragma once
// A client of the rendering service: hello, the frames stream attached, then
// requests with replies and frames as they come. pointillist-client and the
// tests use it; the Python client (clients/python) speaks the same protocol.
#include <chrono>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <zmq.hpp>

#include "service/core/request_validation.hpp"

namespace pointillist::service {

// An error reply from the server.
class ServiceError : public Error {
 public:
  ServiceError(v1::ErrorCode code, const std::string& message) : Error(message), code_(code) {}
  v1::ErrorCode code() const noexcept { return code_; }
  const char* kind() const noexcept override { return "service error"; }

 private:
  v1::ErrorCode code_;
};

struct ReceivedFrame {
  v1::FrameHeader header;
  std::vector<std::uint8_t> pixels;
  std::chrono::steady_clock::time_point received;
};

// CURVE: the server's public key and this client's secret key (Z85).
struct CurveClientKeys {
  std::string serverPublicKey;
  std::string secretKey;
};

class ServiceClient {
 public:
  // Connects, says hello and attaches the frames stream. A TimeoutError when
  // the server does not answer within `timeout`; ServiceError for a refusal.
  ServiceClient(const std::string& controlEndpoint, const std::string& name,
                std::chrono::milliseconds timeout, const CurveClientKeys* curve = nullptr);

  const v1::HelloReply& helloReply() const { return hello_; }
  const std::string& clientId() const { return hello_.client_id(); }

  v1::DatasetInfo info();
  // Returns the request id its frames carry.
  std::uint64_t render(const v1::CameraKey& camera, const v1::FrameFormat& format = {},
                       v1::RenderAccepted* accepted = nullptr);
  std::uint64_t path(const v1::PathRequest& path, v1::RenderAccepted* accepted = nullptr);
  // This client's format, mode and level of detail (and every client's scheduler).
  v1::OptionsReply setOptions(const v1::SetOptionsRequest& options);
  v1::Statistics stats();
  void shutdown(const std::string& reason);

  // The next frame (or superseded notice) on the stream, or nothing by
  // `timeout`, or nothing as soon as `wakeFd` (when not -1) is readable: a
  // caller waiting for frames can be woken by its other work (pointillist-web).
  std::optional<ReceivedFrame> receiveFrame(std::chrono::milliseconds timeout, int wakeFd = -1);

  // A request with this client's id and a fresh request id; answered or thrown.
  v1::Reply call(v1::Request request);

 private:
  v1::Reply exchange(const v1::Request& request);

  std::chrono::milliseconds timeout_;
  zmq::context_t context_;
  zmq::socket_t control_;
  zmq::socket_t stream_;
  v1::HelloReply hello_;
  std::uint64_t nextRequestId_ = 1;
};

// The frames endpoint a client connects to: the server's answer, with a
// wildcard host (0.0.0.0, *, [::]) replaced by the control endpoint's host.
std::string reachableStreamEndpoint(const std::string& advertised, const std::string& control);

}  // namespace pointillist::service
