#pragma once
// Turns the bytes of an incoming message into a checked Request, or a
// RequestError carrying the error code the client gets back. Nothing here
// touches sockets or server state, so a refused request changes nothing.
#include <cstddef>
#include <cstdint>
#include <span>
#include <string>

#include "common/camera_path.hpp"
#include "common/errors.hpp"
#include "service_v1.pb.h"

namespace pointillist::service {

namespace sv1 = pointillist::service::v1;

class RequestError : public Error {
 public:
  RequestError(sv1::ErrorCode code, const std::string& message) : Error(message), code_(code) {}
  sv1::ErrorCode code() const noexcept { return code_; }
  const char* kind() const noexcept override { return "request error"; }
  // The refused request's id, when it parsed far enough to have one: the
  // error reply carries it, so the client can match it to its request.
  std::uint64_t requestId() const noexcept { return requestId_; }
  void setRequestId(std::uint64_t id) noexcept { requestId_ = id; }

 private:
  sv1::ErrorCode code_;
  std::uint64_t requestId_ = 0;
};

struct RequestLimits {
  std::size_t maxMessageBytes = 64 * 1024;
  std::uint32_t maxWidth = 4096;
  std::uint32_t maxHeight = 4096;
  std::uint32_t minSide = 16;
  std::uint32_t maxPathFrames = 1000;
  std::size_t maxClientName = 64;
};

// Parses and checks one message: size, protobuf, version, a known body and
// every field of it. `streamSocket` is true for the frames socket, which takes
// only `attach`, and the control socket refuses `attach`.
sv1::Request parseRequest(std::span<const std::byte> bytes, const RequestLimits& limits,
                          bool streamSocket = false);
// The checks parseRequest applies to a parsed Request.
void validateRequest(const sv1::Request& request, const RequestLimits& limits,
                     bool streamSocket = false);

// A camera key with finite values, eye away from target, up not along the
// view, fov in (0, 180).
void validateCameraKey(const sv1::CameraKey& key, const std::string& where);
// Width and height 0 (keep) or within limits, encoding known or unspecified
// (keep), jpeg quality 0 (keep) or 1-100.
void validateFrameFormat(const sv1::FrameFormat& format, const RequestLimits& limits);

// A key without up gets `defaultUp` (the data's up axis), fov 0 gets 45 degrees.
CameraKey cameraKeyFromMessage(const sv1::CameraKey& key, const glm::vec3& defaultUp);
sv1::CameraKey cameraKeyMessage(const CameraKey& key);

// A client's format with the non-zero fields of `update` applied.
sv1::FrameFormat mergeFormat(const sv1::FrameFormat& base, const sv1::FrameFormat& update);

// "raw", "png", "jpeg"; they parse back.
const char* encodingName(sv1::Encoding encoding);
sv1::Encoding parseEncoding(const std::string& name);  // UsageError for others

sv1::Reply errorReply(std::uint64_t requestId, sv1::ErrorCode code, const std::string& message);

}  // namespace pointillist::service
