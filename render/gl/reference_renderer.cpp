#include "render/gl/reference_renderer.hpp"

#include <chrono>

#include "render/gl/tile_renderers.hpp"

namespace pointillist::render {

ReferenceRenderer::ReferenceRenderer(const Dataset& dataset, v1::Renderer kind, GlProfile profile,
                                     unsigned cpuThreads)
    : dataset_(dataset), renderer_(makeTileRenderer(kind, profile, cpuThreads)) {
  // Statistical packets too (ids after the top-level cells), as render processes hold them.
  if (dataset.hasStatistical())
    renderer_->setStatisticalClasses(
        std::make_shared<const ClassTables>(dataset.readStatisticalClasses()));
  for (std::uint32_t cell = 0; cell < dataset.packetCount(); ++cell) {
    renderer_->uploadCell(cell, dataset.packet(cell));
  }
}

ReferenceFrame ReferenceRenderer::render(const Camera& camera,
                                         const traverse::TraversalSettings& traversal,
                                         const RenderSettings& settings) {
  using Clock = std::chrono::steady_clock;
  // Made once per run, as a traverse process makes it before the first frame.
  if (!culling_ || culling_->sizeScale() != traversal.sizeScale) {
    culling_.emplace(dataset_.cells(), traversal.sizeScale);
  }
  const auto start = Clock::now();
  const TileRect frame = fullFrameRect(camera);
  const auto result = traverse::traverseTile(*culling_, camera, frame, traversal);
  const auto traversed = Clock::now();

  std::vector<DrawRange> ranges;
  ranges.reserve(result.ranges.size());
  for (const auto& range : result.ranges) {
    ranges.push_back({range.topLevel, range.offset, range.count, range.section});
  }
  RenderSettings frameSettings = settings;
  frameSettings.sizeScale = traversal.sizeScale;
  const RenderStats stats = renderer_->render(camera, frame, ranges, frameSettings);

  ReferenceFrame out;
  out.image = Image(camera.image_width(), camera.image_height(), renderer_->pixels());
  out.splats = stats.splats;
  out.traverseSeconds = std::chrono::duration<double>(traversed - start).count();
  out.renderSeconds = stats.seconds;
  return out;
}

}  // namespace pointillist::render
