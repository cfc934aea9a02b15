// pointillist-web: the live browser viewer of a job started with
// `deploy/run.sh --serve`. Serves one page and relays each browser's cameras
// to the service and its frames back.
//   pointillist-web --connect tcp://127.0.0.1:5570 --http 127.0.0.1:8080
#include <CLI/CLI.hpp>

#include <cstdio>

#include "common/tool_entry.hpp"
#include "service/core/frame_encoding.hpp"
#include "service/web/web_server.hpp"
#include "service/zmq/curve_keys.hpp"

namespace pointillist::service::web {
namespace {

int run(int argc, char** argv) {
  CLI::App app{"Pointillist browser viewer: a web page that orbits a running service's data"};
  app.name("pointillist-web");
  WebServerOptions options;
  std::string http = "127.0.0.1:8080";
  std::string encoding = "jpeg";
  std::uint32_t quality = kDefaultJpegQuality;
  double timeoutSeconds = 10.0;
  std::string curveServerKey, curveKey;
  app.add_option("--connect", options.relay.connect, "Control endpoint of the service")
      ->capture_default_str();
  app.add_option("--http", http,
                 "ADDRESS:PORT to serve the page on (loopback unless told otherwise; port 0: "
                 "any free one)")
      ->capture_default_str();
  app.add_option("--encoding", encoding, "Frames as jpeg or png")
      ->check(CLI::IsMember({"jpeg", "png"}))
      ->capture_default_str();
  app.add_option("--quality", quality, "JPEG quality 1-100")
      ->check(CLI::Range(1, 100))
      ->capture_default_str();
  app.add_option("--timeout", timeoutSeconds, "Seconds to wait for a reply of the service")
      ->capture_default_str();
  app.add_option("--max-browsers", options.maxBrowsers, "Browsers served at once")
      ->check(CLI::Range(1, 256))
      ->capture_default_str();
  app.add_option("--curve-server-key", curveServerKey, "CURVE: file with the server's public key");
  app.add_option("--curve-key", curveKey, "CURVE: file with this client's secret key");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& error) {
    return app.exit(error);
  }
  if (curveServerKey.empty() != curveKey.empty()) {
    throw UsageError("CURVE needs both --curve-server-key and --curve-key");
  }
  if (!curveKey.empty()) {
    options.relay.curve = CurveClientKeys{readCurveKey(curveServerKey), readCurveKey(curveKey)};
  }
  if (!(timeoutSeconds > 0.0 && timeoutSeconds < 3600.0)) {
    throw UsageError("--timeout must be between 0 and 3600 seconds");
  }
  options.relay.timeout = std::chrono::milliseconds(static_cast<long>(timeoutSeconds * 1e3));
  options.relay.format.set_encoding(parseEncoding(encoding));
  options.relay.format.set_jpeg_quality(quality);
  parseHttpAddress(http, options);

  WebServer server(options);
  const bool v6 = options.address.find(':') != std::string::npos;
  std::printf("pointillist-web: viewer on http://%s%s%s:%u/ for the service at %s\n", v6 ? "[" : "",
              options.address.c_str(), v6 ? "]" : "", static_cast<unsigned>(server.port()),
              options.relay.connect.c_str());
  std::fflush(stdout);
  const std::string reason = server.runUntilSignal();
  std::printf("pointillist-web: stopped (%s)\n", reason.c_str());
  return 0;
}

}  // namespace
}  // namespace pointillist::service::web

int main(int argc, char** argv) {
  return pointillist::runToolMain("pointillist-web",
                                  [&] { return pointillist::service::web::run(argc, argv); });
}
