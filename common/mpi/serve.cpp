#include "common/mpi/serve.hpp"

namespace pointillist {

void serveUntilShutdown(Job& job, const ServeHandlers& handlers) {
  Channel& channel = job.channel();
  Backoff backoff;
  while (true) {
    if (auto envelope = channel.tryReceive()) {
      backoff.reset();
      if (envelope->kind == MessageKind::Shutdown) {
        job.acknowledgeShutdown(handlers.summary ? handlers.summary() : std::string());
        return;
      }
      if (envelope->kind == MessageKind::ErrorReport) {
        const auto report = envelope->as<v1::ErrorReport>();
        throw ProtocolError("peer " + executableName(report.origin_role()) + " rank " +
                            std::to_string(report.origin_rank()) + " failed: " + report.message());
      }
      if (!handlers.onMessage) {
        throw ProtocolError(std::string("unexpected ") + messageKindName(envelope->kind) +
                            " message from rank " + std::to_string(envelope->source));
      }
      handlers.onMessage(*envelope);
      continue;
    }
    if (handlers.onIdle && handlers.onIdle()) {
      backoff.reset();
      continue;
    }
    if (handlers.transfersPending && handlers.transfersPending()) {
      backoff.wait(kTransferPoll);
    } else {
      backoff.wait();
    }
  }
}

void runWorkerRole(Job& job, const HandshakeOptions& handshake, const std::string& readyDetail,
                   const ServeHandlers& handlers, const std::function<void()>& afterReady) {
  job.handshake(handshake);
  job.reportReady(readyDetail);
  if (afterReady) afterReady();
  serveUntilShutdown(job, handlers);
}

}  // namespace pointillist
