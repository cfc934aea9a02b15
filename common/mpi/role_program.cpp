#include "common/mpi/role_program.hpp"

#include <chrono>
#include <csignal>
#include <iomanip>
#include <iostream>
#include <memory>
#include <sstream>
#include <string_view>

namespace pointillist {
namespace {

bool asksForHelp(int argc, char** argv) {
  for (int i = 1; i < argc; ++i) {
    const std::string_view argument = argv[i];
    if (argument == "--help" || argument == "-h") return true;
  }
  return false;
}

}  // namespace

void addCommonRoleOptions(CLI::App& app, CommonRoleOptions& options) {
  app.allow_extras();
  app.add_option("--expect-layout", options.expectLayout,
                 "Role counts D,T,S,R the launcher started; checked at handshake");
  // Hidden: lets tests start a job whose processes disagree on the protocol.
  app.add_option("--protocol-version", options.protocolVersion)->group("");
  app.add_option("--handshake-timeout", options.handshakeTimeoutSeconds,
                 "Seconds to wait for every process to report in");
  app.add_option("--die-role", options.dieRole)->group("");
  app.add_option("--die-index", options.dieIndex)->group("");
  app.add_option("--die-after", options.dieAfter)->group("");
}

SelfKill::SelfKill(const CommonRoleOptions& options, const Job& job) {
  if (options.dieAfter > 0 && options.dieRole == roleName(job.role()) &&
      options.dieIndex == job.indexInRole()) {
    after_ = options.dieAfter;
  }
}

void SelfKill::count() {
  if (after_ > 0 && ++seen_ == after_) {
    const auto now = std::chrono::system_clock::now().time_since_epoch();
    std::cerr << "test hook: " << seen_ << " events, killing this process at " << std::fixed
              << std::setprecision(3) << std::chrono::duration<double>(now).count()
              << " s since the epoch\n"
              << std::flush;
    std::raise(SIGKILL);
  }
}

HandshakeOptions handshakeOptions(const CommonRoleOptions& options) {
  HandshakeOptions handshake;
  handshake.protocolVersion = options.protocolVersion;
  if (!options.expectLayout.empty()) {
    handshake.expectedLayout = JobLayout::parse(options.expectLayout);
  }
  handshake.timeout =
      std::chrono::milliseconds(static_cast<long>(options.handshakeTimeoutSeconds * 1000.0));
  return handshake;
}

int runRoleMain(int argc, char** argv, v1::Role role, CLI::App& app,
                const std::function<int(Job&)>& body) {
  app.name(executableName(role));
  if (asksForHelp(argc, argv)) {
    std::cout << app.help();
    return 0;
  }
  std::unique_ptr<Job> job;
  const auto report = [&](const char* kind, const std::string& message) {
    std::ostringstream line;
    line << executableName(role);
    if (job) line << " rank " << job->worldRank();
    line << ": " << kind << ": " << message << '\n';
    std::cerr << line.str() << std::flush;
  };
  try {
    job = std::make_unique<Job>(argc, argv, role);
    try {
      app.parse(argc, argv);
    } catch (const CLI::ParseError& error) {
      throw UsageError(error.what());
    }
    const int code = body(*job);
    job->finalize();
    return code;
  } catch (const CoordinatedError& error) {
    report(error.kind(), error.what());
    if (job) {
      job->finalize();
    } else {
      int finalized = 0;
      MPI_Finalized(&finalized);
      if (finalized == 0) MPI_Finalize();
    }
    return 3;
  } catch (const Error& error) {
    report(error.kind(), error.what());
  } catch (const std::exception& error) {
    report("unexpected error", error.what());
  }
  // Peers may be waiting on this process: end the whole job.
  int initialized = 0;
  MPI_Initialized(&initialized);
  int finalized = 0;
  MPI_Finalized(&finalized);
  if (initialized != 0 && finalized == 0) MPI_Abort(MPI_COMM_WORLD, 2);
  return 2;
}

}  // namespace pointillist
