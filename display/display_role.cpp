#include "display/display_role.hpp"

#include <chrono>
#include <cstdio>
#include <thread>

#include "common/mpi/role_options.hpp"

namespace pointillist::display {
namespace {

struct DisplayOptions {
  CommonRoleOptions common;
  double idleSeconds = 0.0;
  double shutdownTimeoutSeconds = 60.0;
};

// Holds the job idle for a while; used to check that idle ranks sleep.
void stayIdle(double seconds) {
  if (seconds <= 0.0) return;
  std::this_thread::sleep_for(std::chrono::duration<double>(seconds));
}

}  // namespace

int runDisplayRole(Job& job, int argc, char** argv) {
  CLI::App app{"Pointillist display process (started by deploy/run.sh)"};
  DisplayOptions options;
  addCommonRoleOptions(app, options.common);
  app.add_option("--idle-seconds", options.idleSeconds,
                 "Keep the job up and idle this long before shutting down");
  app.add_option("--shutdown-timeout", options.shutdownTimeoutSeconds,
                 "Seconds to wait for every process to acknowledge shutdown");
  if (!parseRoleOptions(app, job, argc, argv)) return 0;

  const auto start = std::chrono::steady_clock::now();
  job.handshake(handshakeOptions(options.common));
  const auto ready = job.awaitReady(std::chrono::milliseconds(
      static_cast<long>(options.common.handshakeTimeoutSeconds * 1000.0)));
  const double startupSeconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::printf("display: job %s ready (%zu peers) in %.2f s\n", job.layout().toString().c_str(),
              ready.size(), startupSeconds);
  std::fflush(stdout);

  const double displayCpuBefore = processCpuSeconds();
  stayIdle(options.idleSeconds);
  const double displayCpu = processCpuSeconds() - displayCpuBefore;

  job.shutdownAll("job complete", std::chrono::milliseconds(
                                      static_cast<long>(options.shutdownTimeoutSeconds * 1000.0)));
  double peerCpu = 0.0;
  double peerWall = 0.0;
  for (const auto& ack : job.lastAcks()) {
    peerCpu += ack.cpu_seconds_since_ready();
    peerWall = std::max(peerWall, ack.wall_seconds_since_ready());
  }
  std::printf(
      "display: shutdown complete; cpu since ready: %.3f core-seconds over %.2f s across %d "
      "ranks (display %.3f)\n",
      peerCpu + displayCpu, peerWall, job.worldSize(), displayCpu);
  std::fflush(stdout);
  return 0;
}

}  // namespace pointillist::display
