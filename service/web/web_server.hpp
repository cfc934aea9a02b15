#pragma once
// pointillist-web's HTTP and WebSocket server (Boost.Beast): GET / serves the
// viewer page built into the binary, /ws upgrades to the WebSocket each
// browser's relay (relay.hpp) speaks through. One io_context thread does all
// the socket work; each browser adds one relay thread that blocks on its
// mailbox or on the service, so an idle viewer costs no CPU.
#include <cstdint>
#include <memory>
#include <string>

#include "service/web/relay.hpp"

namespace pointillist::service::web {

struct WebServerOptions {
  std::string address = "127.0.0.1";
  std::uint16_t port = 8080;  // 0: any free port (see WebServer::port)
  std::size_t maxBrowsers = 16;
  RelayOptions relay;
};

// "HOST:PORT" or "[V6]:PORT"; UsageError otherwise.
void parseHttpAddress(const std::string& text, WebServerOptions& options);

class WebServer {
 public:
  // Binds and listens; Error when the address cannot be used.
  explicit WebServer(WebServerOptions options);
  ~WebServer();
  WebServer(const WebServer&) = delete;
  WebServer& operator=(const WebServer&) = delete;

  std::uint16_t port() const;
  // Serves until SIGINT or SIGTERM (or stop()), then ends every browser's
  // relay and returns the signal's name ("stop" for stop()).
  std::string runUntilSignal();
  void stop();

 private:
  class Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace pointillist::service::web
