#pragma once
#include "common/mpi/job.hpp"

namespace pointillist::render {

// The render process's main loop: handshake, ready, work until shutdown.
int runRenderRole(Job& job, int argc, char** argv);

}  // namespace pointillist::render
