#include "service/web/relay.hpp"

#include <sys/eventfd.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <map>

#include "common/clock.hpp"

namespace pointillist::service::web {
namespace {

using SteadyClock = std::chrono::steady_clock;

// Frames queued for a browser's socket beyond this are dropped (a browser that
// does not read must not grow our memory).
constexpr int kMaxFramesInFlight = 2;
// Render requests awaiting their frame: the page keeps two; a client sending
// faster waits here, its newest camera replacing older ones in the mailbox.
constexpr std::size_t kMaxOutstanding = 4;

struct Outstanding {
  std::uint64_t browserId;
  SteadyClock::time_point sent;
};

class Relay {
 public:
  Relay(const RelayOptions& options, const std::string& clientName, RelayMailbox& mailbox,
        const SendToBrowser& send)
      : options_(options),
        mailbox_(mailbox),
        send_(send),
        client_(options.connect, clientName, options.timeout,
                options.curve ? &*options.curve : nullptr) {}

  void run() {
    text(infoJson(client_.info(), client_.helloReply().format()));
    while (auto request = mailbox_.wait()) {
      issue(*request);
      // Frames outstanding: wait for one or for a newer camera, whichever
      // comes first (cleared before take, so no post is missed).
      while (!outstanding_.empty() && !mailbox_.stopped()) {
        mailbox_.clearWake();
        if (outstanding_.size() < kMaxOutstanding) {
          if (auto newer = mailbox_.take()) issue(*newer);
        }
        if (auto frame = client_.receiveFrame(untilFirstExpiry(), mailbox_.wakeFd())) {
          forward(*frame);
        } else {
          expireOld();
        }
      }
    }
  }

 private:
  void text(std::string json) {
    send_(OutgoingMessage{OutgoingMessage::Kind::kText, std::move(json), {}});
  }

  void issue(const BrowserCameraRequest& request) {
    if ((!request.mode.empty() && request.mode != mode_) ||
        (request.lodPixels > 0.0f && request.lodPixels != lodPixels_)) {
      v1::SetOptionsRequest change;
      change.set_mode(request.mode);
      change.set_lod_pixels(request.lodPixels);
      try {
        client_.setOptions(change);
      } catch (const ServiceError& error) {
        // Not this job's (a mode its renderer cannot draw): no frame for it.
        text(errorJson(std::string("service: ") + error.what(),
                       static_cast<std::int64_t>(request.id)));
        return;
      }
      if (!request.mode.empty()) mode_ = request.mode;
      if (request.lodPixels > 0.0f) lodPixels_ = request.lodPixels;
    }
    v1::FrameFormat format = options_.format;
    format.set_width(request.width);
    format.set_height(request.height);
    const auto sent = SteadyClock::now();
    try {
      const std::uint64_t id = client_.render(request.camera, format);
      outstanding_[id] = Outstanding{request.id, sent};
    } catch (const ServiceError& error) {
      // Refused (a size over the job's limit, say): the browser hears why.
      text(errorJson(std::string("service: ") + error.what(),
                     static_cast<std::int64_t>(request.id)));
    }
  }

  void forward(const ReceivedFrame& frame) {
    const auto found = outstanding_.find(frame.header.request_id());
    if (found == outstanding_.end()) return;  // not ours (an expired request)
    const Outstanding request = found->second;
    // An interim frame (render cache) is shown at once; the final one answers.
    if (!frame.header.interim()) outstanding_.erase(found);
    const double latencyMs = millisecondsBetween(request.sent, frame.received);
    const v1::FrameStatus status = frame.header.status();
    const bool hasPixels =
        (status == v1::FRAME_STATUS_OK || status == v1::FRAME_STATUS_INCOMPLETE) &&
        !frame.pixels.empty();
    if (hasPixels && mailbox_.framesInFlight.load() >= kMaxFramesInFlight) {
      text(frameJson(frame.header, request.browserId, latencyMs, "dropped"));
      return;
    }
    if (!hasPixels) {
      text(frameJson(frame.header, request.browserId, latencyMs, "superseded"));
      return;
    }
    ++mailbox_.framesInFlight;
    send_(OutgoingMessage{
        OutgoingMessage::Kind::kFrame, std::string(frame.pixels.begin(), frame.pixels.end()),
        frameJson(frame.header, request.browserId, latencyMs, frameStatusName(status))});
  }

  std::chrono::milliseconds untilFirstExpiry() const {
    auto first = SteadyClock::time_point::max();
    for (const auto& [id, request] : outstanding_) first = std::min(first, request.sent);
    if (first == SteadyClock::time_point::max()) return std::chrono::milliseconds(0);
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
        first + options_.frameTimeout - SteadyClock::now());
    return std::max(left, std::chrono::milliseconds(0)) + std::chrono::milliseconds(1);
  }

  void expireOld() {
    const auto now = SteadyClock::now();
    for (auto it = outstanding_.begin(); it != outstanding_.end();) {
      if (now - it->second.sent > options_.frameTimeout) {
        text(errorJson("no frame from the service within " +
                           std::to_string(options_.frameTimeout.count()) + " ms",
                       static_cast<std::int64_t>(it->second.browserId)));
        it = outstanding_.erase(it);
      } else {
        ++it;
      }
    }
  }

  const RelayOptions& options_;
  RelayMailbox& mailbox_;
  const SendToBrowser& send_;
  ServiceClient client_;
  std::map<std::uint64_t, Outstanding> outstanding_;
  std::string mode_;  // options set on the service for this browser so far
  float lodPixels_ = 0.0f;
};

// The browser hears why and is closed; the operator reads it in the log.
void fail(const std::string& clientName, const std::string& message, const SendToBrowser& send) {
  std::fprintf(stderr, "pointillist-web: %s: %s\n", clientName.c_str(), message.c_str());
  send(OutgoingMessage{OutgoingMessage::Kind::kText, errorJson(message), {}});
  send(OutgoingMessage{OutgoingMessage::Kind::kClose, {}, {}});
}

}  // namespace

RelayMailbox::RelayMailbox() : wakeFd_(eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC)) {
  if (wakeFd_ < 0) throw Error(std::string("cannot make an eventfd: ") + std::strerror(errno));
}

RelayMailbox::~RelayMailbox() {
  close(wakeFd_);
}

void RelayMailbox::post(BrowserCameraRequest request) {
  {
    const std::lock_guard lock(mutex_);
    pending_ = std::move(request);
  }
  changed_.notify_one();
  const std::uint64_t one = 1;
  [[maybe_unused]] const auto written = write(wakeFd_, &one, sizeof one);
}

void RelayMailbox::stop() {
  {
    const std::lock_guard lock(mutex_);
    stop_ = true;
  }
  changed_.notify_one();
  const std::uint64_t one = 1;
  [[maybe_unused]] const auto written = write(wakeFd_, &one, sizeof one);
}

void RelayMailbox::clearWake() {
  std::uint64_t count = 0;
  [[maybe_unused]] const auto drained = read(wakeFd_, &count, sizeof count);
}

bool RelayMailbox::stopped() const {
  const std::lock_guard lock(mutex_);
  return stop_;
}

std::optional<BrowserCameraRequest> RelayMailbox::wait() {
  std::unique_lock lock(mutex_);
  changed_.wait(lock, [&] { return stop_ || pending_; });
  if (stop_) return std::nullopt;
  return std::exchange(pending_, std::nullopt);
}

std::optional<BrowserCameraRequest> RelayMailbox::take() {
  const std::lock_guard lock(mutex_);
  return std::exchange(pending_, std::nullopt);
}

void runRelay(const RelayOptions& options, const std::string& clientName, RelayMailbox& mailbox,
              const SendToBrowser& send) {
  try {
    Relay relay(options, clientName, mailbox, send);
    relay.run();
  } catch (const Error& error) {
    fail(clientName,
         std::string("service unreachable or failed: ") + error.kind() + ": " + error.what(), send);
  } catch (const std::exception& error) {
    fail(clientName, std::string("relay failed: ") + error.what(), send);
  }
}

}  // namespace pointillist::service::web
