#pragma once
// The service side of one browser: a thread that owns a ServiceClient, turns
// the browser's newest camera into a render request and hands frames back.
//
// One browser = one ServiceClient (its own client id on the service). The
// service then keeps each browser's queue apart: a newer camera supersedes
// only that browser's queued frames, one slow browser's stream fills up and
// drops only its own frames, and a browser that leaves takes its client with
// it. A single shared client would need its own per-browser queues and
// supersession here, repeating what the service already does per client.
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <functional>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "service/web/browser_protocol.hpp"
#include "service/zmq/service_client.hpp"

namespace pointillist::service::web {

struct RelayOptions {
  std::string connect = "tcp://127.0.0.1:5570";
  std::optional<CurveClientKeys> curve;
  std::chrono::milliseconds timeout{10000};       // replies of the service
  std::chrono::milliseconds frameTimeout{60000};  // a frame after its request
  v1::FrameFormat format;                         // encoding and quality for every frame
};

// For the browser: a JSON text; a frame (its JSON metadata, then the encoded
// image as a binary message, queued and dropped as one); or the order to close
// its WebSocket after the queued messages.
struct OutgoingMessage {
  enum class Kind { kText, kFrame, kClose };
  Kind kind = Kind::kText;
  std::string data;  // the text, or the frame's image
  std::string meta;  // a frame's metadata
  bool metaSent = false;
};

// Between a browser's WebSocket session (io thread) and its relay thread. The
// browser's newest camera replaces one not yet taken, so nothing piles up.
class RelayMailbox {
 public:
  RelayMailbox();  // Error when no eventfd can be made
  ~RelayMailbox();
  RelayMailbox(const RelayMailbox&) = delete;
  RelayMailbox& operator=(const RelayMailbox&) = delete;

  void post(BrowserCameraRequest request);
  void stop();
  bool stopped() const;
  // Blocks (no CPU) until a camera or stop; nothing on stop.
  std::optional<BrowserCameraRequest> wait();
  std::optional<BrowserCameraRequest> take();
  // Readable after a post or stop, until cleared: the relay waits for frames
  // and for this at once, so a newer camera goes out without polling.
  int wakeFd() const { return wakeFd_; }
  void clearWake();

  // Frames handed to the session and not yet written to the browser's socket.
  std::atomic<int> framesInFlight{0};

 private:
  mutable std::mutex mutex_;
  std::condition_variable changed_;
  std::optional<BrowserCameraRequest> pending_;
  bool stop_ = false;
  int wakeFd_ = -1;
};

using SendToBrowser = std::function<void(OutgoingMessage)>;

// Runs until the mailbox stops or the service fails (then the browser gets an
// error and a close). Never throws.
void runRelay(const RelayOptions& options, const std::string& clientName, RelayMailbox& mailbox,
              const SendToBrowser& send);

}  // namespace pointillist::service::web
