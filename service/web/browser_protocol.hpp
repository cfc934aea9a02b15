#pragma once
// What the viewer page and pointillist-web say to each other over the
// WebSocket. The browser sends JSON text:
//   {"type":"camera","id":7,"eye":[x,y,z],"target":[x,y,z],"up":[x,y,z],
//    "fov":45,"width":1280,"height":720,"mode":"splats","lod":2}
//   (up, fov, width, height, mode and lod optional; mode and lod are this
//   browser's service options, set before the camera's frame when they change)
// and gets JSON text back:
//   {"type":"info",...}      the dataset (bounds, up, counts) once connected
//   {"type":"frame",...}     a frame's metadata; when "status" is "ok" or
//                            "incomplete" one binary message (the encoded image) follows
//   {"type":"error","message":"...","id":7}   a refused message or request
// Nothing here touches sockets, so the unit tests drive it directly.
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>

#include "common/errors.hpp"
#include "service_v1.pb.h"

namespace pointillist::service::web {

// The largest message a browser may send; a camera is about 200 bytes.
inline constexpr std::size_t kMaxBrowserMessageBytes = 4096;

// A browser message that is not JSON, not a known type, or out of range.
class BrowserMessageError : public Error {
 public:
  using Error::Error;
  const char* kind() const noexcept override { return "browser message error"; }
};

struct BrowserCameraRequest {
  std::uint64_t id = 0;  // the page's own number, echoed in the frame's metadata
  v1::CameraKey camera;
  std::uint32_t width = 0;  // 0: the service's default for this client
  std::uint32_t height = 0;
  std::string mode;        // points | splats | blended; empty: unchanged
  float lodPixels = 0.0f;  // target splat size in pixels, (0, 64]; 0: unchanged
};

// Parses and checks one message (camera values as the service checks them).
// Throws BrowserMessageError; the caller answers with errorJson.
BrowserCameraRequest parseBrowserMessage(std::string_view text);

std::string jsonEscape(std::string_view text);

std::string infoJson(const v1::DatasetInfo& info, const v1::FrameFormat& format);
std::string frameJson(const v1::FrameHeader& header, std::uint64_t browserId, double latencyMs,
                      const char* status);
// `id` < 0: not about one request.
std::string errorJson(std::string_view message, std::int64_t id = -1);

// "ok", "superseded", "incomplete"
const char* frameStatusName(v1::FrameStatus status);

}  // namespace pointillist::service::web
