#pragma once
// The data-send process: holds the point data of the top-level cells it owns
// and sends whole cells to render processes as the SendLedger decides.

namespace pointillist::datasend {

// The executable's main: options, handshake, ready, work until shutdown.
int runDatasendMain(int argc, char** argv);

}  // namespace pointillist::datasend
