#pragma once
// The traverse process: loads only the octree-cell-array, walks each tile the
// display hands it and lets the PacketPlanner decide where the packet goes.

namespace pointillist::traverse {

// The executable's main: options, handshake, ready, work until shutdown.
int runTraverseMain(int argc, char** argv);

}  // namespace pointillist::traverse
