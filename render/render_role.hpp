#pragma once
// The render process: owns one OSMesa context, lets the RenderCore decide what
// to cache, ask for and draw next, draws with the SplatRenderer and sends each
// tile to the display.

namespace pointillist::render {

// The executable's main: options, handshake, ready, work until shutdown.
int runRenderMain(int argc, char** argv);

}  // namespace pointillist::render
