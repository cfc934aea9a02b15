#pragma once
// What a render process draws with: one tile of one camera from ranges of
// cached top-level cells. Two renderers implement it:
//   gl   SplatRenderer (render/gl/): OSMesa/llvmpipe, every mode;
//   cpu  CpuPointRenderer (render/raster/): a point kernel on the CPU, points
//        mode only, several times llvmpipe's rate.
// Tiles are drawn in full-frame pixel coordinates, so a tile equals the same
// rectangle of a whole-frame render by the same renderer (common/camera.hpp).
#include <array>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <string>

#include "common/camera.hpp"
#include "common/run_settings.hpp"
#include "common/splat.hpp"
#include "common/statistical_node.hpp"

namespace pointillist::render {

// Instanced: the points of Points, and instanced sections (seed 000) drawn
// with instancing where a range says so (DrawRange::section).
// Statistical: seed 004's PCA nodes, points generated on the GPU; every range
// is a range of node indices of a cell holding a statistical packet (GL only).
enum class SplatMode { Points, Splats, Blended, Instanced, Statistical };
const char* splatModeName(SplatMode mode);
// "points" | "splats" | "blended" | "instanced" | "statistical"; UsageError
// otherwise.
SplatMode parseSplatMode(const std::string& name);
// RENDER_MODE_POINTS -> Points, _SPLATS -> Splats, _BLENDED -> Blended,
// _INSTANCED -> Instanced, _STATISTICAL -> Statistical; UsageError otherwise.
SplatMode splatModeFromProto(v1::RenderMode mode);
v1::RenderMode splatModeToProto(SplatMode mode);

// Eye-dome lighting (render/raster/eye_dome_lighting.hpp): the renderers
// makeTileRenderer returns draw the tile with a halo and shade it.
struct EdlSettings {
  bool enabled = false;
  float strength = kDefaultEdlStrength;
  float radius = kDefaultEdlRadius;  // pixels
};

struct RenderSettings {
  SplatMode mode = SplatMode::Points;
  std::array<float, 4> clearColor{0.0f, 0.0f, 0.0f, 1.0f};
  // Points: > 0 draws every point this many pixels wide (rounded); 0 uses the
  // projected diameter 2 * radius * sizeScale, rounded, in [1, maxPointSize].
  float pointSize = 0.0f;
  float maxPointSize = 64.0f;
  // Multiplies splat radii (RenderPacket.point_size_scale; 0 counts as 1).
  float sizeScale = 1.0f;
  // Splats: on-screen radius never below this (distant splats do not vanish
  // between pixel centres; 0.71 px always reaches one centre).
  float minPixelRadius = 0.75f;
  // Headlight diffuse + ambient from the splat normals (points and splats);
  // splats without a normal keep their colour.
  bool lighting = true;
  float ambient = 0.3f;
  // Blended: splats this many of their radii behind the visible surface still
  // blend into it; farther ones are hidden.
  float blendDepthRadii = 1.0f;
  EdlSettings edl;
  // Also keep each pixel's eye-space depth (TileRenderer::depths); points and
  // splats only.
  bool keepDepth = false;
};

// Window depth d in [0, 1] (glDepthRange(0, 1) of the camera's projection)
// to eye-space depth (distance along the view axis, near to far):
// z = f n / (f - d (f - n)), in float (the depth buffer's own resolution,
// 2^-24 near 1, is what limits it).
struct DepthLinearizer {
  explicit DepthLinearizer(const Camera& camera);
  float operator()(float windowDepth) const { return numerator / (farPlane - windowDepth * range); }

  float numerator = 1.0f;  // f n
  float farPlane = 1.0f;   // f
  float range = 0.0f;      // f - n
};

struct DrawRange {
  std::uint32_t cell = 0;    // id given to uploadCell
  std::uint32_t offset = 0;  // in splats, from the start of the cell
  std::uint32_t count = 0;   // (SplatMode::Statistical: offset and count in nodes)
  // The range is an instancing unit's section (its records; count is the
  // section's record count): SplatMode::Instanced on GL only.
  bool section = false;
};

struct RenderStats {
  std::uint64_t splats = 0;     // vertices submitted (statistical: points generated)
  std::uint32_t drawCalls = 0;  // glMultiDrawArrays calls (one per cell)
  double seconds = 0.0;         // clear to glFinish
};
class TileRenderer {
 public:
  virtual ~TileRenderer() = default;

  // Keeps a cell's splats under `id` (replacing any previous ones); the span
  // need not stay alive afterwards.
  virtual void uploadCell(std::uint32_t id, std::span<const Splat> splats) = 0;
  // Writes `splats` as splats [first, first + splats.size()) of cell `id`:
  // ranges of a packet arrive in any order, and a renderer draws only those
  // its process holds (what lies between them is never drawn). An unknown id
  // starts a new cell. `room` (at least first + splats.size()) is the
  // cell's extent once the data packet at hand is stored: its parts of one
  // cell come one by one, and room for all of them saves copies.
  virtual void writeToCell(std::uint32_t id, std::uint32_t first, std::span<const Splat> splats,
                           std::size_t room) = 0;
  // Cell `id` drawn in place from `count` splats of a block in the CPU point
  // kernel's layout (common/point_groups.hpp) held elsewhere, which outlives
  // its use here (a data-send's shared memory). False: this renderer cannot,
  // and takes the splats through uploadCell / writeToCell instead.
  virtual bool viewCell(std::uint32_t id, const float* groups, std::size_t count, bool hasNormals) {
    (void)id, (void)groups, (void)count, (void)hasNormals;
    return false;
  }
  // Whether viewCell takes cells (so the splats need not be written).
  virtual bool viewsInPlace() const { return false; }
  virtual void releaseCell(std::uint32_t id) = 0;  // no-op for unknown ids
  // Calls `visit` with every cell kept and its splats as uploaded, so another
  // renderer can take them over (a served frame asks for a mode this one
  // cannot draw). The span lives for the call only.
  using CellVisitor = std::function<void(std::uint32_t id, std::span<const Splat> splats)>;
  virtual void forEachCell(const CellVisitor& visit) const = 0;
  // Draws the ranges into the tile `rect` of `camera`'s frame; afterwards
  // pixels() holds it. Throws UsageError for an invalid camera, a rect outside
  // the image, a range outside its cell or an unknown cell.
  virtual RenderStats render(const Camera& camera, const TileRect& rect,
                             std::span<const DrawRange> ranges, const RenderSettings& settings) = 0;
  // The last tile: RGBA8, rows bottom-up, rect.width x rect.height.
  virtual std::span<const std::uint8_t> pixels() const = 0;
  // With settings.keepDepth, the last tile's eye-space depth per pixel (as
  // pixels()), +infinity where nothing was drawn; otherwise empty.
  virtual std::span<const float> depths() const = 0;
  // The cpu point kernel's packed word per pixel of the last tile (as
  // pixels()), for a part of a split tile the display composes by the
  // minimum; empty for renderers that draw otherwise.
  virtual std::span<const std::uint64_t> pointWords() const { return {}; }
  // Whatever the first draw would pay once (shader compilation), paid now.
  virtual void warmUp(const RenderSettings& settings) = 0;
  virtual std::string describe() const = 0;
  // The dataset's class tables, for renderers that draw the statistical mode
  // (they decode its packets); the others ignore them.
  virtual void setStatisticalClasses(std::shared_ptr<const ClassTables> classes) { (void)classes; }
};

}  // namespace pointillist::render
