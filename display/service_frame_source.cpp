#include "display/service_frame_source.hpp"

#include <algorithm>
#include <csignal>
#include <cstdio>
#include <optional>

#include "common/clock.hpp"
#include "common/run_settings.hpp"

namespace pointillist::display {
namespace {

volatile std::sig_atomic_t stopSignal = 0;

extern "C" void onStopSignal(int signal) {
  stopSignal = signal;
}

}  // namespace

ServiceFrameSource::ServiceFrameSource(service::ServiceOptions options,
                                       service::ServedDataset dataset,
                                       RenderCacheServing renderCache)
    : run_(dataset.run), renderCache_(renderCache) {
  dataset.info.set_interim_ms(renderCache_.interimMs);
  frontEnd_ = std::make_unique<service::ServiceFrontEnd>(std::move(options), std::move(dataset));
  // A clean stop: the frames out are finished and every process is shut down.
  struct sigaction action {};
  action.sa_handler = onStopSignal;
  sigemptyset(&action.sa_mask);
  sigaction(SIGINT, &action, nullptr);
  sigaction(SIGTERM, &action, nullptr);
}

ServiceFrameSource::~ServiceFrameSource() {
  close();
}

ServiceFrameSource::ClientCache* ServiceFrameSource::cacheFor(const std::string& clientId,
                                                              v1::RenderMode mode) {
  auto found = caches_.find(clientId);
  if (found == caches_.end()) {
    if (caches_.size() >= std::max<std::size_t>(1, renderCache_.maxClients)) {
      const auto eldest = std::min_element(caches_.begin(), caches_.end(), [](auto& a, auto& b) {
        return a.second.used < b.second.used;
      });
      caches_.erase(eldest);
    }
    found = caches_.emplace(clientId, ClientCache{RenderCache(renderCache_.cache), mode, {}}).first;
  }
  ClientCache& entry = found->second;
  // Another mode draws other pixels: what was cached would be wrong.
  if (entry.mode != mode) {
    entry.cache.clear();
    entry.mode = mode;
  }
  entry.used = std::chrono::steady_clock::now();
  return &entry;
}

std::vector<FrameRequest> ServiceFrameSource::take(std::size_t room) {
  std::vector<FrameRequest> frames;
  while (frames.size() < room) {
    auto order = frontEnd_->nextFrame();
    if (!order) break;
    FrameRequest request{order->camera, order->settings, {}};
    Started started{std::move(*order), nextFrame_++, nullptr, {}, false};
    const v1::RenderMode mode = frameRunSettings(run_, request.settings).mode();
    // Render requests (a person moving the view), in a mode with one visible
    // surface per pixel; path frames are a film, shown exactly as drawn.
    if (renderCache_.interimMs >= 0.0 && started.order.request.single &&
        mode != v1::RENDER_MODE_BLENDED) {
      request.settings.set_tile_depth(true);
      ClientCache* client = cacheFor(started.order.request.clientId, mode);
      if (!client->cache.empty()) {
        auto interim =
            std::make_shared<const InterimFrame>(client->cache.reproject(request.camera));
        ++interimsMade_;
        reprojectSeconds_ += interim->seconds;
        filledSum_ += interim->filledShare();
        request.tilePriority = [interim](const TileRect& rect) {
          return meanPriority(*interim, rect);
        };
        started.interim = std::move(interim);
        started.due = std::chrono::steady_clock::now() +
                      std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                          std::chrono::duration<double, std::milli>(renderCache_.interimMs));
      }
    }
    frames.push_back(std::move(request));
    started_.push_back(std::move(started));
  }
  poll();  // a deadline of 0 sends at once
  return frames;
}

void ServiceFrameSource::poll() {
  const auto now = std::chrono::steady_clock::now();
  for (Started& started : started_) {
    if (!started.interim || started.interimSent || now < started.due) continue;
    started.interimSent = true;
    ++interimsSent_;
    service::InterimOutcome outcome;
    outcome.frameId = started.frame;
    outcome.filledShare = started.interim->filledShare();
    outcome.reprojectMs = started.interim->seconds * 1000.0;
    frontEnd_->interimFrame(started.order, outcome, started.interim->image);
  }
}

bool ServiceFrameSource::finished() {
  if (stopSignal != 0 && !frontEnd_->shutdownRequested()) {
    frontEnd_->requestShutdown(stopSignal == SIGINT ? "SIGINT" : "SIGTERM");
  }
  return frontEnd_->shutdownRequested();
}

void ServiceFrameSource::frameDone(const FinishedFrame& frame, Image image,
                                   std::vector<float> depth) {
  if (started_.empty()) {
    throw ProtocolError("display: frame " + std::to_string(frame.record.frame) +
                        " finished, but no client asked for it");
  }
  Started started = std::move(started_.front());
  started_.pop_front();
  service::FrameOrder& order = started.order;
  // The client gets its frame first; the cache learns from a copy after.
  // A frame with tiles missing would teach the cache holes.
  ClientCache* cache = nullptr;
  if (!depth.empty() && frame.failedTiles.empty()) {
    const auto found = caches_.find(order.request.clientId);
    if (found != caches_.end() &&
        found->second.mode == frameRunSettings(run_, order.settings).mode()) {
      cache = &found->second;
    }
  }
  const Camera camera = order.camera;
  std::optional<Image> copy;
  if (cache != nullptr) copy = image;
  service::FrameOutcome outcome;
  outcome.frameId = frame.record.frame;
  outcome.splats = frame.record.splats;
  outcome.tiles = frame.record.tiles;
  outcome.bytesOrdered = frame.record.bytesOrdered;
  outcome.incomplete = !frame.failedTiles.empty();
  frontEnd_->frameDone(std::move(order), outcome, std::move(image));
  if (cache != nullptr) {
    const auto start = std::chrono::steady_clock::now();
    cache->cache.insert(camera, *copy, depth);
    insertSeconds_ += secondsBetween(start, std::chrono::steady_clock::now());
    ++framesCached_;
  }
}

std::string ServiceFrameSource::renderCacheSummary() const {
  if (renderCache_.interimMs < 0.0) return "";
  const auto made = static_cast<double>(interimsMade_);
  const auto cached = static_cast<double>(framesCached_);
  char line[256];
  std::snprintf(line, sizeof line,
                "render cache: %llu interim frames made (%.2f ms each, %.1f %% filled), %llu "
                "sent; %llu final frames cached (%.2f ms each)\n",
                static_cast<unsigned long long>(interimsMade_),
                interimsMade_ > 0 ? reprojectSeconds_ * 1000.0 / made : 0.0,
                interimsMade_ > 0 ? filledSum_ * 100.0 / made : 0.0,
                static_cast<unsigned long long>(interimsSent_),
                static_cast<unsigned long long>(framesCached_),
                framesCached_ > 0 ? insertSeconds_ * 1000.0 / cached : 0.0);
  return line;
}

std::string ServiceFrameSource::stopReason() const {
  return frontEnd_->shutdownReason();
}

void ServiceFrameSource::close() {
  if (frontEnd_) frontEnd_->close();
}

}  // namespace pointillist::display
