#include "common/mpi/role_options.hpp"

#include <iostream>

namespace pointillist {

void addCommonRoleOptions(CLI::App& app, CommonRoleOptions& options) {
  app.allow_extras();
  app.add_option("--expect-layout", options.expectLayout,
                 "Role counts D,T,S,R the launcher started; checked at handshake");
  // Hidden: lets tests start a job whose processes disagree on the protocol.
  app.add_option("--protocol-version", options.protocolVersion)->group("");
  app.add_option("--handshake-timeout", options.handshakeTimeoutSeconds,
                 "Seconds to wait for every process to report in");
}

HandshakeOptions handshakeOptions(const CommonRoleOptions& options) {
  HandshakeOptions handshake;
  handshake.protocolVersion = options.protocolVersion;
  if (!options.expectLayout.empty())
    handshake.expectedLayout = JobLayout::parse(options.expectLayout);
  handshake.timeout =
      std::chrono::milliseconds(static_cast<long>(options.handshakeTimeoutSeconds * 1000.0));
  return handshake;
}

bool parseRoleOptions(CLI::App& app, Job& job, int argc, char** argv) {
  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp&) {
    if (job.worldRank() == 0) std::cout << app.help();
    return false;
  } catch (const CLI::ParseError& error) {
    throw UsageError(error.what());
  }
  return true;
}

}  // namespace pointillist
