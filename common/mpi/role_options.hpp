#pragma once
// Options every role executable accepts; run.sh passes one argument list to all
// roles, so each role ignores options meant for the others.
#include <CLI/CLI.hpp>

#include <string>

#include "common/mpi/job.hpp"

namespace pointillist {

struct CommonRoleOptions {
  std::string expectLayout;  // D,T,S,R as launched; checked in the handshake
  std::uint32_t protocolVersion = v1::PROTOCOL_VERSION_CURRENT;
  double handshakeTimeoutSeconds = 60.0;
};

void addCommonRoleOptions(CLI::App& app, CommonRoleOptions& options);
HandshakeOptions handshakeOptions(const CommonRoleOptions& options);
// Parses argv; returns false (after printing help on rank 0) when the process
// should exit without error. Throws UsageError for bad options.
bool parseRoleOptions(CLI::App& app, Job& job, int argc, char** argv);

}  // namespace pointillist
