#pragma once
// Draws splats into an OffscreenContext for one camera and one tile.
//
// Data: the render process uploads each cached top-level cell once
// (uploadCell) and draws ranges of it per packet (DrawRange = the packet's
// range_top_level / range_offset / range_count); releaseCell on eviction.
//
// Tiles: a tile is drawn with the full frame's projection and the full frame's
// viewport shifted by (-rect.x, -rect.y) into a tile-sized framebuffer. That is
// the tile projection of common/camera.hpp expressed in the viewport, but clip
// coordinates (and so clipping and the shaders' arithmetic) are bit-identical
// to the full frame's; the tile projection as a matrix would clip wide points
// by their centre at tile borders (llvmpipe drops a point whose centre is
// outside the clip volume) and round differently. Shaders work in full-frame
// pixels (points snap to the full-frame pixel grid; splats ray-cast per
// full-frame pixel), so a tile is pixel-identical to the same rectangle of a
// full-frame render provided it is given every splat that touches it (see
// tilePlanes' margin) in the same relative order (ranges are drawn sorted by
// cell, then offset). The viewport also has a 128-pixel guard band around the
// frame so points centred just outside the frame still show their inside part.
//
// Modes:
//  - Points: GL_POINTS, one vertex per splat; size = the splat's projected
//    diameter rounded to whole pixels (or a constant); headlight shading. Fastest with a
//    compatibility-profile context (legacy points; core profile forces point
//    sprites, slower on llvmpipe).
//  - Splats: seed 002's attributed vertex cloud: one vertex per splat, the
//    geometry shader turns it into a screen rectangle bounding the oriented
//    disk, the fragment shader intersects the pixel's ray with the disk plane,
//    discards outside the radius and writes that depth; flat headlight shading.
//  - Instanced: Points, and seed 000's instanced sections where a range is
//    one (DrawRange::section): the section's remainder as points, and per
//    pool one instanced draw straight from the cell's buffer -- its vertex
//    records per vertex, its translations per instance, the tag bit masks
//    tested in the vertex shader.
//  - Statistical: seed 004's PCA nodes (common/statistical_node.hpp): a cell
//    holds a statistical packet and a range is a range of its node indices.
//    The cell's nodes are decoded once (with the class tables given to
//    setStatisticalClasses) and kept until the cell changes. Per tile every
//    node of the ranges gets its point budget (common/statistical_point_table.hpp)
//    for the full frame's camera; the nodes go into one buffer texture in the
//    order (budget, cell, node index) -- a tile draws a subset of the frame's
//    nodes in the frame's relative order -- and each distinct budget n over m
//    nodes is one draw of n * m points: statistical_points.vert takes node
//    v / n and sample v % n of a static buffer of Gaussian samples
//    (common/statistical_samples.hpp) and turns them into a point, drawn as in
//    Points (snapped, headlight) and budget.pointPixels wide. (Node attributes
//    per instance, one instanced draw per budget, ran 10 % slower on
//    llvmpipe: it pays about 0.75 us per instance.)
//  - Blended: the same disks, EWA-style: a depth pass pushed back by
//    blendDepthRadii radii, an additive pass of Gaussian-weighted colours of the
//    splats within that offset of the visible surface (float framebuffer), and
//    a normalization pass into the context's buffer. Smooth, ~2.5x the cost of
//    Splats (RENDER_MODE_BLENDED, --mode blended).
#include <array>
#include <cstdint>
#include <memory>
#include <span>
#include <unordered_map>
#include <vector>

#include "common/camera.hpp"
#include "common/instanced_section.hpp"
#include "common/splat.hpp"
#include "common/statistical_node.hpp"
#include "common/statistical_point_table.hpp"
#include "common/statistical_samples.hpp"
#include "render/gl/offscreen_context.hpp"
#include "render/raster/tile_renderer.hpp"

namespace pointillist::render {

class SplatRenderer final : public TileRenderer {
 public:
  // The context must outlive the renderer and be current when it is used.
  explicit SplatRenderer(OffscreenContext& context);
  ~SplatRenderer() override;
  SplatRenderer(const SplatRenderer&) = delete;
  SplatRenderer& operator=(const SplatRenderer&) = delete;

  // Copies the splats into a GL buffer under `id` (replacing any previous one);
  // the span need not stay alive afterwards. Throws RenderError on GL failure.
  void uploadCell(std::uint32_t id, std::span<const Splat> splats) override;
  // Writes the splats into the cell's buffer at `first`, first growing it to
  // `room` when they do not fit (a new buffer, the held splats copied on the
  // GL side). Throws RenderError on GL failure.
  void writeToCell(std::uint32_t id, std::uint32_t first, std::span<const Splat> splats,
                   std::size_t room) override;
  void releaseCell(std::uint32_t id) override;  // no-op for unknown ids
  void forEachCell(const CellVisitor& visit) const override;
  void releaseAll();
  bool hasCell(std::uint32_t id) const { return cells_.contains(id); }
  std::size_t cellCount() const { return cells_.size(); }
  std::uint32_t cellSplatCount(std::uint32_t id) const;           // 0 for unknown ids
  std::uint64_t uploadedBytes() const { return uploadedBytes_; }  // cached cells only

  // Resizes the context to the tile, clears it, draws the ranges and waits for
  // the result: afterwards context().pixels() holds the tile (RGBA8, rows
  // bottom-up, rect.width x rect.height). Throws UsageError for an invalid
  // camera, a rect outside the image, or a range outside its cell / an unknown
  // cell; RenderError on GL failure.
  RenderStats render(const Camera& camera, const TileRect& rect, std::span<const DrawRange> ranges,
                     const RenderSettings& settings) override;
  std::span<const std::uint8_t> pixels() const override { return context_.pixels(); }
  // Read back from the depth buffer (settings.keepDepth; not in blended mode,
  // whose depth buffer holds the pushed-back depths of its first pass).
  std::span<const float> depths() const override { return depths_; }
  // Compiles and runs the mode's shaders once on a tiny tile, so that the first
  // real packet is not timed with llvmpipe's shader compilation (T_s).
  void warmUp(const RenderSettings& settings) override;
  std::string describe() const override;
  // Draws splats that are not cached (uploaded into a scratch buffer each call).
  RenderStats renderSplats(const Camera& camera, const TileRect& rect,
                           std::span<const Splat> splats, const RenderSettings& settings);

  // Statistical mode: the class tables its cells' packets decode with. Decoded
  // nodes of every cell are dropped (decoded again with these on next use).
  void setStatisticalClasses(std::shared_ptr<const ClassTables> classes) override;
  // Draws statistical nodes that are not cached, in any mode's settings (drawn
  // as SplatMode::Statistical): node i is cell 0's node i, with budgets[i] when
  // budgets are given (counts clamped to the sample buffer), otherwise its
  // budget for `camera`. Throws UsageError when budgets' size is not the nodes'.
  RenderStats renderNodes(const Camera& camera, const TileRect& rect,
                          std::span<const StatisticalNode> nodes, const RenderSettings& settings,
                          std::span<const PointBudget> budgets = {});
  // Replaces the static sample buffer (default: the first
  // kStatisticalMaxSamples Sobol samples), e.g. with pseudo-random samples for
  // pointillist-statistical-table. Throws UsageError when empty.
  void setStatisticalSamples(std::vector<GaussianSample> samples);
  // Whether instanced draws start at a base instance (GL 4.2 /
  // ARB_base_instance) or move the instance attribute pointers instead.

  OffscreenContext& context() { return context_; }

 private:
  struct Programs;
  // What drawing one of a cell's instanced sections needs, read from its
  // buffer once.
  struct Section {
    InstancedHeader header{};
    std::vector<InstancedPool> pools;
  };
  struct Cell {
    unsigned buffer = 0;
    std::uint32_t count = 0;     // splats up to the last one written
    std::uint32_t capacity = 0;  // splats the buffer has room for
    mutable std::unordered_map<std::uint32_t, Section> sections;  // by first record
    // Statistical mode: the packet's nodes, decoded on first use.
    // Decoded statistical nodes; `stale` when more of the packet arrived since
    // (decoding goes on from the last node, common/statistical_node.hpp).
    mutable std::shared_ptr<StatisticalPacketView> statistical;
    mutable bool statisticalStale = false;
  };
  // One statistical node of a frame: what its instance draws and where it
  // sorts.
  struct StatisticalDraw {
    std::uint32_t count = 0;  // samples
    std::uint32_t cell = 0;
    std::uint32_t index = 0;  // node index in the cell
    float pointPixels = 0.0f;
    const StatisticalNode* node = nullptr;
  };

  struct Accumulation {
    unsigned framebuffer = 0, color = 0, depth = 0;
    std::uint32_t width = 0, height = 0;
  };

  void upload(Cell& cell, std::span<const Splat> splats);
  // The section `range` is in `cell`, parsed and checked on first use.
  const Section& section(const Cell& cell, const DrawRange& range) const;
  // The section's pools, instanced (the instanced program is in use).
  void drawPools(const Cell& cell, const DrawRange& range, RenderStats& stats);
  // The cell's decoded statistical nodes (decoded on first use).
  const StatisticalPacketView& statisticalNodes(const Cell& cell, std::uint32_t id) const;
  // Sorted, uploaded and drawn (the statistical program is in use).
  void drawStatistical(std::span<const StatisticalDraw> draws, RenderStats& stats);
  void ensureAccumulation(std::uint32_t width, std::uint32_t height);
  void destroyAccumulation();
  void destroy(Cell& cell);
  unsigned program(SplatMode mode);
  std::uint32_t guardPixels(const Camera& camera) const;
  void setUniforms(unsigned program, const Camera& camera, const TileRect& rect,
                   const RenderSettings& settings);
  RenderStats draw(const Camera& camera, const TileRect& rect,
                   std::span<const std::pair<const Cell*, std::span<const DrawRange>>> groups,
                   const RenderSettings& settings, std::span<StatisticalDraw> statistical = {});

  OffscreenContext& context_;
  std::unique_ptr<Programs> programs_;
  unsigned vertexArray_ = 0;
  std::unordered_map<std::uint32_t, Cell> cells_;
  Cell scratch_;
  Accumulation accumulation_;
  std::uint64_t uploadedBytes_ = 0;
  float maxPointSizeGl_ = 1.0f;
  std::int64_t maxViewport_ = 0;        // GL_MAX_VIEWPORT_DIMS
  std::int64_t viewportBoundsMin_ = 0;  // GL_VIEWPORT_BOUNDS_RANGE[0]
  std::uint32_t drawSerial_ = 0;
  std::vector<float> depths_;
  // Statistical mode.
  std::shared_ptr<const ClassTables> statisticalClasses_;
  std::vector<GaussianSample> samples_;  // uploaded on first use, then emptied
  unsigned sampleBuffer_ = 0;
  std::uint32_t sampleCount_ = 0;
  unsigned instanceBuffer_ = 0;
  std::size_t instanceCapacity_ = 0;  // bytes of instanceBuffer_
  std::vector<float> instanceScratch_;
  std::vector<StatisticalDraw> statisticalDraws_;
  std::vector<StatisticalDraw> statisticalSorted_;
  std::vector<std::uint32_t> statisticalStarts_;
  unsigned nodeTexture_ = 0;    // buffer textures over instanceBuffer_
  unsigned sampleTexture_ = 0;  // and sampleBuffer_
};

}  // namespace pointillist::render
