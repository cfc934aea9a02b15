#pragma once
// The event loop of a non-display role: handle messages until the display says
// Shutdown, doing background work in between, and sleeping when there is none.
#include <functional>
#include <string>

#include "common/mpi/job.hpp"

namespace pointillist {

struct ServeHandlers {
  // Called for every message except Shutdown.
  std::function<void(Envelope&)> onMessage;
  // Called when no message is waiting; returns true if it did useful work
  // (then the loop polls again at once instead of sleeping).
  std::function<bool()> onIdle;
  // True while bulk sends of this process are still in flight: the loop then
  // polls often enough to move their fragments (shared memory without
  // single-copy moves a large message only while both sides call MPI).
  std::function<bool()> transfersPending;
  // Summary line sent back with the ShutdownAck.
  std::function<std::string()> summary;
};

// Handlers that call a role's process object: onMessage(Envelope&), onIdle(),
// summary() and sendsPending().
template <class Process>
ServeHandlers handlersFor(Process& process) {
  ServeHandlers handlers;
  handlers.onMessage = [&process](Envelope& envelope) { process.onMessage(envelope); };
  handlers.onIdle = [&process] { return process.onIdle(); };
  handlers.summary = [&process] { return process.summary(); };
  handlers.transfersPending = [&process] { return process.sendsPending(); };
  return handlers;
}

void serveUntilShutdown(Job& job, const ServeHandlers& handlers);

// A worker role's life after start-up: handshake, report ready (with a detail
// line for the display), run `afterReady` (e.g. ask for the first work), then
// serve until shutdown.
void runWorkerRole(Job& job, const HandshakeOptions& handshake, const std::string& readyDetail,
                   const ServeHandlers& handlers, const std::function<void()>& afterReady = {});

}  // namespace pointillist
