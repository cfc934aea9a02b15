#pragma once
// The display's ZeroMQ front end (serve mode). An I/O thread owns the sockets:
// the control ROUTER (one Reply per Request) and the frames ROUTER (one
// DEALER per client, identified by the client_id hello gave it). An encoder
// thread turns composed frames into the encoding each client asked for. The
// display's main thread, which alone talks MPI, only takes frames to render
// (nextFrame) and hands composed ones back (frameDone).
//
// A client that never reads or has gone costs the others nothing: frames go
// out without blocking, a full stream (high-water mark) drops the frame and
// counts it, and a client whose stream is gone loses its queued frames.
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include <zmq.hpp>

#include "common/camera.hpp"
#include "common/camera_path.hpp"
#include "common/image.hpp"
#include "pointillist.pb.h"
#include "service/core/frame_queue.hpp"
#include "service/core/latency_window.hpp"
#include "service/core/request_validation.hpp"

namespace pointillist::service {

// Every message on the frames stream is [tag, protobuf, payload]: a Reply
// (to attach) with an empty payload, or a FrameHeader and the encoded pixels.
inline constexpr const char* kStreamReplyTag = "R";
inline constexpr const char* kStreamFrameTag = "F";

struct ServiceOptions {
  std::string listen = "tcp://127.0.0.1:5570";
  std::string streamListen;  // empty: derived from listen (streamEndpointFor)
  RequestLimits limits;
  // Messages over this are dropped unread by libzmq (ZMQ_MAXMSGSIZE), which
  // closes that connection; between limits.maxMessageBytes and this they get
  // ERROR_TOO_LARGE.
  std::int64_t hardMessageCap = 1 << 20;
  FrameQueueLimits queueLimits;
  std::size_t maxClients = 64;
  int streamHighWaterMark = 16;  // frames queued for one client before frames are dropped
  std::size_t maxEncodeBacklog = 4;
  v1::FrameFormat defaultFormat;  // complete
  // CURVE (both set or neither): the server's secret key file, and the file of
  // client public keys admitted (a ZAP handler refuses any other).
  std::string curveSecretKeyFile;
  std::string curveAuthorizedKeysFile;
};

// What the job serves, fixed at start-up.
struct ServedDataset {
  v1::DatasetInfo info;
  pointillist::v1::RunSettings run;  // what clients' frame settings override
  SceneBounds bounds;
  glm::vec3 up{0.0f, 0.0f, 1.0f};
};

// A frame the display renders now.
struct FrameOrder {
  QueuedFrame request;
  Camera camera;
  // The client's mode and level of detail, and the scheduler in force.
  pointillist::v1::FrameSettings settings;
  std::chrono::steady_clock::time_point admitted;
};

// What the display measured for a composed frame.
struct FrameOutcome {
  std::uint64_t frameId = 0;
  std::uint64_t splats = 0;
  std::uint32_t tiles = 0;
  std::uint64_t bytesOrdered = 0;
  bool incomplete = false;  // some tiles never came back
};

// What the render cache made of an interim frame.
struct InterimOutcome {
  std::uint64_t frameId = 0;  // the job's frame it stands in for
  double filledShare = 0.0;   // pixels the cache coloured
  double reprojectMs = 0.0;
  // Tiles of the final frame already pasted in (they replace the cache's
  // pixels region by region), and its tiles in all.
  std::uint32_t tilesComposed = 0, tiles = 0;
  // When regionWidth > 0, the image is only the rectangle at (regionX,
  // regionY) (from the bottom-left, as Image) of a frameWidth x frameHeight
  // frame.
  std::uint32_t regionX = 0, regionY = 0, regionWidth = 0, regionHeight = 0;
  std::uint32_t frameWidth = 0, frameHeight = 0;
};

// The frames endpoint beside a control endpoint: tcp port + 1 (an ephemeral
// port stays ephemeral), ipc and inproc names with ".frames" appended.
std::string streamEndpointFor(const std::string& control);
// True for tcp on 127.0.0.0/8, ::1 or localhost, and for ipc and inproc.
bool isLocalEndpoint(const std::string& endpoint);

class ServiceFrontEnd {
 public:
  // Binds both sockets (a TransportError names an endpoint that cannot be
  // bound) and starts the threads.
  ServiceFrontEnd(ServiceOptions options, ServedDataset dataset);
  ~ServiceFrontEnd();
  ServiceFrontEnd(const ServiceFrontEnd&) = delete;
  ServiceFrontEnd& operator=(const ServiceFrontEnd&) = delete;

  const std::string& controlEndpoint() const { return controlEndpoint_; }
  const std::string& streamEndpoint() const { return streamEndpoint_; }
  bool curve() const { return !authorizedKeys_.empty(); }

  // Main thread: the next frame to render, or nothing (none queued, or the
  // encoder is behind by maxEncodeBacklog frames).
  std::optional<FrameOrder> nextFrame();
  // Main thread: a composed frame; encoded and sent on the encoder thread.
  void frameDone(FrameOrder order, const FrameOutcome& outcome, Image image);
  // Main thread: an interim frame of an order not yet done (the display's
  // render cache); encoded and sent ahead of the final frame.
  void interimFrame(const FrameOrder& order, const InterimOutcome& outcome, Image image);

  bool shutdownRequested() const { return shutdown_.load(); }
  void requestShutdown(const std::string& reason);
  std::string shutdownReason() const;
  // Encodes and sends what is pending, then stops both threads.
  void close();

 private:
  struct ClientState {
    std::string name;
    v1::FrameFormat format;
    pointillist::v1::FrameSettings settings;  // set_options: mode, level of detail
    bool attached = false;
    std::chrono::steady_clock::time_point lastSeen;
    v1::ClientStatistics stats;
  };
  struct EncodeJob {
    FrameOrder order;
    FrameOutcome outcome;
    Image image;
    std::optional<InterimOutcome> interim;
  };
  struct Outgoing {
    std::string clientId;
    std::chrono::steady_clock::time_point requested;
    bool single = true;  // a render request's (not a path's)
    v1::FrameHeader header;
    std::vector<std::uint8_t> pixels;
  };

  void ioLoop();
  void encodeLoop();
  void handleControl();
  void handleStream();
  void handleZap();
  void sendOutgoing();
  // Answers one control request; runs under mutex_.
  v1::Reply answer(const v1::Request& request);
  v1::Reply hello(const v1::Request& request);
  v1::Reply queueRender(const v1::Request& request, ClientState& client);
  v1::Reply queuePath(const v1::Request& request, ClientState& client);
  v1::Reply setOptions(const v1::Request& request, ClientState& client);
  v1::Reply statistics(const v1::Request& request);
  QueuedFrame queuedFrame(const v1::Request& request, const ClientState& client,
                          const v1::FrameFormat& requested) const;
  void noteSuperseded(const std::vector<QueuedFrame>& frames);
  void send(Outgoing outgoing);
  // full: the client's stream is (EAGAIN); gone: the client is
  // (EHOSTUNREACH); failed: another error, the message is lost.
  enum class Delivery { sent, full, gone, failed };
  Delivery transmit(const Outgoing& out);
  void noteDelivery(const Outgoing& out, Delivery delivery);
  void wake(zmq::socket_t& pusher);

  ServiceOptions options_;
  ServedDataset dataset_;
  std::chrono::steady_clock::time_point started_;
  zmq::context_t context_;
  zmq::socket_t control_;
  zmq::socket_t stream_;
  zmq::socket_t wakeReceiver_;
  zmq::socket_t encoderWaker_;            // encoder thread's
  zmq::socket_t zap_;                     // CURVE client authentication (ZAP, RFC 27)
  std::set<std::string> authorizedKeys_;  // 32-byte binary client public keys
  std::string controlEndpoint_;
  std::string streamEndpoint_;
  std::string wakeEndpoint_;

  mutable std::mutex mutex_;  // guards everything below
  FrameQueue queue_;
  std::map<std::string, ClientState> clients_;
  std::deque<EncodeJob> encodeQueue_;
  std::deque<Outgoing> outgoing_;
  // IO thread only: render requests' final frames and superseded notices
  // that found their client's stream full, sent first when it has room (the
  // client waits for them; interim and path frames are dropped instead).
  std::map<std::string, std::deque<Outgoing>> deferred_;
  static constexpr std::size_t kDeferredPerClient = 16;
  std::size_t encoding_ = 0;  // frames the encoder holds
  std::condition_variable encodeReady_;
  std::string shutdownReason_;
  pointillist::v1::Scheduler scheduler_;  // every client's frames' (set_options)
  std::uint64_t requests_ = 0, errors_ = 0, framesRendered_ = 0, framesSuperseded_ = 0,
                framesDropped_ = 0, bytesSent_ = 0, splats_ = 0, framesInterim_ = 0;
  LatencyWindow requestToSent_, renderLatency_, encodeLatency_, reprojectLatency_;

  std::atomic<bool> shutdown_{false};
  std::atomic<bool> stopping_{false};
  std::atomic<bool> encoderDone_{false};
  std::thread ioThread_;
  std::thread encoderThread_;
};

}  // namespace pointillist::service
