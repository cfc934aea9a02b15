#include "service/zmq/service_front_end.hpp"

#include <cstdio>
#include <random>
#include <regex>

#include "common/clock.hpp"
#include "common/errors.hpp"
#include "common/run_settings.hpp"
#include "common/view_options.hpp"
#include "service/core/frame_encoding.hpp"
#include "service/zmq/curve_keys.hpp"

namespace pointillist::service {
namespace {

using SteadyClock = std::chrono::steady_clock;

std::string randomClientId() {
  static thread_local std::mt19937_64 generator{std::random_device{}()};
  char text[17];
  std::snprintf(text, sizeof text, "%016llx", static_cast<unsigned long long>(generator()));
  return text;
}

void fillLatency(v1::LatencySummary* out, const LatencyWindow& window) {
  const LatencyFigures figures = window.figures();
  out->set_count(figures.count);
  out->set_median_ms(figures.median);
  out->set_p95_ms(figures.p95);
  out->set_max_ms(figures.max);
}

zmq::message_t serialized(const google::protobuf::MessageLite& message) {
  const std::string bytes = message.SerializeAsString();
  return zmq::message_t(bytes.data(), bytes.size());
}

std::string lastEndpoint(zmq::socket_t& socket) {
  return socket.get(zmq::sockopt::last_endpoint);
}

void bindOrThrow(zmq::socket_t& socket, const std::string& endpoint, const char* what) {
  try {
    socket.bind(endpoint);
  } catch (const zmq::error_t& error) {
    throw TransportError(std::string("cannot bind the service's ") + what + " socket to " +
                         endpoint + ": " + error.what());
  }
}

}  // namespace

std::string streamEndpointFor(const std::string& control) {
  static const std::regex tcp(R"(^tcp://(.+):([0-9]+|\*)$)");
  std::smatch match;
  if (std::regex_match(control, match, tcp)) {
    const std::string port = match[2];
    if (port == "*" || port == "0") return "tcp://" + match[1].str() + ":" + port;
    const unsigned long next = std::stoul(port) + 1;
    if (next > 65535) throw UsageError("--listen " + control + ": no port above it for frames");
    return "tcp://" + match[1].str() + ":" + std::to_string(next);
  }
  if (control.rfind("ipc://", 0) == 0 || control.rfind("inproc://", 0) == 0) {
    return control + ".frames";
  }
  throw UsageError("--listen '" + control +
                   "' is not tcp://HOST:PORT, ipc://PATH or inproc://NAME");
}

bool isLocalEndpoint(const std::string& endpoint) {
  if (endpoint.rfind("ipc://", 0) == 0 || endpoint.rfind("inproc://", 0) == 0) return true;
  static const std::regex loopback(R"(^tcp://(127\.[0-9.]+|localhost|\[::1\]|::1):.*$)");
  return std::regex_match(endpoint, loopback);
}

ServiceFrontEnd::ServiceFrontEnd(ServiceOptions options, ServedDataset dataset)
    : options_(std::move(options)),
      dataset_(std::move(dataset)),
      started_(SteadyClock::now()),
      context_(1),
      control_(context_, zmq::socket_type::router),
      stream_(context_, zmq::socket_type::router),
      wakeReceiver_(context_, zmq::socket_type::pull),
      encoderWaker_(context_, zmq::socket_type::push),
      zap_(context_, zmq::socket_type::rep),
      queue_(options_.queueLimits),
      scheduler_(dataset_.run.scheduler()) {
  const std::string streamListen =
      options_.streamListen.empty() ? streamEndpointFor(options_.listen) : options_.streamListen;
  for (zmq::socket_t* socket : {&control_, &stream_}) {
    socket->set(zmq::sockopt::maxmsgsize, options_.hardMessageCap);
    socket->set(zmq::sockopt::linger, 200);
    socket->set(zmq::sockopt::rcvhwm, 64);
  }
  control_.set(zmq::sockopt::sndhwm, 256);
  // Full or vanished clients are reported (EAGAIN, EHOSTUNREACH), never waited for.
  control_.set(zmq::sockopt::router_mandatory, true);
  stream_.set(zmq::sockopt::router_mandatory, true);
  stream_.set(zmq::sockopt::sndhwm, options_.streamHighWaterMark);
  // A reconnecting client with the same id takes over its stream.
  stream_.set(zmq::sockopt::router_handover, true);
  if (options_.curveSecretKeyFile.empty() != options_.curveAuthorizedKeysFile.empty()) {
    throw UsageError("CURVE needs both the server's secret key and the authorized client keys");
  }
  if (!options_.curveSecretKeyFile.empty()) {
    requireCurve();
    const std::string secret = readCurveKey(options_.curveSecretKeyFile);
    authorizedKeys_ = readAuthorizedKeys(options_.curveAuthorizedKeysFile);
    // The handler must be bound before any connection is accepted.
    zap_.set(zmq::sockopt::linger, 0);
    zap_.bind("inproc://zeromq.zap.01");
    for (zmq::socket_t* socket : {&control_, &stream_}) {
      socket->set(zmq::sockopt::curve_server, true);
      socket->set(zmq::sockopt::curve_secretkey, secret);
    }
  }
  bindOrThrow(control_, options_.listen, "control");
  bindOrThrow(stream_, streamListen, "frames");
  controlEndpoint_ = lastEndpoint(control_);
  streamEndpoint_ = lastEndpoint(stream_);
  wakeEndpoint_ = "inproc://pointillist-service-wake";
  wakeReceiver_.bind(wakeEndpoint_);
  encoderWaker_.connect(wakeEndpoint_);
  ioThread_ = std::thread([this] { ioLoop(); });
  encoderThread_ = std::thread([this] { encodeLoop(); });
}

ServiceFrontEnd::~ServiceFrontEnd() {
  try {
    close();
  } catch (...) {
    // Unwinding: the threads are joined by close() or terminate the process.
  }
}

void ServiceFrontEnd::requestShutdown(const std::string& reason) {
  std::lock_guard lock(mutex_);
  if (shutdownReason_.empty()) shutdownReason_ = reason;
  shutdown_ = true;
}

std::string ServiceFrontEnd::shutdownReason() const {
  std::lock_guard lock(mutex_);
  return shutdownReason_;
}

void ServiceFrontEnd::close() {
  if (!encoderThread_.joinable() && !ioThread_.joinable()) return;
  stopping_ = true;
  encodeReady_.notify_all();
  if (encoderThread_.joinable()) encoderThread_.join();
  if (ioThread_.joinable()) ioThread_.join();
  encoderWaker_.close();
  wakeReceiver_.close();
  control_.close();
  stream_.close();
  zap_.close();
}

std::optional<FrameOrder> ServiceFrontEnd::nextFrame() {
  std::lock_guard lock(mutex_);
  if (encodeQueue_.size() + encoding_ >= options_.maxEncodeBacklog) return std::nullopt;
  auto frame = queue_.pop();
  if (!frame) return std::nullopt;
  FrameOrder order;
  order.camera =
      cameraFromKey(frame->key, dataset_.bounds, frame->format.width(), frame->format.height());
  order.settings = frame->settings;
  order.settings.set_scheduler(scheduler_);
  order.request = std::move(*frame);
  order.admitted = SteadyClock::now();
  return order;
}

void ServiceFrontEnd::frameDone(FrameOrder order, const FrameOutcome& outcome, Image image) {
  {
    std::lock_guard lock(mutex_);
    ++framesRendered_;
    splats_ += outcome.splats;
    renderLatency_.add(millisecondsBetween(order.admitted, SteadyClock::now()));
    encodeQueue_.push_back({std::move(order), outcome, std::move(image), std::nullopt});
  }
  encodeReady_.notify_one();
}

void ServiceFrontEnd::interimFrame(const FrameOrder& order, const InterimOutcome& outcome,
                                   Image image) {
  {
    std::lock_guard lock(mutex_);
    reprojectLatency_.add(outcome.reprojectMs);
    FrameOutcome stand;
    stand.frameId = outcome.frameId;
    encodeQueue_.push_back({order, stand, std::move(image), outcome});
  }
  encodeReady_.notify_one();
}

void ServiceFrontEnd::encodeLoop() {
  while (true) {
    EncodeJob job;
    {
      std::unique_lock lock(mutex_);
      encodeReady_.wait(lock, [&] { return stopping_ || !encodeQueue_.empty(); });
      if (encodeQueue_.empty()) break;  // stopping, and nothing left to encode
      job = std::move(encodeQueue_.front());
      encodeQueue_.pop_front();
      ++encoding_;
    }
    const QueuedFrame& request = job.order.request;
    Outgoing out;
    out.clientId = request.clientId;
    out.requested = request.requested;
    out.single = request.single;
    v1::FrameHeader& header = out.header;
    header.set_request_id(request.requestId);
    header.set_frame_id(job.outcome.frameId);
    header.set_path_index(request.pathIndex);
    header.set_path_length(request.pathLength);
    header.set_status(job.outcome.incomplete ? v1::FRAME_STATUS_INCOMPLETE : v1::FRAME_STATUS_OK);
    *header.mutable_camera() = cameraKeyMessage(request.key);
    header.set_width(job.image.width());
    header.set_height(job.image.height());
    header.set_encoding(request.format.encoding());
    header.set_queued_ms(millisecondsBetween(request.requested, job.order.admitted));
    const auto encodeStart = SteadyClock::now();
    header.set_render_ms(millisecondsBetween(job.order.admitted, encodeStart));
    try {
      out.pixels = encodeFrame(job.image, request.format.encoding(), request.format.jpeg_quality());
    } catch (const Error& error) {
      std::fprintf(stderr, "display: service: frame %llu not encoded: %s\n",
                   static_cast<unsigned long long>(job.outcome.frameId), error.what());
      header.set_status(v1::FRAME_STATUS_INCOMPLETE);
    }
    const double encodeMs = millisecondsBetween(encodeStart, SteadyClock::now());
    header.set_encode_ms(encodeMs);
    header.set_splats(job.outcome.splats);
    header.set_tiles(job.outcome.tiles);
    header.set_bytes_ordered(job.outcome.bytesOrdered);
    header.set_encoded_bytes(out.pixels.size());
    const pointillist::v1::RunSettings drawn = frameRunSettings(dataset_.run, job.order.settings);
    header.set_mode(renderModeName(drawn.mode()));
    header.set_lod_pixels(drawn.lod_pixels());
    header.set_scheduler(pointillist::schedulerName(drawn.scheduler()));
    if (job.interim) {
      header.set_interim(true);
      header.set_cache_filled(static_cast<float>(job.interim->filledShare));
      header.set_reproject_ms(job.interim->reprojectMs);
      header.set_tiles_composed(job.interim->tilesComposed);
      header.set_tiles(job.interim->tiles);
      if (const InterimOutcome& region = *job.interim; region.regionWidth > 0) {
        header.set_width(region.frameWidth);
        header.set_height(region.frameHeight);
        header.set_region_x(region.regionX);
        header.set_region_y(region.frameHeight - region.regionY - region.regionHeight);
        header.set_region_width(region.regionWidth);
        header.set_region_height(region.regionHeight);
      }
      header.set_render_ms(0.0);
    }
    {
      std::lock_guard lock(mutex_);
      encodeLatency_.add(encodeMs);
      outgoing_.push_back(std::move(out));
      --encoding_;
    }
    wake(encoderWaker_);
  }
  encoderDone_ = true;
  wake(encoderWaker_);
}

void ServiceFrontEnd::wake(zmq::socket_t& pusher) {
  // One byte is enough; a full pipe already holds a wake-up.
  (void)pusher.send(zmq::const_buffer("w", 1), zmq::send_flags::dontwait);
}

void ServiceFrontEnd::ioLoop() {
  std::vector<zmq::pollitem_t> items{{control_.handle(), 0, ZMQ_POLLIN, 0},
                                     {stream_.handle(), 0, ZMQ_POLLIN, 0},
                                     {wakeReceiver_.handle(), 0, ZMQ_POLLIN, 0}};
  if (curve()) items.push_back({zap_.handle(), 0, ZMQ_POLLIN, 0});
  while (true) {
    // The timeout only bounds how late stopping is noticed, and how soon
    // frames that waited for room are tried again.
    zmq::poll(items, std::chrono::milliseconds(deferred_.empty() ? 100 : 2));
    if ((items[0].revents & ZMQ_POLLIN) != 0) {
      for (int i = 0; i < 64 && (control_.get(zmq::sockopt::events) & ZMQ_POLLIN) != 0; ++i) {
        handleControl();
      }
    }
    if ((items[1].revents & ZMQ_POLLIN) != 0) {
      for (int i = 0; i < 64 && (stream_.get(zmq::sockopt::events) & ZMQ_POLLIN) != 0; ++i) {
        handleStream();
      }
    }
    if ((items[2].revents & ZMQ_POLLIN) != 0) {
      zmq::message_t ignored;
      while (wakeReceiver_.recv(ignored, zmq::recv_flags::dontwait)) {
      }
    }
    if (curve() && (items[3].revents & ZMQ_POLLIN) != 0) handleZap();
    sendOutgoing();
    if (stopping_ && encoderDone_) {
      sendOutgoing();
      break;
    }
  }
}

void ServiceFrontEnd::handleControl() {
  std::vector<zmq::message_t> parts;
  while (true) {
    zmq::message_t part;
    if (!control_.recv(part, zmq::recv_flags::dontwait)) break;
    const bool more = part.more();
    // Bound the parts kept: the rest of an over-long message is read and dropped.
    if (parts.size() < 4) parts.push_back(std::move(part));
    if (!more) break;
  }
  if (parts.empty()) return;
  // REQ sends [id, "", body]; a DEALER may send [id, body] or [id, "", body].
  const bool delimited = parts.size() >= 3 && parts[1].size() == 0;
  const bool shapeOk = parts.size() == 2 || (parts.size() == 3 && delimited);
  v1::Reply reply;
  {
    std::lock_guard lock(mutex_);
    ++requests_;
    if (!shapeOk) {
      reply = errorReply(0, v1::ERROR_MALFORMED,
                         "a request is one message part (after REQ's empty delimiter), got " +
                             std::to_string(parts.size() - 1));
    } else {
      const zmq::message_t& body = parts.back();
      v1::Request request;
      try {
        request = parseRequest(std::span(static_cast<const std::byte*>(body.data()), body.size()),
                               options_.limits);
        reply = answer(request);
      } catch (const RequestError& error) {
        reply = errorReply(error.requestId() != 0 ? error.requestId() : request.request_id(),
                           error.code(), error.what());
      } catch (const Error& error) {
        reply = errorReply(request.request_id(), v1::ERROR_INVALID_ARGUMENT, error.what());
      }
    }
    if (reply.has_error()) ++errors_;
  }
  reply.set_version(v1::SERVICE_VERSION_CURRENT);
  // Echo the envelope (identity and, for REQ, the delimiter).
  try {
    control_.send(parts[0], zmq::send_flags::sndmore | zmq::send_flags::dontwait);
    if (delimited) control_.send(zmq::message_t(), zmq::send_flags::sndmore);
    control_.send(serialized(reply), zmq::send_flags::none);
  } catch (const zmq::error_t&) {
    // The client left before its reply; nothing to undo.
  }
}

void ServiceFrontEnd::handleStream() {
  std::vector<zmq::message_t> parts;
  while (true) {
    zmq::message_t part;
    if (!stream_.recv(part, zmq::recv_flags::dontwait)) break;
    const bool more = part.more();
    if (parts.size() < 4) parts.push_back(std::move(part));
    if (!more) break;
  }
  if (parts.size() < 2) return;
  const std::string peer = parts[0].to_string();
  v1::Reply reply;
  {
    std::lock_guard lock(mutex_);
    ++requests_;
    v1::Request request;
    try {
      if (parts.size() != 2) throw RequestError(v1::ERROR_MALFORMED, "attach is one message part");
      request =
          parseRequest(std::span(static_cast<const std::byte*>(parts[1].data()), parts[1].size()),
                       options_.limits, true);
      const auto client = clients_.find(request.client_id());
      if (client == clients_.end()) {
        throw RequestError(v1::ERROR_UNKNOWN_CLIENT, "attach from a client hello did not name");
      }
      if (peer != request.client_id()) {
        throw RequestError(v1::ERROR_UNKNOWN_CLIENT,
                           "the frames socket's routing id must be the client_id");
      }
      client->second.attached = true;
      client->second.lastSeen = SteadyClock::now();
      reply.set_request_id(request.request_id());
      reply.mutable_attached();
    } catch (const RequestError& error) {
      ++errors_;
      reply = errorReply(error.requestId() != 0 ? error.requestId() : request.request_id(),
                         error.code(), error.what());
    }
  }
  reply.set_version(v1::SERVICE_VERSION_CURRENT);
  try {
    stream_.send(parts[0], zmq::send_flags::sndmore | zmq::send_flags::dontwait);
    stream_.send(zmq::buffer(std::string_view(kStreamReplyTag)), zmq::send_flags::sndmore);
    stream_.send(serialized(reply), zmq::send_flags::sndmore);
    stream_.send(zmq::message_t(), zmq::send_flags::none);
  } catch (const zmq::error_t&) {
  }
}

// ZAP request: version, request id, domain, address, routing id, mechanism,
// credentials (for CURVE the client's 32-byte public key).
void ServiceFrontEnd::handleZap() {
  std::vector<zmq::message_t> parts;
  while (true) {
    zmq::message_t part;
    if (!zap_.recv(part, zmq::recv_flags::dontwait)) break;
    const bool more = part.more();
    parts.push_back(std::move(part));
    if (!more) break;
  }
  if (parts.size() < 6) return;
  const bool admitted = parts.size() == 7 && parts[5].to_string() == "CURVE" &&
                        authorizedKeys_.contains(parts[6].to_string());
  if (!admitted) {
    std::fprintf(stderr, "display: service: refused a connection from %s (%s key not authorized)\n",
                 parts[3].to_string().c_str(), parts[5].to_string().c_str());
  }
  zap_.send(zmq::str_buffer("1.0"), zmq::send_flags::sndmore);
  zap_.send(parts[1], zmq::send_flags::sndmore);
  zap_.send(zmq::buffer(std::string_view(admitted ? "200" : "400")), zmq::send_flags::sndmore);
  zap_.send(zmq::buffer(std::string_view(admitted ? "OK" : "client key not authorized")),
            zmq::send_flags::sndmore);
  zap_.send(zmq::str_buffer(""), zmq::send_flags::sndmore);
  zap_.send(zmq::str_buffer(""), zmq::send_flags::none);
}

void ServiceFrontEnd::sendOutgoing() {
  std::deque<Outgoing> batch;
  {
    std::lock_guard lock(mutex_);
    batch.swap(outgoing_);
  }
  // What waited for room first, each client's in order.
  for (auto waiting = deferred_.begin(); waiting != deferred_.end();) {
    std::deque<Outgoing>& queue = waiting->second;
    while (!queue.empty()) {
      const Delivery delivery = transmit(queue.front());
      if (delivery == Delivery::full) break;
      noteDelivery(queue.front(), delivery);
      queue.pop_front();
      if (delivery == Delivery::gone) {
        for (const Outgoing& out : queue) noteDelivery(out, Delivery::gone);
        queue.clear();
      }
    }
    waiting = queue.empty() ? deferred_.erase(waiting) : std::next(waiting);
  }
  for (Outgoing& out : batch) send(std::move(out));
}

void ServiceFrontEnd::send(Outgoing out) {
  // Behind what this client already waits for, to keep its frames in order.
  const auto waiting = deferred_.find(out.clientId);
  const Delivery delivery = waiting == deferred_.end() ? transmit(out) : Delivery::full;
  const bool mustArrive = out.single && !out.header.interim();
  if (delivery == Delivery::full && mustArrive &&
      (waiting == deferred_.end() || waiting->second.size() < kDeferredPerClient)) {
    deferred_[out.clientId].push_back(std::move(out));
    return;
  }
  noteDelivery(out, delivery);
}

ServiceFrontEnd::Delivery ServiceFrontEnd::transmit(const Outgoing& out) {
  try {
    if (!stream_.send(zmq::buffer(out.clientId),
                      zmq::send_flags::sndmore | zmq::send_flags::dontwait)) {
      return Delivery::full;
    }
    // The first part was taken: the rest of the message is queued whole.
    stream_.send(zmq::buffer(std::string_view(kStreamFrameTag)), zmq::send_flags::sndmore);
    stream_.send(serialized(out.header), zmq::send_flags::sndmore);
    stream_.send(zmq::message_t(out.pixels.data(), out.pixels.size()), zmq::send_flags::none);
    return Delivery::sent;
  } catch (const zmq::error_t& error) {
    return error.num() == EHOSTUNREACH ? Delivery::gone : Delivery::failed;
  }
}

void ServiceFrontEnd::noteDelivery(const Outgoing& out, Delivery delivery) {
  const std::string& id = out.clientId;
  const std::size_t bytes = out.pixels.size();
  const bool sent = delivery == Delivery::sent;
  const bool gone = delivery == Delivery::gone;
  std::lock_guard lock(mutex_);
  const auto client = clients_.find(id);
  // Interim frames are counted apart: a client's frames are its final ones.
  const bool frame = out.header.status() != v1::FRAME_STATUS_SUPERSEDED && !out.header.interim();
  if (sent && out.header.interim()) ++framesInterim_;
  if (sent) {
    bytesSent_ += bytes;
    if (frame) requestToSent_.add(millisecondsBetween(out.requested, SteadyClock::now()));
    if (client != clients_.end()) {
      client->second.stats.set_bytes_sent(client->second.stats.bytes_sent() + bytes);
      if (frame) client->second.stats.set_frames_sent(client->second.stats.frames_sent() + 1);
    }
    return;
  }
  if (frame) ++framesDropped_;
  if (client == clients_.end()) return;
  if (frame) client->second.stats.set_frames_dropped(client->second.stats.frames_dropped() + 1);
  if (gone) {
    // Its stream is gone: what it queued would be dropped too.
    client->second.attached = false;
    framesDropped_ += queue_.dropClient(id);
  }
}

void ServiceFrontEnd::noteSuperseded(const std::vector<QueuedFrame>& frames) {
  for (const QueuedFrame& frame : frames) {
    ++framesSuperseded_;
    auto client = clients_.find(frame.clientId);
    if (client != clients_.end()) {
      client->second.stats.set_frames_superseded(client->second.stats.frames_superseded() + 1);
    }
    Outgoing out;
    out.clientId = frame.clientId;
    out.single = frame.single;
    out.header.set_request_id(frame.requestId);
    out.header.set_status(v1::FRAME_STATUS_SUPERSEDED);
    out.header.set_path_index(frame.pathIndex);
    out.header.set_path_length(frame.pathLength);
    *out.header.mutable_camera() = cameraKeyMessage(frame.key);
    out.header.set_encoding(frame.format.encoding());
    outgoing_.push_back(std::move(out));
  }
}

v1::Reply ServiceFrontEnd::answer(const v1::Request& request) {
  if (request.has_hello()) return hello(request);
  const auto found = clients_.find(request.client_id());
  if (found == clients_.end()) {
    throw RequestError(v1::ERROR_UNKNOWN_CLIENT,
                       "client_id was not issued by this server (or was forgotten): send hello");
  }
  ClientState& client = found->second;
  client.lastSeen = SteadyClock::now();
  v1::Reply reply;
  reply.set_request_id(request.request_id());
  switch (request.body_case()) {
    case v1::Request::kInfo:
      *reply.mutable_info() = dataset_.info;
      reply.mutable_info()->set_scheduler(pointillist::schedulerName(scheduler_));
      return reply;
    case v1::Request::kRender:
      return queueRender(request, client);
    case v1::Request::kPath:
      return queuePath(request, client);
    case v1::Request::kSetOptions:
      return setOptions(request, client);
    case v1::Request::kStats:
      return statistics(request);
    case v1::Request::kShutdown:
      if (shutdownReason_.empty()) {
        shutdownReason_ =
            "shutdown requested by client " + client.name +
            (request.shutdown().reason().empty() ? "" : ": " + request.shutdown().reason());
      }
      shutdown_ = true;
      reply.mutable_shutdown();
      return reply;
    default:
      throw RequestError(v1::ERROR_UNKNOWN_REQUEST, "request has no body this server knows");
  }
}

v1::Reply ServiceFrontEnd::hello(const v1::Request& request) {
  if (shutdown_) throw RequestError(v1::ERROR_SHUTTING_DOWN, "the service is shutting down");
  if (clients_.size() >= options_.maxClients) {
    // Forget the longest-silent client with nothing queued, if any.
    auto oldest = clients_.end();
    for (auto it = clients_.begin(); it != clients_.end(); ++it) {
      if (queue_.queued(it->first) > 0) continue;
      if (oldest == clients_.end() || it->second.lastSeen < oldest->second.lastSeen) oldest = it;
    }
    if (oldest == clients_.end()) {
      throw RequestError(v1::ERROR_BUSY, "all " + std::to_string(options_.maxClients) +
                                             " client places have frames queued");
    }
    clients_.erase(oldest);
  }
  std::string id;
  do {
    id = randomClientId();
  } while (clients_.contains(id));
  ClientState& client = clients_[id];
  client.name = request.hello().client_name();
  client.format = options_.defaultFormat;
  client.lastSeen = SteadyClock::now();
  client.stats.set_client_id(id);
  client.stats.set_client_name(client.name);
  v1::Reply reply;
  reply.set_request_id(request.request_id());
  v1::HelloReply& hello = *reply.mutable_hello();
  hello.set_client_id(id);
  hello.set_stream_endpoint(streamEndpoint_);
  hello.set_max_message_bytes(static_cast<std::uint32_t>(options_.limits.maxMessageBytes));
  *hello.mutable_format() = client.format;
  return reply;
}

QueuedFrame ServiceFrontEnd::queuedFrame(const v1::Request& request, const ClientState& client,
                                         const v1::FrameFormat& requested) const {
  QueuedFrame frame;
  frame.clientId = request.client_id();
  frame.requestId = request.request_id();
  frame.format = mergeFormat(client.format, requested);
  frame.settings = client.settings;
  frame.requested = SteadyClock::now();
  return frame;
}

v1::Reply ServiceFrontEnd::queueRender(const v1::Request& request, ClientState& client) {
  if (shutdown_) throw RequestError(v1::ERROR_SHUTTING_DOWN, "the service is shutting down");
  if (!client.attached) {
    throw RequestError(v1::ERROR_UNKNOWN_CLIENT, "attach the frames socket before rendering");
  }
  QueuedFrame frame = queuedFrame(request, client, request.render().format());
  frame.key = cameraKeyFromMessage(request.render().camera(), dataset_.up);
  const auto superseded = queue_.pushSingle(std::move(frame));
  noteSuperseded(superseded);
  v1::Reply reply;
  reply.set_request_id(request.request_id());
  reply.mutable_accepted()->set_frames(1);
  reply.mutable_accepted()->set_superseded(static_cast<std::uint32_t>(superseded.size()));
  return reply;
}

v1::Reply ServiceFrontEnd::queuePath(const v1::Request& request, ClientState& client) {
  if (shutdown_) throw RequestError(v1::ERROR_SHUTTING_DOWN, "the service is shutting down");
  if (!client.attached) {
    throw RequestError(v1::ERROR_UNKNOWN_CLIENT, "attach the frames socket before rendering");
  }
  const v1::PathRequest& path = request.path();
  std::vector<CameraKey> keys;
  if (path.has_cameras()) {
    for (const auto& key : path.cameras().keys()) {
      keys.push_back(cameraKeyFromMessage(key, dataset_.up));
    }
  } else {
    keys = builtinCameraPath(path.builtin(), dataset_.bounds, path.frames(), dataset_.up);
  }
  std::vector<QueuedFrame> frames;
  const QueuedFrame base = queuedFrame(request, client, path.format());
  for (std::size_t i = 0; i < keys.size(); ++i) {
    QueuedFrame frame = base;
    frame.key = keys[i];
    frame.pathIndex = static_cast<std::uint32_t>(i);
    frame.pathLength = static_cast<std::uint32_t>(keys.size());
    frames.push_back(std::move(frame));
  }
  queue_.pushPath(std::move(frames));
  v1::Reply reply;
  reply.set_request_id(request.request_id());
  reply.mutable_accepted()->set_frames(static_cast<std::uint32_t>(keys.size()));
  return reply;
}

v1::Reply ServiceFrontEnd::setOptions(const v1::Request& request, ClientState& client) {
  const v1::SetOptionsRequest& options = request.set_options();
  // Checked whole before anything changes: a refused request changes nothing.
  pointillist::v1::FrameSettings settings = client.settings;
  std::optional<pointillist::v1::Scheduler> scheduler;
  try {
    if (!options.mode().empty()) settings.set_mode(parseRenderMode(options.mode()));
    if (!options.scheduler().empty()) scheduler = parseScheduler(options.scheduler());
  } catch (const UsageError& error) {
    throw RequestError(v1::ERROR_INVALID_ARGUMENT, error.what());
  }
  if (options.lod_pixels() != 0.0f) settings.set_lod_pixels(options.lod_pixels());
  try {
    checkFrameSettings(dataset_.run, settings);
  } catch (const UsageError& error) {
    throw RequestError(v1::ERROR_NOT_CHANGEABLE, error.what());
  }
  client.settings = settings;
  if (scheduler) scheduler_ = *scheduler;
  client.format = mergeFormat(client.format, options.format());
  v1::Reply reply;
  reply.set_request_id(request.request_id());
  v1::OptionsReply& answer = *reply.mutable_options();
  *answer.mutable_format() = client.format;
  pointillist::v1::FrameSettings current = client.settings;
  current.set_scheduler(scheduler_);
  const pointillist::v1::RunSettings drawn = frameRunSettings(dataset_.run, current);
  answer.set_mode(renderModeName(drawn.mode()));
  answer.set_lod_pixels(drawn.lod_pixels());
  answer.set_scheduler(pointillist::schedulerName(drawn.scheduler()));
  return reply;
}

v1::Reply ServiceFrontEnd::statistics(const v1::Request& request) {
  v1::Reply reply;
  reply.set_request_id(request.request_id());
  v1::Statistics& stats = *reply.mutable_stats();
  stats.set_requests(requests_);
  stats.set_errors(errors_);
  stats.set_frames_rendered(framesRendered_);
  stats.set_frames_superseded(framesSuperseded_);
  stats.set_frames_dropped(framesDropped_);
  stats.set_bytes_sent(bytesSent_);
  stats.set_splats(splats_);
  fillLatency(stats.mutable_request_to_sent(), requestToSent_);
  fillLatency(stats.mutable_render(), renderLatency_);
  fillLatency(stats.mutable_encode(), encodeLatency_);
  fillLatency(stats.mutable_reproject(), reprojectLatency_);
  stats.set_frames_interim(framesInterim_);
  for (const auto& [id, client] : clients_) {
    v1::ClientStatistics& entry = *stats.add_clients();
    entry = client.stats;
    entry.set_queued(static_cast<std::uint32_t>(queue_.queued(id)));
  }
  stats.set_uptime_seconds(millisecondsBetween(started_, SteadyClock::now()) / 1000.0);
  stats.set_queued(static_cast<std::uint32_t>(queue_.size()));
  return reply;
}

}  // namespace pointillist::service
