#pragma once
// A role executable's main: options, MPI start-up, and errors reported with
// role and rank. run.sh passes one argument list to all roles, so each role
// ignores options meant for the others.
#include <CLI/CLI.hpp>

#include <functional>
#include <string>

#include "common/mpi/job.hpp"

namespace pointillist {

struct CommonRoleOptions {
  std::string expectLayout;  // D,T,S,R as launched; checked in the handshake
  std::uint32_t protocolVersion = v1::PROTOCOL_VERSION_CURRENT;
  double handshakeTimeoutSeconds = 60.0;
  // Test hook: one process kills itself (SIGKILL, as when its node is lost)
  // after a number of events (messages handled; frames finished for the
  // display). Hidden options --die-role, --die-index, --die-after.
  std::string dieRole;
  int dieIndex = 0;
  std::uint64_t dieAfter = 0;
};

// Counts a process's events and kills it at the count the test hook asked for.
class SelfKill {
 public:
  SelfKill() = default;
  SelfKill(const CommonRoleOptions& options, const Job& job);
  void count();  // raises SIGKILL on the chosen event
  bool armed() const { return after_ > 0; }

 private:
  std::uint64_t after_ = 0;
  std::uint64_t seen_ = 0;
};

void addCommonRoleOptions(CLI::App& app, CommonRoleOptions& options);
HandshakeOptions handshakeOptions(const CommonRoleOptions& options);

// `--help` (or `-h`) prints the app's help and returns 0 without starting MPI,
// so every executable answers it when started on its own. Otherwise sets up
// the Job, parses the options (a bad one is a UsageError), calls body, and
// turns any exception into a message naming role and rank. Errors every peer
// already knows about end the job with a non-zero exit; any other error aborts
// the whole MPI job so no peer waits forever.
int runRoleMain(int argc, char** argv, v1::Role role, CLI::App& app,
                const std::function<int(Job&)>& body);

}  // namespace pointillist
