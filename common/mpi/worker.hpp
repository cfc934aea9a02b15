#pragma once
// The life of a traverse, data-send or render process: options, handshake,
// Ready, then messages until the display says Shutdown, with background work
// in between and sleep when there is none.
#include <CLI/CLI.hpp>

#include <functional>
#include <memory>
#include <string>

#include "common/mpi/job.hpp"
#include "common/mpi/role_program.hpp"

namespace pointillist {

// A worker role's process: a thin driver of the role's core.
class WorkerProcess {
 public:
  virtual ~WorkerProcess() = default;
  // After the handshake, with the run's settings from the display.
  virtual void begin(const v1::RunSettings& settings) = 0;
  // One line for the display's start-up report (after begin).
  virtual std::string readyDetail() const = 0;
  // Every message except Shutdown and ErrorReport.
  virtual void onMessage(Envelope& envelope) = 0;
  // Called when no message is waiting; true if it did useful work (the loop
  // then polls again at once instead of sleeping).
  virtual bool onIdle() { return false; }
  // What the CPU time of an onIdle that did work is charged to.
  virtual std::string idleActivity() const { return "idle work"; }
  // Sent back with the ShutdownAck.
  virtual std::string summary() const = 0;
  // The display says `rank` is gone (the job sends nothing more to it).
  virtual void onPeerLost(int /*rank*/, v1::Role /*role*/) {}
};

// Handles messages until Shutdown. Without a process (a job started without a
// dataset, to check the handshake) any other message is a ProtocolError.
// Sends the display a Heartbeat every heartbeat interval; once the display has
// spoken, a display silent past the peer timeout is a PeerSilentError.
// `selfKill` counts every message handed to the process (a test hook).
void serveUntilShutdown(Job& job, WorkerProcess* process, SelfKill selfKill = {});

// A worker role's main. The options are the common ones, --dataset and those
// `addOptions` adds; `start` loads the dataset and builds the process before
// the handshake, so that a bad dataset fails before any work is handed out.
// Without --dataset the process only takes part in the handshake.
int runWorkerMain(
    int argc, char** argv, v1::Role role, const std::string& description,
    const std::function<void(CLI::App&)>& addOptions,
    const std::function<std::unique_ptr<WorkerProcess>(Job&, const std::string&)>& start);

}  // namespace pointillist
