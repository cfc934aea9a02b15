#include "display/service_frame_source.hpp"

#include <algorithm>
#include <condition_variable>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <exception>
#include <mutex>
#include <thread>
#include <utility>

#include "common/clock.hpp"
#include "common/run_settings.hpp"

namespace pointillist::display {
namespace {

volatile std::sig_atomic_t stopSignal = 0;

extern "C" void onStopSignal(int signal) {
  stopSignal = signal;
}

}  // namespace

// Inserts final frames into the client caches on its own thread, in order.
// When a client's next frame comes before its last one went in, the newer
// replaces it in the queue: the cache wants the latest view.
class ServiceFrameSource::Inserter {
 public:
  Inserter() : thread_([this] { run(); }) {}
  ~Inserter() {
    {
      const std::lock_guard lock(mutex_);
      stopping_ = true;
      jobs_.clear();  // shutting down: what is not in yet is not needed
    }
    wake_.notify_all();
    thread_.join();
  }
  Inserter(const Inserter&) = delete;
  Inserter& operator=(const Inserter&) = delete;

  void push(RenderCache* cache, const Camera& camera, Image image, std::vector<float> depth) {
    {
      const std::lock_guard lock(mutex_);
      rethrowLocked();
      const auto queued = std::find_if(jobs_.begin(), jobs_.end(),
                                       [cache](const Job& job) { return job.cache == cache; });
      Job job{cache, camera, std::move(image), std::move(depth)};
      if (queued != jobs_.end()) {
        *queued = std::move(job);
        ++replaced_;
      } else {
        jobs_.push_back(std::move(job));
      }
    }
    wake_.notify_one();
  }

  // Returns when no insert is queued or running (before a cache is cleared or
  // dropped); rethrows an insert's failure.
  void waitIdle() {
    std::unique_lock lock(mutex_);
    idle_.wait(lock, [this] { return jobs_.empty() && !busy_; });
    rethrowLocked();
  }

  // Returns when `cache` has no insert queued or running.
  void waitFor(const RenderCache* cache) {
    std::unique_lock lock(mutex_);
    idle_.wait(lock, [this, cache] {
      return running_ != cache && std::none_of(jobs_.begin(), jobs_.end(), [cache](const Job& job) {
               return job.cache == cache;
             });
    });
    rethrowLocked();
  }

  void rethrowFailure() {
    const std::lock_guard lock(mutex_);
    rethrowLocked();
  }

  struct Figures {
    std::uint64_t inserted = 0, replaced = 0;
    double seconds = 0.0;
  };
  Figures figures() const {
    const std::lock_guard lock(mutex_);
    return {inserted_, replaced_, seconds_};
  }

 private:
  struct Job {
    RenderCache* cache = nullptr;
    Camera camera;
    Image image;
    std::vector<float> depth;
  };

  void rethrowLocked() {
    if (failure_) std::rethrow_exception(std::exchange(failure_, nullptr));
  }

  void run() {
    std::unique_lock lock(mutex_);
    while (true) {
      wake_.wait(lock, [this] { return stopping_ || !jobs_.empty(); });
      if (stopping_) return;
      Job job = std::move(jobs_.front());
      jobs_.pop_front();
      busy_ = true;
      running_ = job.cache;
      lock.unlock();
      const auto start = std::chrono::steady_clock::now();
      std::exception_ptr failure;
      try {
        job.cache->insert(job.camera, job.image, job.depth);
      } catch (...) {
        failure = std::current_exception();
      }
      const double seconds = secondsBetween(start, std::chrono::steady_clock::now());
      lock.lock();
      busy_ = false;
      running_ = nullptr;
      if (failure) {
        failure_ = failure;
      } else {
        ++inserted_;
        seconds_ += seconds;
      }
      idle_.notify_all();
    }
  }

  mutable std::mutex mutex_;
  std::condition_variable wake_, idle_;
  std::deque<Job> jobs_;
  bool busy_ = false, stopping_ = false;
  const RenderCache* running_ = nullptr;
  std::exception_ptr failure_;
  std::uint64_t inserted_ = 0, replaced_ = 0;
  double seconds_ = 0.0;
  std::thread thread_;  // last: it starts once the members it uses exist
};

ServiceFrameSource::ServiceFrameSource(service::ServiceOptions options,
                                       service::ServedDataset dataset,
                                       RenderCacheServing renderCache)
    : run_(dataset.run), renderCache_(renderCache) {
  if (renderCache_.interimMs >= 0.0) inserter_ = std::make_unique<Inserter>();
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
      inserter_->waitIdle();  // no insert may still use the cache that goes
      const auto eldest = std::min_element(caches_.begin(), caches_.end(), [](auto& a, auto& b) {
        return a.second.used < b.second.used;
      });
      caches_.erase(eldest);
    }
    found = caches_.try_emplace(clientId, renderCache_.cache, mode).first;
  }
  ClientCache& entry = found->second;
  // Another mode draws other pixels: what was cached would be wrong.
  if (entry.mode != mode) {
    inserter_->waitIdle();
    entry.cache.clear();
    entry.mode = mode;
  }
  entry.used = std::chrono::steady_clock::now();
  return &entry;
}

ServiceFrameSource::ClientCache* ServiceFrameSource::cacheHolding(
    const service::FrameOrder& order) {
  const auto found = caches_.find(order.request.clientId);
  if (found == caches_.end() ||
      found->second.mode != frameRunSettings(run_, order.settings).mode()) {
    return nullptr;
  }
  return &found->second;
}

std::vector<FrameRequest> ServiceFrameSource::take(std::size_t room) {
  std::vector<FrameRequest> frames;
  while (frames.size() < room) {
    auto order = frontEnd_->nextFrame();
    if (!order) break;
    FrameRequest request{order->camera, order->settings, {}};
    Started started;
    started.order = std::move(*order);
    started.frame = nextFrame_++;
    const v1::RenderMode mode = frameRunSettings(run_, request.settings).mode();
    // Render requests (a person moving the view), in a mode with one visible
    // surface per pixel; path frames are a film, shown exactly as drawn.
    if (renderCache_.interimMs >= 0.0 && started.order.request.single &&
        mode != v1::RENDER_MODE_BLENDED) {
      request.settings.set_tile_depth(true);
      ClientCache* client = cacheFor(started.order.request.clientId, mode);
      // The client's first final frame may still be going in: a cache that
      // is about to hold it is worth the wait (later frames reproject from
      // what the cache holds, an insert running or not).
      if (client->cache.empty()) inserter_->waitFor(&client->cache);
      if (!client->cache.empty()) {
        started.due = std::chrono::steady_clock::now() +
                      std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                          std::chrono::duration<double, std::milli>(renderCache_.interimMs));
        if (renderCache_.tilePriority) {
          auto interim = reproject(*client, request.camera);
          request.tilePriority = [interim](const TileRect& rect) {
            return meanPriority(*interim, rect);
          };
          started.interim = std::move(interim);
        } else {
          started.reprojectPending = true;
        }
      }
    }
    frames.push_back(std::move(request));
    started_.push_back(std::move(started));
  }
  if (renderCache_.tilePriority) poll();  // a deadline of 0 sends at once
  return frames;
}

std::shared_ptr<const InterimFrame> ServiceFrameSource::reproject(ClientCache& client,
                                                                  const Camera& camera) {
  auto interim = std::make_shared<const InterimFrame>(client.cache.reproject(camera));
  ++interimsMade_;
  reprojectSeconds_ += interim->seconds;
  filledSum_ += interim->filledShare();
  return interim;
}

void ServiceFrameSource::reprojectIfPending(Started& started) {
  if (!started.reprojectPending) return;
  started.reprojectPending = false;
  // The client's cache may have gone (or changed mode) since take().
  if (ClientCache* client = cacheHolding(started.order); client != nullptr) {
    started.interim = reproject(*client, started.order.camera);
  }
}

void ServiceFrameSource::tileComposed(const ComposedTile& tile, const Image& composed) {
  const auto found = std::find_if(started_.begin(), started_.end(), [&](const Started& started) {
    return started.frame == tile.frame;
  });
  if (found == started_.end()) return;
  Started& started = *found;
  // Once the interim frame went, tiles matter only to refreshes.
  if (started.interimSent && renderCache_.refreshMs < 0.0) return;
  reprojectIfPending(started);
  if (!started.interim) return;
  if (started.shown.empty()) started.shown = started.interim->image;
  const TileRect& rect = tile.rect;
  if (started.shown.width() != composed.width() || started.shown.height() != composed.height() ||
      rect.x() + rect.width() > composed.width() || rect.y() + rect.height() > composed.height()) {
    throw ProtocolError("display: tile " + std::to_string(rect.width()) + "x" +
                        std::to_string(rect.height()) + " at " + std::to_string(rect.x()) + "," +
                        std::to_string(rect.y()) + " does not fit frame " +
                        std::to_string(tile.frame) + "'s interim image");
  }
  // The exact pixels replace the reprojected ones, region by region.
  for (std::uint32_t y = rect.y(); y < rect.y() + rect.height(); ++y) {
    std::memcpy(started.shown.pixel(rect.x(), y), composed.pixel(rect.x(), y),
                std::size_t{rect.width()} * 4);
  }
  started.tilesShown = tile.tilesDone;
  started.tiles = tile.tiles;
  if (started.changedX1 <= started.changedX0) {
    started.changedX0 = rect.x(), started.changedY0 = rect.y();
    started.changedX1 = rect.x() + rect.width(), started.changedY1 = rect.y() + rect.height();
  } else {
    started.changedX0 = std::min(started.changedX0, rect.x());
    started.changedY0 = std::min(started.changedY0, rect.y());
    started.changedX1 = std::max(started.changedX1, rect.x() + rect.width());
    started.changedY1 = std::max(started.changedY1, rect.y() + rect.height());
  }
}

void ServiceFrameSource::sendInterim(Started& started, std::chrono::steady_clock::time_point now) {
  service::InterimOutcome outcome;
  outcome.frameId = started.frame;
  outcome.filledShare = started.interim->filledShare();
  outcome.reprojectMs = started.interim->seconds * 1000.0;
  outcome.tilesComposed = started.tilesShown;
  outcome.tiles = started.tiles;
  Image image;
  if (!started.interimSent) {  // the whole frame, with the tiles that came
    image = started.shown.empty() ? started.interim->image : started.shown;
  } else {  // the tiles that came since: the client paints them over
    ++refreshesSent_;
    outcome.regionX = started.changedX0;
    outcome.regionY = started.changedY0;
    outcome.regionWidth = started.changedX1 - started.changedX0;
    outcome.regionHeight = started.changedY1 - started.changedY0;
    outcome.frameWidth = started.shown.width();
    outcome.frameHeight = started.shown.height();
    image = crop(started.shown, outcome.regionX, outcome.regionY, outcome.regionWidth,
                 outcome.regionHeight);
  }
  started.interimSent = true;
  started.lastSent = now;
  started.tilesSent = started.tilesShown;
  started.changedX0 = started.changedY0 = started.changedX1 = started.changedY1 = 0;
  ++interimsSent_;
  frontEnd_->interimFrame(started.order, outcome, std::move(image));
}

void ServiceFrameSource::poll() {
  if (inserter_) inserter_->rethrowFailure();
  for (Started& started : started_) reprojectIfPending(started);
  const auto now = std::chrono::steady_clock::now();
  const auto refresh = std::chrono::duration_cast<std::chrono::steady_clock::duration>(
      std::chrono::duration<double, std::milli>(renderCache_.refreshMs));
  for (Started& started : started_) {
    if (!started.interim || now < started.due) continue;
    if (!started.interimSent) {
      sendInterim(started, now);
      continue;
    }
    // Again with the tiles that came since; not once all came (the final
    // frame is on its way).
    if (renderCache_.refreshMs >= 0.0 && started.tilesShown > started.tilesSent &&
        started.tilesShown < started.tiles && now >= started.lastSent + refresh) {
      sendInterim(started, now);
    }
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
  if (!depth.empty() && frame.failedTiles.empty()) cache = cacheHolding(order);
  const Camera camera = order.camera;
  Image copy;
  if (cache != nullptr) copy = image;
  service::FrameOutcome outcome;
  outcome.frameId = frame.record.frame;
  outcome.splats = frame.record.splats;
  outcome.tiles = frame.record.tiles;
  outcome.bytesOrdered = frame.record.bytesOrdered;
  outcome.incomplete = !frame.failedTiles.empty();
  frontEnd_->frameDone(std::move(order), outcome, std::move(image));
  if (cache != nullptr) inserter_->push(&cache->cache, camera, std::move(copy), std::move(depth));
}

std::string ServiceFrameSource::renderCacheSummary() const {
  if (renderCache_.interimMs < 0.0) return "";
  const auto made = static_cast<double>(interimsMade_);
  const Inserter::Figures inserts = inserter_->figures();
  char line[400];
  std::snprintf(
      line, sizeof line,
      "render cache: %llu interim frames made (%.2f ms each, %.1f %% filled), %llu "
      "sent (%llu of them the tiles that came since); %llu final frames cached (%.2f ms each, "
      "on the cache thread), %llu "
      "passed over for a newer one\n",
      static_cast<unsigned long long>(interimsMade_),
      interimsMade_ > 0 ? reprojectSeconds_ * 1000.0 / made : 0.0,
      interimsMade_ > 0 ? filledSum_ * 100.0 / made : 0.0,
      static_cast<unsigned long long>(interimsSent_),
      static_cast<unsigned long long>(refreshesSent_),
      static_cast<unsigned long long>(inserts.inserted),
      inserts.inserted > 0 ? inserts.seconds * 1000.0 / static_cast<double>(inserts.inserted) : 0.0,
      static_cast<unsigned long long>(inserts.replaced));
  return line;
}

std::string ServiceFrameSource::stopReason() const {
  return frontEnd_->shutdownReason();
}

void ServiceFrameSource::close() {
  if (frontEnd_) frontEnd_->close();
}

}  // namespace pointillist::display
