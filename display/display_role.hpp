#pragma once
#include "common/mpi/job.hpp"

namespace pointillist::display {

// The display process: handshake, wait for every peer to be ready, run the
// frames (or stay idle on request), then shut the job down.
int runDisplayRole(Job& job, int argc, char** argv);

}  // namespace pointillist::display
