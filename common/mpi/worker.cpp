#include "common/mpi/worker.hpp"

#include "common/mpi/role_program.hpp"
#include "common/peer_watch.hpp"

#include <cstdio>
#include <optional>

namespace pointillist {

namespace {

// Nothing more is taken from a silent peer; whether the job goes on is the
// display's call (it hears from everyone), and work its message carried is
// re-issued as late. Without the display nothing can go on.
void ignoreSilentPeer(Job& job, const PeerSilentError& silent) {
  if (silent.rank() == job.displayRank()) throw silent;
  std::fprintf(stderr, "%s: %s; ignoring it from now on\n", job.describe().c_str(), silent.what());
  job.markLost(silent.rank());
}

}  // namespace

void serveUntilShutdown(Job& job, WorkerProcess* process, SelfKill selfKill) {
  Channel& channel = job.channel();
  SendQueue& sends = job.sends();
  Backoff backoff;
  const LivenessSettings liveness = livenessOf(job.runSettings());
  const int display = job.displayRank();
  HeartbeatTimer heartbeat(liveness.heartbeat, Clock::now());
  // Armed by the display's first message: it starts speaking only once every
  // process is ready, which may take a while after this one is.
  std::optional<TimePoint> displayHeard;
  // Each pass is charged to what it did: polling when nothing came or was done.
  CpuActivities::Meter meter(job.activities(), "poll");
  while (true) {
    const TimePoint now = Clock::now();
    meter.switchTo("send");
    if (heartbeat.due(now)) {
      v1::Heartbeat beat;
      beat.set_sent_ns(now.time_since_epoch().count());
      sends.post(display, MessageKind::Heartbeat, beat);
    }
    sends.reap();
    meter.switchTo("receive");
    std::optional<Envelope> envelope;
    try {
      envelope = channel.tryReceive();
    } catch (const PeerSilentError& silent) {
      // A peer stopped halfway through a message: it died, or its link is
      // down for longer than any transfer may take.
      ignoreSilentPeer(job, silent);
      continue;
    }
    // Judged only with nothing waiting: after a long draw the display's
    // heartbeats are still queued, not missing.
    if (!envelope && displayHeard && now - *displayHeard > liveness.peerTimeout) {
      throw PeerSilentError(display, "the display (" + job.describeRank(display) + ") is lost: " +
                                         silenceText(secondsBetween(*displayHeard, now)) +
                                         "; the job cannot go on without it");
    }
    if (!envelope) meter.relabel("poll");
    if (envelope) {
      backoff.reset();
      if (envelope->source == display) displayHeard = Clock::now();
      if (envelope->kind == MessageKind::Heartbeat) continue;
      if (envelope->kind == MessageKind::PeerLost) {
        const auto lost = envelope->as<v1::PeerLost>();
        job.markLost(lost.world_rank());
        if (process != nullptr) process->onPeerLost(lost.world_rank(), lost.role());
        continue;
      }
      if (envelope->kind == MessageKind::Shutdown) {
        // A lost process will not take what is still on its way to it.
        const auto shutdown = envelope->as<v1::Shutdown>();
        for (int lost : shutdown.lost_ranks()) job.markLost(lost);
        job.acknowledgeShutdown(process != nullptr ? process->summary() : std::string());
        return;
      }
      if (envelope->kind == MessageKind::ErrorReport) {
        const auto report = envelope->as<v1::ErrorReport>();
        throw ProtocolError("peer " + executableName(report.origin_role()) + " rank " +
                            std::to_string(report.origin_rank()) + " failed: " + report.message());
      }
      if (process == nullptr) {
        throw ProtocolError(std::string("unexpected ") + messageKindName(envelope->kind) +
                            " message from rank " + std::to_string(envelope->source));
      }
      meter.switchTo(std::string("handle ") + messageKindName(envelope->kind));
      try {
        process->onMessage(*envelope);
      } catch (const PeerSilentError& silent) {
        // A message that needed its sender after it ended (a data packet in
        // a lost data-send's memory): as when its payload never comes.
        ignoreSilentPeer(job, silent);
        continue;
      }
      selfKill.count();
      continue;
    }
    if (process != nullptr) {
      meter.switchTo(process->idleActivity());
      if (process->onIdle()) {
        backoff.reset();
        continue;
      }
      meter.relabel("poll");
    }
    if (sends.pending()) {
      backoff.wait(kTransferPoll);
    } else {
      backoff.wait();
    }
  }
}

int runWorkerMain(
    int argc, char** argv, v1::Role role, const std::string& description,
    const std::function<void(CLI::App&)>& addOptions,
    const std::function<std::unique_ptr<WorkerProcess>(Job&, const std::string&)>& start) {
  CLI::App app{description};
  CommonRoleOptions common;
  std::string datasetPath;
  addCommonRoleOptions(app, common);
  app.add_option("--dataset", datasetPath, "Dataset directory written by pointillist-preprocess");
  if (addOptions) addOptions(app);
  return runRoleMain(argc, argv, role, app, [&](Job& job) {
    std::unique_ptr<WorkerProcess> process;
    if (!datasetPath.empty()) process = start(job, datasetPath);
    job.handshake(handshakeOptions(common));
    if (process) process->begin(job.runSettings());
    job.reportReady(process ? process->readyDetail() : std::string("no dataset"));
    serveUntilShutdown(job, process.get(), SelfKill(common, job));
    // Sends still in flight may read the process's memory.
    job.sends().drain(std::chrono::seconds(5));
    return 0;
  });
}

}  // namespace pointillist
