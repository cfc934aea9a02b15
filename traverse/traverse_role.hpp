#pragma once
#include "common/mpi/job.hpp"

namespace pointillist::traverse {

// The traverse process's main loop: handshake, ready, work until shutdown.
int runTraverseRole(Job& job, int argc, char** argv);

}  // namespace pointillist::traverse
