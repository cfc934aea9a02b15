#include "render/gl/tile_renderers.hpp"

#include "common/errors.hpp"
#include "render/gl/splat_renderer.hpp"
#include "render/raster/cpu_point_renderer.hpp"
#include "render/raster/eye_dome_lighting.hpp"

namespace pointillist::render {
namespace {

// A SplatRenderer with the context it draws into.
class GlTileRenderer final : public TileRenderer {
 public:
  explicit GlTileRenderer(GlProfile profile) : context_(64, 64, profile), renderer_(context_) {}

  void uploadCell(std::uint32_t id, std::span<const Splat> splats) override {
    renderer_.uploadCell(id, splats);
  }
  void writeToCell(std::uint32_t id, std::uint32_t first, std::span<const Splat> splats,
                   std::size_t room) override {
    renderer_.writeToCell(id, first, splats, room);
  }
  void releaseCell(std::uint32_t id) override { renderer_.releaseCell(id); }
  void forEachCell(const CellVisitor& visit) const override { renderer_.forEachCell(visit); }
  RenderStats render(const Camera& camera, const TileRect& rect, std::span<const DrawRange> ranges,
                     const RenderSettings& settings) override {
    return renderer_.render(camera, rect, ranges, settings);
  }
  std::span<const std::uint8_t> pixels() const override { return renderer_.pixels(); }
  std::span<const float> depths() const override { return renderer_.depths(); }
  void warmUp(const RenderSettings& settings) override { renderer_.warmUp(settings); }
  std::string describe() const override { return renderer_.describe(); }
  void setStatisticalClasses(std::shared_ptr<const ClassTables> classes) override {
    renderer_.setStatisticalClasses(std::move(classes));
  }

 private:
  OffscreenContext context_;
  SplatRenderer renderer_;
};

}  // namespace

std::unique_ptr<TileRenderer> makeTileRenderer(v1::Renderer kind, GlProfile profile,
                                               unsigned cpuThreads) {
  switch (kind) {
    case v1::RENDERER_GL:
      return std::make_unique<EdlTileRenderer>(std::make_unique<GlTileRenderer>(profile));
    case v1::RENDERER_CPU:
      return std::make_unique<EdlTileRenderer>(std::make_unique<CpuPointRenderer>(cpuThreads));
    default:
      break;
  }
  throw UsageError("makeTileRenderer: resolve the renderer first (gl or cpu)");
}

}  // namespace pointillist::render
