#include "service/web/web_server.hpp"

#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/post.hpp>
#include <boost/asio/signal_set.hpp>
#include <boost/asio/steady_timer.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/websocket.hpp>

#include <atomic>
#include <csignal>
#include <cstdio>
#include <deque>
#include <system_error>
#include <thread>

#include "service/web/viewer_page.hpp"

namespace pointillist::service::web {
namespace {

namespace asio = boost::asio;
namespace beast = boost::beast;
namespace http = beast::http;
namespace websocket = beast::websocket;
using tcp = asio::ip::tcp;

constexpr std::uint32_t kMaxHttpHeaderBytes = 8 * 1024;
constexpr std::chrono::seconds kHttpTimeout{30};
constexpr std::size_t kMaxQueuedMessages = 64;

// Every relay thread; the server waits for all of them before it goes, as
// they post into its io_context.
class RelayThreads {
 public:
  void launch(const RelayOptions& options, std::string clientName,
              std::shared_ptr<RelayMailbox> mailbox, SendToBrowser send) {
    {
      const std::lock_guard lock(mutex_);
      ++running_;
      std::erase_if(mailboxes_, [](const auto& weak) { return weak.expired(); });
      mailboxes_.push_back(mailbox);
    }
    try {
      std::thread([this, &options, name = std::move(clientName), mailbox = std::move(mailbox),
                   send = std::move(send)] {
        runRelay(options, name, *mailbox, send);
        const std::lock_guard lock(mutex_);
        --running_;
        done_.notify_all();
      }).detach();
    } catch (const std::system_error& error) {
      const std::lock_guard lock(mutex_);
      --running_;
      throw Error(std::string("cannot start a relay thread: ") + error.what());
    }
  }

  void stopAllAndWait() {
    std::unique_lock lock(mutex_);
    for (const auto& weak : mailboxes_) {
      if (auto mailbox = weak.lock()) mailbox->stop();
    }
    done_.wait(lock, [&] { return running_ == 0; });
  }

 private:
  std::mutex mutex_;
  std::condition_variable done_;
  std::size_t running_ = 0;
  std::vector<std::weak_ptr<RelayMailbox>> mailboxes_;
};

struct ServerState {
  const WebServerOptions& options;
  asio::io_context& ioc;
  RelayThreads& relays;
  std::atomic<std::size_t> browsers{0};
};

std::string peerName(const tcp::socket& socket) {
  boost::system::error_code ec;
  const auto endpoint = socket.remote_endpoint(ec);
  if (ec) return "unknown peer";
  return endpoint.address().to_string() + ":" + std::to_string(endpoint.port());
}

// A browser's WebSocket: reads its messages (one at a time, capped), writes
// what its relay sends (in order, one write at a time). Lives on the io thread.
class BrowserSession : public std::enable_shared_from_this<BrowserSession> {
 public:
  BrowserSession(tcp::socket&& socket, ServerState& state)
      : ws_(std::move(socket)), state_(state), mailbox_(std::make_shared<RelayMailbox>()) {
    ++state_.browsers;
  }
  ~BrowserSession() {
    mailbox_->stop();
    --state_.browsers;
  }
  BrowserSession(const BrowserSession&) = delete;
  BrowserSession& operator=(const BrowserSession&) = delete;

  void start(http::request<http::string_body> request) {
    peer_ = peerName(beast::get_lowest_layer(ws_).socket());
    beast::get_lowest_layer(ws_).expires_never();  // the WebSocket's own timeouts apply
    // Pings after 30 s of silence, closed after 60: a browser whose machine
    // vanished does not keep its relay for ever.
    auto timeout = websocket::stream_base::timeout::suggested(beast::role_type::server);
    timeout.idle_timeout = std::chrono::seconds(60);
    timeout.keep_alive_pings = true;
    ws_.set_option(timeout);
    ws_.read_message_max(kMaxBrowserMessageBytes);
    ws_.async_accept(request,
                     [self = shared_from_this()](beast::error_code ec) { self->onAccept(ec); });
  }

  void send(OutgoingMessage message) {
    if (closing_) return;
    // A browser that sends but never reads: what it would get stops here (its
    // frames are bounded before, by the relay's framesInFlight).
    if (message.kind != OutgoingMessage::Kind::kClose && queue_.size() >= kMaxQueuedMessages) {
      if (message.kind == OutgoingMessage::Kind::kFrame) --mailbox_->framesInFlight;
      return;
    }
    queue_.push_back(std::move(message));
    if (queue_.size() == 1) writeNext();
  }

 private:
  void onAccept(beast::error_code ec) {
    if (ec) return;
    std::fprintf(stderr, "pointillist-web: browser %s connected\n", peer_.c_str());
    const std::weak_ptr<BrowserSession> weak = weak_from_this();
    try {
      state_.relays.launch(state_.options.relay, "pointillist-web " + peer_, mailbox_,
                           [weak, executor = state_.ioc.get_executor()](OutgoingMessage message) {
                             asio::post(executor, [weak, message = std::move(message)]() mutable {
                               if (auto self = weak.lock()) self->send(std::move(message));
                             });
                           });
    } catch (const Error& error) {
      std::fprintf(stderr, "pointillist-web: browser %s: %s\n", peer_.c_str(), error.what());
      send({OutgoingMessage::Kind::kText, errorJson(error.what()), {}});
      send({OutgoingMessage::Kind::kClose, {}, {}});
      return;
    }
    readNext();
  }

  void readNext() {
    ws_.async_read(buffer_, [self = shared_from_this()](beast::error_code ec, std::size_t) {
      self->onRead(ec);
    });
  }

  void onRead(beast::error_code ec) {
    if (ec) {
      // Closed, gone, or over the size cap (Beast closes with 1009): only this
      // browser's relay stops.
      std::fprintf(stderr, "pointillist-web: browser %s left (%s)\n", peer_.c_str(),
                   ec.message().c_str());
      mailbox_->stop();
      return;
    }
    const std::string text = beast::buffers_to_string(buffer_.data());
    buffer_.consume(buffer_.size());
    if (!ws_.got_text()) {
      send({OutgoingMessage::Kind::kText, errorJson("binary messages are not taken"), {}});
    } else {
      try {
        mailbox_->post(parseBrowserMessage(text));
      } catch (const BrowserMessageError& error) {
        send({OutgoingMessage::Kind::kText, errorJson(error.what()), {}});
      }
    }
    readNext();
  }

  void writeNext() {
    OutgoingMessage& message = queue_.front();
    if (message.kind == OutgoingMessage::Kind::kClose) {
      closing_ = true;
      ws_.async_close(websocket::close_code::internal_error,
                      [self = shared_from_this()](beast::error_code) {});
      return;
    }
    const bool frameMeta = message.kind == OutgoingMessage::Kind::kFrame && !message.metaSent;
    ws_.binary(message.kind == OutgoingMessage::Kind::kFrame && !frameMeta);
    ws_.async_write(asio::buffer(frameMeta ? message.meta : message.data),
                    [self = shared_from_this(), frameMeta](beast::error_code ec, std::size_t) {
                      self->onWrite(ec, frameMeta);
                    });
  }

  void onWrite(beast::error_code ec, bool frameMeta) {
    if (!ec && frameMeta) {
      queue_.front().metaSent = true;  // the image next
      writeNext();
      return;
    }
    if (queue_.front().kind == OutgoingMessage::Kind::kFrame) --mailbox_->framesInFlight;
    queue_.pop_front();
    if (ec) {
      mailbox_->stop();
      queue_.clear();
      closing_ = true;
      return;
    }
    if (!queue_.empty()) writeNext();
  }

  websocket::stream<beast::tcp_stream> ws_;
  ServerState& state_;
  std::shared_ptr<RelayMailbox> mailbox_;
  beast::flat_buffer buffer_;
  std::deque<OutgoingMessage> queue_;
  std::string peer_;
  bool closing_ = false;
};

// One HTTP connection: the page, a 404, or the upgrade to a BrowserSession.
class HttpSession : public std::enable_shared_from_this<HttpSession> {
 public:
  HttpSession(tcp::socket&& socket, ServerState& state)
      : stream_(std::move(socket)), state_(state) {}

  void start() { readNext(); }

 private:
  void readNext() {
    parser_.emplace();
    parser_->header_limit(kMaxHttpHeaderBytes);
    parser_->body_limit(1024);
    stream_.expires_after(kHttpTimeout);
    http::async_read(
        stream_, buffer_, *parser_,
        [self = shared_from_this()](beast::error_code ec, std::size_t) { self->onRead(ec); });
  }

  void onRead(beast::error_code ec) {
    if (ec) {
      stream_.socket().shutdown(tcp::socket::shutdown_send, ec);
      return;
    }
    http::request<http::string_body> request = parser_->release();
    if (websocket::is_upgrade(request)) {
      upgrade(std::move(request));
      return;
    }
    respond(request);
  }

  // A page from another site must not drive this viewer from the user's
  // browser: the Origin (when the browser sends one) must be this server.
  static bool sameOrigin(const http::request<http::string_body>& request) {
    const auto origin = request.find(http::field::origin);
    if (origin == request.end()) return true;
    const auto host = request.find(http::field::host);
    if (host == request.end()) return false;
    return origin->value() == "http://" + std::string(host->value());
  }

  void upgrade(http::request<http::string_body> request) {
    if (request.target() != "/ws")
      return reply(request, http::status::not_found, "no such WebSocket\n");
    if (!sameOrigin(request))
      return reply(request, http::status::forbidden, "cross-origin refused\n");
    if (state_.browsers.load() >= state_.options.maxBrowsers) {
      return reply(request, http::status::service_unavailable, "too many browsers\n");
    }
    std::shared_ptr<BrowserSession> session;
    try {
      session = std::make_shared<BrowserSession>(stream_.release_socket(), state_);
    } catch (const Error& error) {
      std::fprintf(stderr, "pointillist-web: cannot serve a browser: %s\n", error.what());
      return;  // the socket closes with the session that was not made
    }
    session->start(std::move(request));
  }

  void respond(const http::request<http::string_body>& request) {
    if (request.method() != http::verb::get && request.method() != http::verb::head) {
      return reply(request, http::status::method_not_allowed, "GET only\n");
    }
    const beast::string_view target = request.target();
    if (target != "/" && target != "/index.html") {
      return reply(request, http::status::not_found, "not found\n");
    }
    const std::string_view page = viewerPage();
    reply(request, http::status::ok, std::string(page), "text/html; charset=utf-8");
  }

  void reply(const http::request<http::string_body>& request, http::status status, std::string body,
             const char* type = "text/plain; charset=utf-8") {
    auto response = std::make_shared<http::response<http::string_body>>(status, request.version());
    response->set(http::field::server, "pointillist-web");
    response->set(http::field::content_type, type);
    response->set(http::field::cache_control, "no-store");
    response->keep_alive(request.keep_alive());
    if (request.method() == http::verb::head) {
      response->content_length(body.size());
    } else {
      response->body() = std::move(body);
      response->prepare_payload();
    }
    http::async_write(stream_, *response,
                      [self = shared_from_this(), response](beast::error_code ec, std::size_t) {
                        if (ec || !response->keep_alive()) {
                          self->stream_.socket().shutdown(tcp::socket::shutdown_send, ec);
                          return;
                        }
                        self->readNext();
                      });
  }

  beast::tcp_stream stream_;
  ServerState& state_;
  beast::flat_buffer buffer_;
  std::optional<http::request_parser<http::string_body>> parser_;
};

}  // namespace

void parseHttpAddress(const std::string& text, WebServerOptions& options) {
  const auto colon = text.rfind(':');
  if (colon == std::string::npos || colon == 0 || colon + 1 == text.size()) {
    throw UsageError("--http takes ADDRESS:PORT, not '" + text + "'");
  }
  std::string host = text.substr(0, colon);
  if (host.size() > 2 && host.front() == '[' && host.back() == ']') {
    host = host.substr(1, host.size() - 2);
  }
  const std::string portText = text.substr(colon + 1);
  unsigned long port = 0;
  try {
    std::size_t used = 0;
    port = std::stoul(portText, &used);
    if (used != portText.size()) throw std::invalid_argument(portText);
  } catch (const std::exception&) {
    throw UsageError("--http: port '" + portText + "' is not a number");
  }
  if (port > 65535) throw UsageError("--http: port " + portText + " is over 65535");
  boost::system::error_code ec;
  asio::ip::make_address(host, ec);
  if (ec) throw UsageError("--http: '" + host + "' is not an IP address");
  options.address = host;
  options.port = static_cast<std::uint16_t>(port);
}

class WebServer::Impl {
 public:
  explicit Impl(WebServerOptions options)
      : options_(std::move(options)),
        state_{options_, ioc_, relays_, {}},
        acceptor_(ioc_),
        signals_(ioc_, SIGINT, SIGTERM) {
    boost::system::error_code ec;
    const auto address = asio::ip::make_address(options_.address, ec);
    if (ec) throw UsageError("'" + options_.address + "' is not an IP address");
    const tcp::endpoint endpoint(address, options_.port);
    const auto check = [&](const char* what) {
      if (ec) {
        throw Error(std::string("cannot ") + what + " " + options_.address + ":" +
                    std::to_string(options_.port) + ": " + ec.message());
      }
    };
    acceptor_.open(endpoint.protocol(), ec);
    check("open");
    acceptor_.set_option(asio::socket_base::reuse_address(true), ec);
    check("configure");
    acceptor_.bind(endpoint, ec);
    check("bind");
    acceptor_.listen(asio::socket_base::max_listen_connections, ec);
    check("listen on");
  }

  ~Impl() { relays_.stopAllAndWait(); }

  std::uint16_t port() const { return acceptor_.local_endpoint().port(); }

  std::string run() {
    acceptNext();
    signals_.async_wait([this](beast::error_code ec, int signal) {
      if (ec) return;
      reason_ = signal == SIGINT ? "SIGINT" : "SIGTERM";
      ioc_.stop();
    });
    ioc_.run();
    relays_.stopAllAndWait();
    return reason_;
  }

  void stop() {
    asio::post(ioc_, [this] { ioc_.stop(); });
  }

 private:
  void acceptNext() {
    acceptor_.async_accept(ioc_, [this](beast::error_code ec, tcp::socket socket) {
      if (ec == asio::error::operation_aborted) return;
      if (!ec) {
        // A frame's metadata and its image go out back to back: without this,
        // Nagle holds the image until the browser's delayed ACK (40 ms a frame).
        socket.set_option(tcp::no_delay(true), ec);
        std::make_shared<HttpSession>(std::move(socket), state_)->start();
        acceptNext();
        return;
      }
      // Out of descriptors, say: try again a little later rather than spin.
      retry_.expires_after(std::chrono::milliseconds(200));
      retry_.async_wait([this](beast::error_code) { acceptNext(); });
    });
  }

  // Destroyed bottom-up: ioc_ destroys the sessions its handlers still hold,
  // and they touch state_ (browsers) on the way, so state_ and what it names
  // come before ioc_. The relay threads, which post into ioc_, end in ~Impl.
  WebServerOptions options_;
  RelayThreads relays_;
  ServerState state_;
  asio::io_context ioc_{1};
  tcp::acceptor acceptor_;
  asio::signal_set signals_;
  asio::steady_timer retry_{ioc_};
  std::string reason_ = "stop";
};

WebServer::WebServer(WebServerOptions options)
    : impl_(std::make_unique<Impl>(std::move(options))) {}
WebServer::~WebServer() = default;
std::uint16_t WebServer::port() const {
  return impl_->port();
}
std::string WebServer::runUntilSignal() {
  return impl_->run();
}
void WebServer::stop() {
  impl_->stop();
}

}  // namespace pointillist::service::web
