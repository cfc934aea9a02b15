#pragma once
// The display process: lets the FrameAssembly decide which tiles go out, when
// and where, composes the tiles that come back into frames and writes them.

namespace pointillist::display {

// The executable's main: handshake (sending the run's settings), wait for
// every peer, run the frames (or stay idle on request), shut the job down.
int runDisplayMain(int argc, char** argv);

}  // namespace pointillist::display
