#pragma once
// The single-process oracle: the same traversal (level of detail, culling) and
// the same renderer as the distributed job (GL or the CPU point kernel), over
// the whole frame at once. Frames the job composes from tiles are compared
// against these.
#include <cstdint>
#include <memory>
#include <optional>

#include "common/camera.hpp"
#include "common/dataset.hpp"
#include "common/image.hpp"
#include "render/gl/offscreen_context.hpp"
#include "render/raster/tile_renderer.hpp"
#include "traverse/core/octree_traversal.hpp"

namespace pointillist::render {

struct ReferenceFrame {
  Image image;  // RGBA8, rows bottom-up, background (0,0,0,255)
  std::uint64_t splats = 0;
  double traverseSeconds = 0.0;
  double renderSeconds = 0.0;
};

class ReferenceRenderer {
 public:
  // The dataset must have its points loaded (DatasetParts::All); every
  // packet is uploaded once. `kind` is resolved (Gl or Cpu);
  // `cpuThreads` draw each frame of the CPU renderer.
  ReferenceRenderer(const Dataset& dataset, v1::Renderer kind,
                    GlProfile profile = GlProfile::Compatibility, unsigned cpuThreads = 1);

  ReferenceFrame render(const Camera& camera, const traverse::TraversalSettings& traversal,
                        const RenderSettings& settings);
  const TileRenderer& renderer() const { return *renderer_; }

 private:
  const Dataset& dataset_;
  std::unique_ptr<TileRenderer> renderer_;
  std::optional<traverse::CullingTable> culling_;  // for the last size scale asked for
};

}  // namespace pointillist::render
