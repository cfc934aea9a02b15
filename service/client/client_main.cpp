// pointillist-client: talks to a job started with `deploy/run.sh --serve`.
//   pointillist-client info
//   pointillist-client render --camera ex,ey,ez,tx,ty,tz[,ux,uy,uz[,fov]] -o frame.png
//   pointillist-client path --camera-path orbit --frames 24 -o DIR
//   pointillist-client orbit --frames 48        (one camera at a time: latency and frames/s)
//   pointillist-client stats | shutdown
#include <CLI/CLI.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <optional>
#include <sstream>
#include <thread>

#include "common/camera_path.hpp"
#include "common/clock.hpp"
#include "common/tool_entry.hpp"
#include "service/core/frame_encoding.hpp"
#include "service/core/latency_window.hpp"
#include "service/zmq/curve_keys.hpp"
#include "service/zmq/service_client.hpp"

namespace pointillist::service {
namespace {

using SteadyClock = std::chrono::steady_clock;

struct ClientOptions {
  std::string connect = "tcp://127.0.0.1:5570";
  std::string name = "pointillist-client";
  double timeoutSeconds = 30.0;
  std::string encoding;  // empty: the server's default for this client
  std::string size;      // WxH; empty: the server's default
  std::uint32_t jpegQuality = 0;
  // What this client's frames are drawn with (empty or 0: the job's).
  std::string mode;
  float lodPixels = 0.0f;
  std::string scheduler;  // every client's, from the next frame on
  // render
  std::string camera;
  std::string output;
  // path, orbit
  std::string cameraPath = "orbit";
  std::uint32_t frames = 24;
  double readDelayMs = 0.0;
  bool neverRead = false;
  double frameTimeoutSeconds = 120.0;
  // render: also write the interim frame (render cache) beside the output
  bool keepInterim = false;
  // orbit: per-frame figures as CSV
  std::string csv;
  // shutdown
  std::string reason = "asked by pointillist-client";
  // CURVE
  std::string curveServerKey;  // file with the server's public key
  std::string curveKey;        // file with this client's secret key
  std::string keygenPrefix;
};

v1::FrameFormat requestedFormat(const ClientOptions& options) {
  v1::FrameFormat format;
  if (!options.encoding.empty()) format.set_encoding(parseEncoding(options.encoding));
  if (!options.size.empty()) {
    const auto [width, height] = parseImageSize(options.size);
    format.set_width(width);
    format.set_height(height);
  }
  format.set_jpeg_quality(options.jpegQuality);
  return format;
}

v1::CameraKey parseCamera(const std::string& text) {
  std::vector<float> values;
  std::stringstream stream(text);
  std::string item;
  while (std::getline(stream, item, ',')) {
    try {
      std::size_t used = 0;
      values.push_back(std::stof(item, &used));
      if (used != item.size()) throw std::invalid_argument(item);
    } catch (const std::exception&) {
      throw UsageError("--camera: '" + item + "' is not a number");
    }
  }
  if (values.size() != 6 && values.size() != 9 && values.size() != 10) {
    throw UsageError("--camera takes ex,ey,ez,tx,ty,tz[,ux,uy,uz[,fovY]] (6, 9 or 10 numbers)");
  }
  CameraKey key;
  key.eye = {values[0], values[1], values[2]};
  key.target = {values[3], values[4], values[5]};
  v1::CameraKey message = cameraKeyMessage(key);
  if (values.size() >= 9) {
    message.mutable_up()->set_x(values[6]);
    message.mutable_up()->set_y(values[7]);
    message.mutable_up()->set_z(values[8]);
  } else {
    message.clear_up();  // the server uses the data's up axis
  }
  message.set_fov_y_degrees(values.size() == 10 ? values[9] : 0.0f);
  return message;
}

// Writes the frame in the format the file's extension names (.png, .jpg/.jpeg,
// .rgba); the pixels travel as the chosen encoding and are converted here.
void writeFrame(const ReceivedFrame& frame, const std::filesystem::path& path) {
  const v1::FrameHeader& header = frame.header;
  std::string extension = path.extension().string();
  std::transform(extension.begin(), extension.end(), extension.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  const v1::Encoding wanted = extension == ".jpg" || extension == ".jpeg" ? v1::ENCODING_JPEG
                              : extension == ".rgba"                      ? v1::ENCODING_RAW_RGBA
                                                                          : v1::ENCODING_PNG;
  std::vector<std::uint8_t> bytes = frame.pixels;
  if (wanted != header.encoding()) {
    const Image image =
        decodeFrame(frame.pixels, header.encoding(), header.width(), header.height());
    bytes = encodeFrame(image, wanted);
  }
  if (path.has_parent_path()) std::filesystem::create_directories(path.parent_path());
  const std::filesystem::path temporary = path.string() + ".part";
  {
    std::ofstream out(temporary, std::ios::binary);
    out.write(reinterpret_cast<const char*>(bytes.data()),
              static_cast<std::streamsize>(bytes.size()));
    if (!out) throw Error("cannot write " + temporary.string());
  }
  std::filesystem::rename(temporary, path);
}

void printFrame(const ReceivedFrame& frame, double latencyMs) {
  const v1::FrameHeader& header = frame.header;
  std::printf(
      "frame %llu (request %llu, %u/%u): %s, latency %.1f ms (queued %.1f, render %.1f, encode "
      "%.1f), %.2f M splats, %u tiles, %.1f KiB %s\n",
      static_cast<unsigned long long>(header.frame_id()),
      static_cast<unsigned long long>(header.request_id()), header.path_index() + 1,
      header.path_length(), v1::FrameStatus_Name(header.status()).c_str(), latencyMs,
      header.queued_ms(), header.render_ms(), header.encode_ms(),
      static_cast<double>(header.splats()) / 1e6, header.tiles(),
      static_cast<double>(header.encoded_bytes()) / 1024.0, encodingName(header.encoding()));
  if (!header.mode().empty()) {
    std::printf("  drawn as %s, lod %g px, scheduler %s\n", header.mode().c_str(),
                static_cast<double>(header.lod_pixels()), header.scheduler().c_str());
  }
  std::fflush(stdout);
}

// The final frame of a render request; interim frames from the display's
// render cache that come first go to `interim` when given, else are skipped.
ReceivedFrame awaitFrame(ServiceClient& client, std::uint64_t requestId,
                         const ClientOptions& options,
                         std::vector<ReceivedFrame>* interim = nullptr) {
  const auto timeout =
      std::chrono::milliseconds(static_cast<long>(options.frameTimeoutSeconds * 1e3));
  while (true) {
    auto frame = client.receiveFrame(timeout);
    if (!frame) throw TimeoutError("no frame for request " + std::to_string(requestId));
    if (frame->header.request_id() != requestId) continue;
    if (!frame->header.interim()) return std::move(*frame);
    if (interim != nullptr) interim->push_back(std::move(*frame));
  }
}

// What the client shows after an interim frame: the whole frame, or a region
// of it (service version 3) painted over the interim frame shown so far.
void showInterim(const ReceivedFrame& frame, Image& shown) {
  const v1::FrameHeader& header = frame.header;
  if (header.region_width() == 0) {
    shown = decodeFrame(frame.pixels, header.encoding(), header.width(), header.height());
    return;
  }
  if (shown.width() != header.width() || shown.height() != header.height() ||
      header.region_height() == 0 || header.region_x() > header.width() ||
      header.region_width() > header.width() - header.region_x() ||
      header.region_y() > header.height() ||
      header.region_height() > header.height() - header.region_y()) {
    throw ProtocolError(
        "interim frame " + std::to_string(header.frame_id()) + ": region " +
        std::to_string(header.region_width()) + "x" + std::to_string(header.region_height()) +
        " at " + std::to_string(header.region_x()) + "," + std::to_string(header.region_y()) +
        " does not fit the " + std::to_string(shown.width()) + "x" +
        std::to_string(shown.height()) + " frame shown");
  }
  const Image region =
      decodeFrame(frame.pixels, header.encoding(), header.region_width(), header.region_height());
  blit(region, shown, header.region_x(),
       header.height() - header.region_y() - header.region_height());
}

void printLatency(const char* what, const LatencyWindow& window) {
  const LatencyFigures figures = window.figures();
  std::printf("%s: %llu frames, median %.1f ms, p95 %.1f ms, max %.1f ms\n", what,
              static_cast<unsigned long long>(figures.count), figures.median, figures.p95,
              figures.max);
}

int info(ServiceClient& client) {
  const v1::DatasetInfo info = client.info();
  std::printf("dataset %s: %llu points, %llu level-splats, %llu cells (%u top-level)\n",
              info.name().c_str(), static_cast<unsigned long long>(info.points()),
              static_cast<unsigned long long>(info.level_splats()),
              static_cast<unsigned long long>(info.cells()), info.top_level_cells());
  std::printf(
      "bounds (%g, %g, %g) - (%g, %g, %g), up (%g, %g, %g)\n",
      static_cast<double>(info.bounds_min().x()), static_cast<double>(info.bounds_min().y()),
      static_cast<double>(info.bounds_min().z()), static_cast<double>(info.bounds_max().x()),
      static_cast<double>(info.bounds_max().y()), static_cast<double>(info.bounds_max().z()),
      static_cast<double>(info.default_up().x()), static_cast<double>(info.default_up().y()),
      static_cast<double>(info.default_up().z()));
  std::string modes, paths;
  for (const auto& mode : info.modes_available()) modes += (modes.empty() ? "" : ", ") + mode;
  for (const auto& path : info.camera_paths()) paths += (paths.empty() ? "" : ", ") + path;
  std::printf("job %s: mode %s (available: %s), lod %g px, scheduler %s; paths: %s\n",
              info.layout().c_str(), info.mode().c_str(), modes.c_str(),
              static_cast<double>(info.lod_pixels()), info.scheduler().c_str(), paths.c_str());
  if (info.interim_ms() >= 0.0) {
    std::printf("render cache: interim frames for render requests after %g ms\n",
                info.interim_ms());
  } else {
    std::printf("render cache: off\n");
  }
  const v1::FrameFormat& format = client.helloReply().format();
  std::printf("frames: %ux%u %s by default\n", format.width(), format.height(),
              encodingName(format.encoding()));
  return 0;
}

int renderOne(ServiceClient& client, const ClientOptions& options) {
  const auto sent = SteadyClock::now();
  const std::uint64_t id = client.render(parseCamera(options.camera), requestedFormat(options));
  std::vector<ReceivedFrame> interim;
  const ReceivedFrame frame = awaitFrame(client, id, options, &interim);
  Image shown;
  for (const ReceivedFrame& early : interim) {
    const v1::FrameHeader& header = early.header;
    if (header.region_width() == 0) {
      std::printf(
          "interim frame after %.1f ms: reprojected in %.1f ms, %.1f %% of pixels filled, %u "
          "tiles final\n",
          millisecondsBetween(sent, early.received), header.reproject_ms(),
          static_cast<double>(header.cache_filled()) * 100.0, header.tiles_composed());
    } else {
      std::printf("  then after %.1f ms: the tiles that came, %ux%u at %u,%u (%u of %u final)\n",
                  millisecondsBetween(sent, early.received), header.region_width(),
                  header.region_height(), header.region_x(), header.region_y(),
                  header.tiles_composed(), header.tiles());
    }
    showInterim(early, shown);
  }
  if (!interim.empty() && options.keepInterim && !options.output.empty()) {
    // The first interim frame as the cache made it (the tiles after are the final frame's).
    std::filesystem::path path(options.output);
    path.replace_extension(".interim" + path.extension().string());
    writeFrame(interim.front(), path);
    std::printf("wrote %s\n", path.c_str());
  }
  printFrame(frame, millisecondsBetween(sent, frame.received));
  if (frame.header.status() == v1::FRAME_STATUS_SUPERSEDED) return 1;
  if (!options.output.empty()) {
    writeFrame(frame, options.output);
    std::printf("wrote %s\n", options.output.c_str());
  }
  return frame.header.status() == v1::FRAME_STATUS_OK ? 0 : 1;
}

// Frames of this client the service dropped (its stream was full or gone).
std::uint64_t framesDropped(ServiceClient& client) {
  const v1::Statistics stats = client.stats();
  for (const auto& entry : stats.clients()) {
    if (entry.client_id() == client.clientId()) return entry.frames_dropped();
  }
  return 0;
}

// The next frame of a path request, or nothing once every frame not yet
// received is known dropped: a reader the job outran does not wait for them.
std::optional<ReceivedFrame> awaitPathFrame(ServiceClient& client, std::uint64_t requestId,
                                            std::uint32_t received, std::uint32_t total,
                                            const ClientOptions& options) {
  const auto deadline =
      SteadyClock::now() +
      std::chrono::milliseconds(static_cast<long>(options.frameTimeoutSeconds * 1e3));
  while (SteadyClock::now() < deadline) {
    auto frame = client.receiveFrame(std::chrono::milliseconds(1000));
    if (frame && frame->header.request_id() == requestId) return frame;
    if (!frame && received + framesDropped(client) >= total) return std::nullopt;
  }
  throw TimeoutError("no frame for request " + std::to_string(requestId));
}

int renderPath(ServiceClient& client, const ClientOptions& options) {
  v1::PathRequest path;
  path.set_builtin(options.cameraPath);
  path.set_frames(options.frames);
  *path.mutable_format() = requestedFormat(options);
  const auto sent = SteadyClock::now();
  v1::RenderAccepted accepted;
  const std::uint64_t id = client.path(path, &accepted);
  if (options.neverRead) {
    // A test's misbehaving client: asks, then never reads its stream.
    std::this_thread::sleep_for(
        std::chrono::milliseconds(static_cast<long>(options.frameTimeoutSeconds * 1e3)));
    return 0;
  }
  LatencyWindow latency;
  std::uint32_t failed = 0;
  auto previous = sent;
  std::uint32_t received = 0;
  for (; received < accepted.frames(); ++received) {
    const auto next = awaitPathFrame(client, id, received, accepted.frames(), options);
    if (!next) break;
    const ReceivedFrame& frame = *next;
    latency.add(millisecondsBetween(previous, frame.received));
    previous = frame.received;
    printFrame(frame, millisecondsBetween(sent, frame.received));
    if (frame.header.status() != v1::FRAME_STATUS_OK) ++failed;
    if (!options.output.empty()) {
      char name[64];
      std::snprintf(name, sizeof name, "frame_%05u.png", frame.header.path_index());
      writeFrame(frame, std::filesystem::path(options.output) / name);
    }
    if (options.readDelayMs > 0.0) {
      std::this_thread::sleep_for(std::chrono::duration<double, std::milli>(options.readDelayMs));
    }
  }
  const double seconds = millisecondsBetween(sent, previous) / 1e3;
  printLatency("time between frames", latency);
  std::printf("path: %u frames in %.2f s, %.2f frames/s\n", received, seconds,
              seconds > 0.0 ? received / seconds : 0.0);
  if (received < accepted.frames()) {
    std::fprintf(stderr,
                 "pointillist-client: %u of %u frames were dropped: the job outran this client "
                 "and its stream was full (read faster, or start the job with a larger "
                 "--stream-hwm)\n",
                 accepted.frames() - received, accepted.frames());
    return 1;
  }
  return failed == 0 ? 0 : 1;
}

// One camera at a time along a built-in path, each sent when the last final
// frame came: the latency a user moving the view sees, and the frames/s it
// allows. With the display's render cache, the interim frame that comes
// first is what the user sees at once: its latency, its PSNR against the
// final frame and the share of pixels the cache filled are measured too.
int orbit(ServiceClient& client, const ClientOptions& options) {
  const v1::DatasetInfo info = client.info();
  const SceneBounds bounds{{info.bounds_min().x(), info.bounds_min().y(), info.bounds_min().z()},
                           {info.bounds_max().x(), info.bounds_max().y(), info.bounds_max().z()}};
  const glm::vec3 up{info.default_up().x(), info.default_up().y(), info.default_up().z()};
  const auto keys = builtinCameraPath(options.cameraPath, bounds, options.frames, up);
  std::unique_ptr<std::ofstream> csv;
  if (!options.csv.empty()) {
    const std::filesystem::path file(options.csv);
    if (file.has_parent_path()) std::filesystem::create_directories(file.parent_path());
    csv = std::make_unique<std::ofstream>(file);
    if (!*csv) throw Error("cannot write " + options.csv);
    *csv << "frame,final_ms,first_shown_ms,interim,interim_ms,reproject_ms,cache_filled,"
            "interim_psnr,interim_identical,covered_filled,interims,last_tiles_composed,"
            "last_interim_identical,interims_converge\n";
  }
  LatencyWindow latency, firstShown, interimPsnr, filled;
  std::size_t interims = 0, refreshes = 0;
  const auto start = SteadyClock::now();
  for (std::size_t index = 0; index < keys.size(); ++index) {
    const auto sent = SteadyClock::now();
    const std::uint64_t id = client.render(cameraKeyMessage(keys[index]), requestedFormat(options));
    std::vector<ReceivedFrame> early;
    const ReceivedFrame frame = awaitFrame(client, id, options, &early);
    const double ms = millisecondsBetween(sent, frame.received);
    latency.add(ms);
    const double shownMs = early.empty() ? ms : millisecondsBetween(sent, early.front().received);
    firstShown.add(shownMs);
    printFrame(frame, ms);
    if (!options.output.empty()) {
      char name[64];
      std::snprintf(name, sizeof name, "frame_%05zu.png", index);
      writeFrame(frame, std::filesystem::path(options.output) / name);
    }
    double psnr = 0.0, identical = 0.0, coveredFilled = 0.0, lastIdentical = 0.0;
    // Later interim frames (--interim-refresh-ms) carry more of the final
    // frame's tiles: more tiles each time, never fewer pixels as final.
    bool converge = true;
    if (!early.empty() && frame.header.status() == v1::FRAME_STATUS_OK) {
      ++interims;
      const ReceivedFrame& interim = early.front();
      const Image finalImage = decodeFrame(frame.pixels, frame.header.encoding(),
                                           frame.header.width(), frame.header.height());
      const Image interimImage = decodeFrame(interim.pixels, interim.header.encoding(),
                                             interim.header.width(), interim.header.height());
      const ImageQuality quality = measureQuality(interimImage, finalImage);
      psnr = std::min(quality.psnr, 99.0);
      identical = quality.identicalShare();
      // Of the pixels the final frame covers, the share the interim one had.
      std::uint64_t covered = 0, had = 0;
      const Rgba8 background{0, 0, 0, 255};
      for (std::uint32_t y = 0; y < finalImage.height(); ++y) {
        for (std::uint32_t x = 0; x < finalImage.width(); ++x) {
          if (finalImage.at(x, y) == background) continue;
          ++covered;
          had += interimImage.at(x, y) != background ? 1u : 0u;
        }
      }
      coveredFilled = covered > 0 ? static_cast<double>(had) / static_cast<double>(covered) : 1.0;
      interimPsnr.add(psnr);
      filled.add(coveredFilled * 100.0);
      lastIdentical = identical;
      Image shown = interimImage;
      for (std::size_t i = 1; i < early.size(); ++i) {
        const v1::FrameHeader& header = early[i].header;
        showInterim(early[i], shown);
        const double share = measureQuality(shown, finalImage).identicalShare();
        converge = converge && header.region_width() > 0 &&
                   header.tiles_composed() > early[i - 1].header.tiles_composed() &&
                   share >= lastIdentical;
        lastIdentical = share;
        ++refreshes;
      }
      std::printf(
          "  interim after %.1f ms: PSNR %.1f dB against the final frame, %.1f %% of "
          "its covered pixels filled\n",
          shownMs, psnr, coveredFilled * 100.0);
      if (early.size() > 1) {
        std::printf(
            "  %zu more with the tiles that came (the last with %u of %u tiles): %.1f %% of "
            "pixels as final, from %.1f %%\n",
            early.size() - 1, early.back().header.tiles_composed(), early.back().header.tiles(),
            lastIdentical * 100.0, identical * 100.0);
      }
    }
    if (csv) {
      *csv << index << ',' << ms << ',' << shownMs << ',' << (early.empty() ? 0 : 1) << ','
           << (early.empty() ? 0.0 : shownMs) << ','
           << (early.empty() ? 0.0 : early.front().header.reproject_ms()) << ','
           << (early.empty() ? 0.0 : static_cast<double>(early.front().header.cache_filled()))
           << ',' << psnr << ',' << identical << ',' << coveredFilled << ',' << early.size() << ','
           << (early.empty() ? 0u : early.back().header.tiles_composed()) << ',' << lastIdentical
           << ',' << (converge ? 1 : 0) << '\n';
    }
  }
  const double seconds = millisecondsBetween(start, SteadyClock::now()) / 1e3;
  printLatency("latency request to final frame", latency);
  printLatency("latency request to first frame shown", firstShown);
  if (interims > 0) {
    const LatencyFigures quality = interimPsnr.figures();
    const LatencyFigures share = filled.figures();
    std::printf(
        "interim frames: %zu of %zu, PSNR against the final frame median %.1f dB, "
        "covered pixels filled median %.1f %%\n",
        interims, keys.size(), quality.median, share.median);
    if (refreshes > 0) {
      std::printf("interim updates with the tiles that came: %zu\n", refreshes);
    }
  }
  std::printf("%s: %zu frames in %.2f s, %.2f frames/s\n", options.cameraPath.c_str(), keys.size(),
              seconds, seconds > 0.0 ? static_cast<double>(keys.size()) / seconds : 0.0);
  return 0;
}

int stats(ServiceClient& client) {
  const v1::Statistics stats = client.stats();
  std::printf(
      "uptime %.1f s, %llu requests (%llu errors), %llu frames rendered, %llu superseded, "
      "%llu dropped, %.1f MiB sent, %.2f M splats, %u queued\n",
      stats.uptime_seconds(), static_cast<unsigned long long>(stats.requests()),
      static_cast<unsigned long long>(stats.errors()),
      static_cast<unsigned long long>(stats.frames_rendered()),
      static_cast<unsigned long long>(stats.frames_superseded()),
      static_cast<unsigned long long>(stats.frames_dropped()),
      static_cast<double>(stats.bytes_sent()) / (1024.0 * 1024.0),
      static_cast<double>(stats.splats()) / 1e6, stats.queued());
  const auto line = [](const char* what, const v1::LatencySummary& summary) {
    std::printf("%s: %llu, median %.1f ms, p95 %.1f ms, max %.1f ms\n", what,
                static_cast<unsigned long long>(summary.count()), summary.median_ms(),
                summary.p95_ms(), summary.max_ms());
  };
  line("request to sent", stats.request_to_sent());
  line("render", stats.render());
  line("encode", stats.encode());
  if (stats.frames_interim() > 0) {
    std::printf("interim frames (render cache): %llu\n",
                static_cast<unsigned long long>(stats.frames_interim()));
    line("reproject", stats.reproject());
  }
  for (const auto& client_ : stats.clients()) {
    std::printf(
        "client %s (%s): %llu frames sent, %llu dropped, %llu superseded, %.1f MiB, %u queued\n",
        client_.client_id().c_str(), client_.client_name().c_str(),
        static_cast<unsigned long long>(client_.frames_sent()),
        static_cast<unsigned long long>(client_.frames_dropped()),
        static_cast<unsigned long long>(client_.frames_superseded()),
        static_cast<double>(client_.bytes_sent()) / (1024.0 * 1024.0), client_.queued());
  }
  return 0;
}

int run(int argc, char** argv) {
  CLI::App app{"Pointillist service client (for a job started with deploy/run.sh --serve)"};
  app.name("pointillist-client");
  ClientOptions options;
  app.add_option("--connect", options.connect, "Control endpoint of the service")
      ->capture_default_str();
  app.add_option("--name", options.name, "Name the service shows for this client");
  app.add_option("--timeout", options.timeoutSeconds, "Seconds to wait for a reply");
  app.add_option("--frame-timeout", options.frameTimeoutSeconds, "Seconds to wait for a frame");
  app.add_option("--encoding", options.encoding, "Frames as raw, png or jpeg");
  app.add_option("--size", options.size, "Frame size WxH");
  app.add_option("--jpeg-quality", options.jpegQuality, "1-100")->check(CLI::Range(1, 100));
  app.add_option("--mode", options.mode,
                 "This client's frames: points, splats, blended, instanced (a dataset built with "
                 "--instanced) or statistical (built with --statistical)");
  app.add_option("--lod-pixels", options.lodPixels,
                 "This client's frames: target splat size on screen in pixels")
      ->check(CLI::PositiveNumber);
  app.add_option("--scheduler", options.scheduler,
                 "Every client's frames from the next one: cost, regions, round-robin, static, "
                 "equalizer");
  app.add_option("--curve-server-key", options.curveServerKey,
                 "CURVE: file with the server's public key");
  app.add_option("--curve-key", options.curveKey, "CURVE: file with this client's secret key");
  app.require_subcommand(1);
  app.fallthrough();  // global options may follow the subcommand
  app.add_subcommand("info", "Dataset and job");
  auto* render = app.add_subcommand("render", "Render one frame");
  render->add_option("--camera", options.camera, "ex,ey,ez,tx,ty,tz[,ux,uy,uz[,fovY]]")->required();
  render->add_option("-o,--output", options.output, "File (.png, .jpg or .rgba)");
  render->add_flag("--keep-interim", options.keepInterim,
                   "Also write the render cache's interim frame (OUTPUT.interim.png)");
  auto* path = app.add_subcommand("path", "Render a built-in camera path");
  path->add_option("--camera-path", options.cameraPath, "orbit, flythrough, closeup or turns")
      ->capture_default_str();
  path->add_option("--frames", options.frames, "Frames of the path")->capture_default_str();
  path->add_option("-o,--output", options.output, "Directory for frame_NNNNN.png");
  path->add_option("--read-delay-ms", options.readDelayMs,
                   "Sleep after each frame (a slow reader)");
  path->add_flag("--never-read", options.neverRead, "Ask, then never read (for tests)")->group("");
  auto* orbitCommand = app.add_subcommand(
      "orbit", "One camera at a time along a path, each sent when the last frame came");
  orbitCommand->add_option("--frames", options.frames, "Frames of the path")->capture_default_str();
  orbitCommand->add_option("--camera-path", options.cameraPath, "A built-in path")
      ->capture_default_str();
  orbitCommand->add_option("-o,--output", options.output,
                           "Directory for the final frames, frame_NNNNN.png");
  orbitCommand->add_option("--csv", options.csv,
                           "Per-frame latency and interim-frame figures as CSV");
  app.add_subcommand("stats", "The service's statistics");
  auto* keygen =
      app.add_subcommand("keygen", "Write a CURVE key pair: PREFIX.secret, PREFIX.public");
  keygen->add_option("prefix", options.keygenPrefix, "Path without extension")->required();
  auto* shutdown = app.add_subcommand("shutdown", "Stop the job");
  shutdown->add_option("--reason", options.reason, "Said in the job's log");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& error) {
    return app.exit(error);
  }
  const std::string command = app.get_subcommands().front()->get_name();
  if (command == "keygen") {
    const CurveKeyPair pair = writeCurveKeyPair(options.keygenPrefix);
    std::printf("wrote %s.secret and %s.public (public key %s)\n", options.keygenPrefix.c_str(),
                options.keygenPrefix.c_str(), pair.publicKey.c_str());
    return 0;
  }
  if (options.curveServerKey.empty() != options.curveKey.empty()) {
    throw UsageError("CURVE needs both --curve-server-key and --curve-key");
  }
  std::optional<CurveClientKeys> curve;
  if (!options.curveKey.empty()) {
    curve = CurveClientKeys{readCurveKey(options.curveServerKey), readCurveKey(options.curveKey)};
  }
  const auto connectStart = SteadyClock::now();
  ServiceClient client(options.connect, options.name,
                       std::chrono::milliseconds(static_cast<long>(options.timeoutSeconds * 1e3)),
                       curve ? &*curve : nullptr);
  std::fprintf(stderr, "connected to %s as %s in %.1f ms\n", options.connect.c_str(),
               client.clientId().c_str(), millisecondsBetween(connectStart, SteadyClock::now()));
  if (!options.mode.empty() || options.lodPixels > 0.0f || !options.scheduler.empty()) {
    v1::SetOptionsRequest request;
    request.set_mode(options.mode);
    request.set_lod_pixels(options.lodPixels);
    request.set_scheduler(options.scheduler);
    const v1::OptionsReply reply = client.setOptions(request);
    std::fprintf(stderr, "frames drawn as %s, lod %g px, scheduler %s\n", reply.mode().c_str(),
                 static_cast<double>(reply.lod_pixels()), reply.scheduler().c_str());
  }
  if (command == "info") return info(client);
  if (command == "render") return renderOne(client, options);
  if (command == "path") return renderPath(client, options);
  if (command == "orbit") return orbit(client, options);
  if (command == "stats") return stats(client);
  client.shutdown(options.reason);
  std::printf("shutdown requested\n");
  return 0;
}

}  // namespace
}  // namespace pointillist::service

int main(int argc, char** argv) {
  return pointillist::runToolMain("pointillist-client",
                                  [&] { return pointillist::service::run(argc, argv); });
}
