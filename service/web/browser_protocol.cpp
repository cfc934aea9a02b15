#include "service/web/browser_protocol.hpp"

#include <boost/property_tree/json_parser.hpp>
#include <boost/property_tree/ptree.hpp>

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <sstream>
#include <vector>

#include "service/core/request_validation.hpp"

namespace pointillist::service::web {
namespace {

using boost::property_tree::ptree;

[[noreturn]] void refuse(const std::string& message) {
  throw BrowserMessageError(message);
}

double number(const ptree& node, const std::string& what) {
  if (!node.empty()) refuse(what + " must be a number");
  const std::string& text = node.data();
  if (text.empty() || text.size() > 64) refuse(what + " must be a number");
  char* end = nullptr;
  errno = 0;
  const double value = std::strtod(text.c_str(), &end);
  if (end != text.c_str() + text.size() || errno == ERANGE || !std::isfinite(value)) {
    refuse(what + " must be a finite number");
  }
  return value;
}

std::uint32_t side(const ptree& message, const char* key) {
  const auto node = message.get_child_optional(key);
  if (!node) return 0;
  const double value = number(*node, key);
  if (value < 0.0 || value > 65535.0 || value != std::floor(value)) {
    refuse(std::string(key) + " must be a whole number of pixels");
  }
  return static_cast<std::uint32_t>(value);
}

v1::Vec3 vec3(const ptree& message, const char* key, bool required, bool* present) {
  v1::Vec3 out;
  const auto node = message.get_child_optional(key);
  if (present != nullptr) *present = static_cast<bool>(node);
  if (!node) {
    if (required) refuse(std::string("\"") + key + "\" is required");
    return out;
  }
  std::vector<float> values;
  for (const auto& [name, element] : *node) {
    if (!name.empty()) refuse(std::string(key) + " must be an array of 3 numbers");
    values.push_back(static_cast<float>(number(element, key)));
  }
  if (values.size() != 3) refuse(std::string(key) + " must be an array of 3 numbers");
  out.set_x(values[0]);
  out.set_y(values[1]);
  out.set_z(values[2]);
  return out;
}

std::string vec3Json(const v1::Vec3& v) {
  char text[128];
  std::snprintf(text, sizeof text, "[%.9g,%.9g,%.9g]", static_cast<double>(v.x()),
                static_cast<double>(v.y()), static_cast<double>(v.z()));
  return text;
}

}  // namespace

BrowserCameraRequest parseBrowserMessage(std::string_view text) {
  if (text.size() > kMaxBrowserMessageBytes) refuse("message over the size cap");
  ptree message;
  try {
    std::istringstream stream{std::string(text)};
    boost::property_tree::read_json(stream, message);
  } catch (const boost::property_tree::json_parser_error& error) {
    refuse("not JSON: " + error.message());
  }
  const auto type = message.get_optional<std::string>("type");
  if (!type || !message.get_child("type").empty()) refuse("a message needs a \"type\"");
  if (*type != "camera") refuse("unknown message type '" + type->substr(0, 32) + "'");

  BrowserCameraRequest request;
  const auto id = message.get_child_optional("id");
  if (!id) refuse("\"id\" is required");
  const double idValue = number(*id, "id");
  if (idValue < 0.0 || idValue > 9007199254740991.0 || idValue != std::floor(idValue)) {
    refuse("id must be a whole number from 0 to 2^53-1");
  }
  request.id = static_cast<std::uint64_t>(idValue);
  *request.camera.mutable_eye() = vec3(message, "eye", true, nullptr);
  *request.camera.mutable_target() = vec3(message, "target", true, nullptr);
  bool hasUp = false;
  const v1::Vec3 up = vec3(message, "up", false, &hasUp);
  if (hasUp) *request.camera.mutable_up() = up;
  if (const auto fov = message.get_child_optional("fov")) {
    request.camera.set_fov_y_degrees(static_cast<float>(number(*fov, "fov")));
  }
  request.width = side(message, "width");
  request.height = side(message, "height");
  if (const auto mode = message.get_optional<std::string>("mode")) {
    if (!message.get_child("mode").empty() ||
        (*mode != "points" && *mode != "splats" && *mode != "blended")) {
      refuse("mode must be \"points\", \"splats\" or \"blended\"");
    }
    request.mode = *mode;
  }
  if (const auto lod = message.get_child_optional("lod")) {
    const double value = number(*lod, "lod");
    if (!(value > 0.0 && value <= 64.0)) refuse("lod must be in (0, 64] pixels");
    request.lodPixels = static_cast<float>(value);
  }
  try {
    validateCameraKey(request.camera, "camera");
    v1::FrameFormat format;
    format.set_width(request.width);
    format.set_height(request.height);
    validateFrameFormat(format, RequestLimits{});
  } catch (const RequestError& error) {
    refuse(error.what());
  }
  return request;
}

std::string jsonEscape(std::string_view text) {
  std::string out;
  out.reserve(text.size() + 2);
  for (const char c : text) {
    switch (c) {
      case '"':
        out += "\\\"";
        break;
      case '\\':
        out += "\\\\";
        break;
      case '\n':
        out += "\\n";
        break;
      case '\r':
        out += "\\r";
        break;
      case '\t':
        out += "\\t";
        break;
      default:
        if (static_cast<unsigned char>(c) < 0x20) {
          char escaped[8];
          std::snprintf(escaped, sizeof escaped, "\\u%04x", static_cast<unsigned>(c));
          out += escaped;
        } else {
          out += c;
        }
    }
  }
  return out;
}

std::string infoJson(const v1::DatasetInfo& info, const v1::FrameFormat& format) {
  std::ostringstream out;
  out << R"({"type":"info","name":")" << jsonEscape(info.name()) << R"(","bounds_min":)"
      << vec3Json(info.bounds_min()) << R"(,"bounds_max":)" << vec3Json(info.bounds_max())
      << R"(,"default_up":)" << vec3Json(info.default_up()) << R"(,"points":)" << info.points()
      << R"(,"layout":")" << jsonEscape(info.layout()) << R"(","mode":")" << jsonEscape(info.mode())
      << R"(","max_width":)" << info.max_width() << R"(,"max_height":)" << info.max_height()
      << R"(,"width":)" << format.width() << R"(,"height":)" << format.height()
      << R"(,"encoding":")" << encodingName(format.encoding()) << R"(","lod_pixels":)"
      << info.lod_pixels() << R"(,"modes_available":[)";
  for (int i = 0; i < info.modes_available_size(); ++i) {
    out << (i > 0 ? "," : "") << '"' << jsonEscape(info.modes_available(i)) << '"';
  }
  out << "]}";
  return out.str();
}

const char* frameStatusName(v1::FrameStatus status) {
  switch (status) {
    case v1::FRAME_STATUS_OK:
      return "ok";
    case v1::FRAME_STATUS_SUPERSEDED:
      return "superseded";
    case v1::FRAME_STATUS_INCOMPLETE:
      return "incomplete";
    default:
      return "unknown";
  }
}

std::string frameJson(const v1::FrameHeader& header, std::uint64_t browserId, double latencyMs,
                      const char* status) {
  char text[768];
  std::snprintf(
      text, sizeof text,
      R"({"type":"frame","id":%llu,"status":"%s","frame_id":%llu,"width":%u,"height":%u,)"
      R"("encoding":"%s","bytes":%llu,"splats":%llu,"tiles":%u,"latency_ms":%.2f,)"
      R"("queued_ms":%.2f,"render_ms":%.2f,"encode_ms":%.2f,"mode":"%s","lod_pixels":%g,)"
      R"("interim":%s,"cache_filled":%.3f,"tiles_composed":%u,"region":[%u,%u,%u,%u]})",
      static_cast<unsigned long long>(browserId), status,
      static_cast<unsigned long long>(header.frame_id()), header.width(), header.height(),
      encodingName(header.encoding()), static_cast<unsigned long long>(header.encoded_bytes()),
      static_cast<unsigned long long>(header.splats()), header.tiles(), latencyMs,
      header.queued_ms(), header.render_ms(), header.encode_ms(),
      jsonEscape(header.mode().substr(0, 32)).c_str(), static_cast<double>(header.lod_pixels()),
      header.interim() ? "true" : "false", static_cast<double>(header.cache_filled()),
      header.tiles_composed(), header.region_x(), header.region_y(), header.region_width(),
      header.region_height());
  return text;
}

std::string errorJson(std::string_view message, std::int64_t id) {
  std::string out = R"({"type":"error","message":")" + jsonEscape(message) + "\"";
  if (id >= 0) out += ",\"id\":" + std::to_string(id);
  return out + "}";
}

}  // namespace pointillist::service::web
