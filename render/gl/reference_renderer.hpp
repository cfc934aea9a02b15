#pragma once
// The single-process oracle: the same traversal (level of detail, culling) and
// the same renderer as the distributed job, over the whole frame at once.
// Frames the job composes from tiles are compared against these.
#include <cstdint>

#include "common/camera.hpp"
#include "common/dataset.hpp"
#include "common/image.hpp"
#include "render/gl/splat_renderer.hpp"
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
  // top-level cell is uploaded once.
  ReferenceRenderer(const Dataset& dataset, GlProfile profile = GlProfile::Compatibility);

  ReferenceFrame render(const Camera& camera, const traverse::TraversalSettings& traversal,
                        SplatMode mode);

 private:
  const Dataset& dataset_;
  OffscreenContext context_;
  SplatRenderer renderer_;
};

}  // namespace pointillist::render
