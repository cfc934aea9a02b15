#include "service/core/request_validation.hpp"

#include <cmath>

#include <glm/glm.hpp>

namespace pointillist::service {
namespace {

bool finite(const sv1::Vec3& v) {
  return std::isfinite(v.x()) && std::isfinite(v.y()) && std::isfinite(v.z());
}

glm::vec3 vec(const sv1::Vec3& v) {
  return {v.x(), v.y(), v.z()};
}

void invalid(const std::string& message) {
  throw RequestError(sv1::ERROR_INVALID_ARGUMENT, message);
}

}  // namespace

sv1::Request parseRequest(std::span<const std::byte> bytes, const RequestLimits& limits,
                          bool streamSocket) {
  if (bytes.size() > limits.maxMessageBytes) {
    throw RequestError(sv1::ERROR_TOO_LARGE, "message of " + std::to_string(bytes.size()) +
                                                 " bytes is over the cap of " +
                                                 std::to_string(limits.maxMessageBytes));
  }
  sv1::Request request;
  if (!request.ParseFromArray(bytes.data(), static_cast<int>(bytes.size()))) {
    throw RequestError(sv1::ERROR_MALFORMED,
                       "message of " + std::to_string(bytes.size()) + " bytes is not a Request");
  }
  try {
    validateRequest(request, limits, streamSocket);
  } catch (RequestError& error) {
    error.setRequestId(request.request_id());
    throw;
  }
  return request;
}

void validateRequest(const sv1::Request& request, const RequestLimits& limits, bool streamSocket) {
  if (request.version() != sv1::SERVICE_VERSION_CURRENT) {
    throw RequestError(sv1::ERROR_VERSION_MISMATCH,
                       "client speaks service version " + std::to_string(request.version()) +
                           ", this server speaks " +
                           std::to_string(static_cast<int>(sv1::SERVICE_VERSION_CURRENT)));
  }
  // Fields this server does not know (a newer client's body) land here.
  if (request.body_case() == sv1::Request::BODY_NOT_SET) {
    throw RequestError(sv1::ERROR_UNKNOWN_REQUEST, "request has no body this server knows");
  }
  const bool attach = request.body_case() == sv1::Request::kAttach;
  if (streamSocket != attach) {
    throw RequestError(sv1::ERROR_UNKNOWN_REQUEST, streamSocket
                                                       ? "the frames socket takes only attach"
                                                       : "attach belongs on the frames socket");
  }
  if (request.body_case() != sv1::Request::kHello && request.client_id().empty()) {
    throw RequestError(sv1::ERROR_UNKNOWN_CLIENT, "request without a client_id: send hello first");
  }
  switch (request.body_case()) {
    case sv1::Request::kHello:
      if (request.hello().client_name().size() > limits.maxClientName) {
        invalid("client_name is longer than " + std::to_string(limits.maxClientName) + " bytes");
      }
      break;
    case sv1::Request::kRender:
      if (!request.render().has_camera()) invalid("render request without a camera");
      validateCameraKey(request.render().camera(), "camera");
      validateFrameFormat(request.render().format(), limits);
      break;
    case sv1::Request::kPath: {
      const sv1::PathRequest& path = request.path();
      validateFrameFormat(path.format(), limits);
      if (path.path_case() == sv1::PathRequest::kBuiltin) {
        if (!isBuiltinCameraPath(path.builtin())) {
          std::string names;
          for (const auto& name : builtinCameraPaths()) names += (names.empty() ? "" : ", ") + name;
          invalid("camera path '" + path.builtin().substr(0, 64) + "' is not a built-in one (" +
                  names + "); files are not read for clients");
        }
        if (path.frames() == 0 || path.frames() > limits.maxPathFrames) {
          invalid("path frames " + std::to_string(path.frames()) + " not in [1, " +
                  std::to_string(limits.maxPathFrames) + "]");
        }
      } else if (path.path_case() == sv1::PathRequest::kCameras) {
        const auto count = static_cast<std::uint32_t>(path.cameras().keys_size());
        if (count == 0 || count > limits.maxPathFrames) {
          invalid("path of " + std::to_string(count) + " cameras not in [1, " +
                  std::to_string(limits.maxPathFrames) + "]");
        }
        for (int i = 0; i < path.cameras().keys_size(); ++i) {
          validateCameraKey(path.cameras().keys(i), "camera " + std::to_string(i));
        }
      } else {
        invalid("path request names neither a built-in path nor cameras");
      }
      break;
    }
    case sv1::Request::kSetOptions: {
      const sv1::SetOptionsRequest& options = request.set_options();
      validateFrameFormat(options.format(), limits);
      if (!std::isfinite(options.lod_pixels()) || options.lod_pixels() < 0.0f) {
        invalid("lod_pixels must be finite and not negative");
      }
      if (options.lod_pixels() > 64.0f) invalid("lod_pixels over 64");
      if (options.mode().size() > 32) invalid("mode name over 32 bytes");
      if (options.scheduler().size() > 32) invalid("scheduler name over 32 bytes");
      break;
    }
    case sv1::Request::kShutdown:
      if (request.shutdown().reason().size() > 256) invalid("shutdown reason over 256 bytes");
      break;
    default:
      break;
  }
}

void validateCameraKey(const sv1::CameraKey& key, const std::string& where) {
  if (!key.has_eye() || !key.has_target()) invalid(where + ": eye and target are required");
  if (!finite(key.eye()) || !finite(key.target()) || !finite(key.up()) ||
      !std::isfinite(key.fov_y_degrees())) {
    invalid(where + ": values must be finite");
  }
  const glm::vec3 view = vec(key.target()) - vec(key.eye());
  if (glm::length(view) <= 0.0f) invalid(where + ": eye and target are the same point");
  if (key.has_up()) {
    const glm::vec3 up = vec(key.up());
    if (glm::length(up) <= 0.0f) invalid(where + ": up is zero");
    if (glm::length(glm::cross(glm::normalize(view), glm::normalize(up))) < 1e-6f) {
      invalid(where + ": up is parallel to the view direction");
    }
  }
  if (key.fov_y_degrees() != 0.0f &&
      !(key.fov_y_degrees() > 0.0f && key.fov_y_degrees() < 180.0f)) {
    invalid(where + ": fov_y_degrees not in (0, 180)");
  }
}

void validateFrameFormat(const sv1::FrameFormat& format, const RequestLimits& limits) {
  const auto side = [&](std::uint32_t value, std::uint32_t max, const char* name) {
    if (value != 0 && (value < limits.minSide || value > max)) {
      invalid(std::string(name) + " " + std::to_string(value) + " not in [" +
              std::to_string(limits.minSide) + ", " + std::to_string(max) + "]");
    }
  };
  side(format.width(), limits.maxWidth, "width");
  side(format.height(), limits.maxHeight, "height");
  if (!sv1::Encoding_IsValid(format.encoding())) {
    invalid("encoding " + std::to_string(static_cast<int>(format.encoding())) + " is unknown");
  }
  if (format.jpeg_quality() > 100) invalid("jpeg_quality over 100");
}

CameraKey cameraKeyFromMessage(const sv1::CameraKey& key, const glm::vec3& defaultUp) {
  CameraKey out;
  out.up = defaultUp;
  out.eye = vec(key.eye());
  out.target = vec(key.target());
  if (key.has_up()) out.up = vec(key.up());
  if (key.fov_y_degrees() != 0.0f) out.fovYDegrees = key.fov_y_degrees();
  return out;
}

sv1::CameraKey cameraKeyMessage(const CameraKey& key) {
  const auto set = [](sv1::Vec3* out, const glm::vec3& v) {
    out->set_x(v.x);
    out->set_y(v.y);
    out->set_z(v.z);
  };
  sv1::CameraKey out;
  set(out.mutable_eye(), key.eye);
  set(out.mutable_target(), key.target);
  set(out.mutable_up(), key.up);
  out.set_fov_y_degrees(key.fovYDegrees);
  return out;
}

sv1::FrameFormat mergeFormat(const sv1::FrameFormat& base, const sv1::FrameFormat& update) {
  sv1::FrameFormat merged = base;
  if (update.width() != 0) merged.set_width(update.width());
  if (update.height() != 0) merged.set_height(update.height());
  if (update.encoding() != sv1::ENCODING_UNSPECIFIED) merged.set_encoding(update.encoding());
  if (update.jpeg_quality() != 0) merged.set_jpeg_quality(update.jpeg_quality());
  return merged;
}

const char* encodingName(sv1::Encoding encoding) {
  switch (encoding) {
    case sv1::ENCODING_RAW_RGBA:
      return "raw";
    case sv1::ENCODING_PNG:
      return "png";
    case sv1::ENCODING_JPEG:
      return "jpeg";
    default:
      return "unspecified";
  }
}

sv1::Encoding parseEncoding(const std::string& name) {
  if (name == "raw") return sv1::ENCODING_RAW_RGBA;
  if (name == "png") return sv1::ENCODING_PNG;
  if (name == "jpeg" || name == "jpg") return sv1::ENCODING_JPEG;
  throw UsageError("encoding '" + name + "' is not one of: raw, png, jpeg");
}

sv1::Reply errorReply(std::uint64_t requestId, sv1::ErrorCode code, const std::string& message) {
  sv1::Reply reply;
  reply.set_version(sv1::SERVICE_VERSION_CURRENT);
  reply.set_request_id(requestId);
  reply.mutable_error()->set_code(code);
  reply.mutable_error()->set_message(message);
  return reply;
}

}  // namespace pointillist::service
