#include "common/mpi/worker.hpp"

#include "common/mpi/role_program.hpp"

namespace pointillist {

void serveUntilShutdown(Job& job, WorkerProcess* process) {
  Channel& channel = job.channel();
  SendQueue& sends = job.sends();
  Backoff backoff;
  // Each pass is charged to what it did: polling when nothing came or was done.
  CpuActivities::Meter meter(job.activities(), "poll");
  while (true) {
    meter.switchTo("send");
    sends.reap();
    meter.switchTo("receive");
    auto envelope = channel.tryReceive();
    if (!envelope) meter.relabel("poll");
    if (envelope) {
      backoff.reset();
      if (envelope->kind == MessageKind::Shutdown) {
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
      process->onMessage(*envelope);
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
    serveUntilShutdown(job, process.get());
    // Sends still in flight may read the process's memory.
    job.sends().drain(std::chrono::seconds(5));
    return 0;
  });
}

}  // namespace pointillist
