#pragma once
// Makes the renderer a run asked for: the CPU point kernel, or OSMesa with a
// context of its own.
#include <memory>

#include "render/gl/offscreen_context.hpp"
#include "render/raster/tile_renderer.hpp"

namespace pointillist::render {

// `kind` must be resolved (Gl or Cpu: resolveRenderer). `cpuThreads` draw each
// tile of the CPU renderer. The renderer applies settings.edl (EdlTileRenderer).
std::unique_ptr<TileRenderer> makeTileRenderer(v1::Renderer kind, GlProfile profile,
                                               unsigned cpuThreads = 1);

}  // namespace pointillist::render
