#pragma once
#include "common/mpi/job.hpp"

namespace pointillist::datasend {

// The datasend process's main loop: handshake, ready, work until shutdown.
int runDatasendRole(Job& job, int argc, char** argv);

}  // namespace pointillist::datasend
