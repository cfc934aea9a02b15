#pragma once
// Eye-dome lighting (Boucheny 2009; the shading CloudCompare and Potree offer
// for scans without normals): a screen-space pass over the depth buffer that
// darkens a pixel by how far its neighbours stand in front of it.
//
// For each drawn pixel p, with z the eye-space depth:
//   response = mean over 8 neighbours q at `radius` pixels (directions k * 45
//              degrees, offsets rounded to whole pixels) of
//              max(0, log2 z_p - log2 z_q);
//   shade    = exp(-strength * 300 * response), which multiplies R, G and B.
// log2 makes the response depend on relative depth steps only, so near and far
// parts of the scene shade alike. A neighbour where nothing was drawn (or
// outside the frame) counts as a step of kEdlBackgroundStep: taken as far away
// it would never darken anything (it is not in front), and silhouettes are
// what shows shape best, so they get a dark rim. Pixels where nothing was
// drawn keep their colour.
//
// A pixel's result depends only on the pixels within edlHaloPixels(radius), so
// a tile shaded from an image of the tile grown by that halo (edlInputRect)
// equals the same rectangle of the whole frame's pass, bit for bit. The pass
// is SIMD (Highway, dispatched at run time) and computes log2 and exp from
// + - * / and floor only, with no fused multiply-add (libm's versions differ
// between CPUs), so every target gives the same bits: a tile shaded on one
// machine equals a frame shaded on another.
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "render/raster/tile_renderer.hpp"

namespace pointillist::render {

// Response scale per unit of log2 depth (Potree's); a background neighbour's
// step in log2 depth (about 0.7 %): one darkens a pixel to 69 %, the three
// beyond a straight silhouette to 32 % (strength 1).
inline constexpr float kEdlResponseScale = 300.0f;
inline constexpr float kEdlBackgroundStep = 0.01f;

// A rectangle of a frame's pixels with their depth.
struct EdlImage {
  std::span<const std::uint8_t> rgba;  // rect.width x rect.height RGBA8, rows bottom-up
  std::span<const float> depth;        // eye-space depth; not finite and > 0: nothing drawn
  TileRect rect;                       // in frame pixels
  std::uint32_t frameWidth = 0;
  std::uint32_t frameHeight = 0;
};

// What to draw to shade `output`: grown by edlHaloPixels(radius) on every
// side, clamped to the frame.
TileRect edlInputRect(const TileRect& output, std::uint32_t frameWidth, std::uint32_t frameHeight,
                      float radius);

// The neighbour offsets (dx, dy) sampled at `radius`.
std::vector<std::pair<std::int32_t, std::int32_t>> edlOffsets(float radius);

// Shades the rectangle `output` of the frame from `input`, which must contain
// edlInputRect(output, ...); writes output.width x output.height RGBA8 pixels,
// rows bottom-up, into `out`. Throws UsageError for a strength or radius out of
// range (checkEdl), sizes that do not match, or rectangles that do not fit.
// `scratch` (resized as needed) saves an allocation per call.
void eyeDomeLighting(const EdlImage& input, const TileRect& output, float strength, float radius,
                     std::span<std::uint8_t> out, std::vector<float>& scratch);
void eyeDomeLighting(const EdlImage& input, const TileRect& output, float strength, float radius,
                     std::span<std::uint8_t> out);

// Applies settings.edl to any renderer: a tile is drawn as edlInputRect(rect)
// with depth, shaded, and cut back to rect. Passes through when edl is off.
// makeTileRenderer wraps every renderer it makes in one.
class EdlTileRenderer final : public TileRenderer {
 public:
  explicit EdlTileRenderer(std::unique_ptr<TileRenderer> inner);

  void uploadCell(std::uint32_t id, std::span<const Splat> splats) override {
    inner_->uploadCell(id, splats);
  }
  void writeToCell(std::uint32_t id, std::uint32_t first, std::span<const Splat> splats,
                   std::size_t room) override {
    inner_->writeToCell(id, first, splats, room);
  }
  bool viewCell(std::uint32_t id, const float* groups, std::size_t count,
                bool hasNormals) override {
    return inner_->viewCell(id, groups, count, hasNormals);
  }
  bool viewsInPlace() const override { return inner_->viewsInPlace(); }
  void releaseCell(std::uint32_t id) override { inner_->releaseCell(id); }
  void forEachCell(const CellVisitor& visit) const override { inner_->forEachCell(visit); }
  // Also throws UsageError for settings.edl out of range or in blended mode.
  RenderStats render(const Camera& camera, const TileRect& rect, std::span<const DrawRange> ranges,
                     const RenderSettings& settings) override;
  std::span<const std::uint8_t> pixels() const override {
    return shaded_ ? std::span<const std::uint8_t>(pixels_) : inner_->pixels();
  }
  std::span<const float> depths() const override {
    return shaded_ ? std::span<const float>(depths_) : inner_->depths();
  }
  // A shaded tile's words would be of the grown rect, before shading: none.
  std::span<const std::uint64_t> pointWords() const override {
    return shaded_ ? std::span<const std::uint64_t>() : inner_->pointWords();
  }
  void warmUp(const RenderSettings& settings) override { inner_->warmUp(settings); }
  std::string describe() const override { return inner_->describe(); }
  void setStatisticalClasses(std::shared_ptr<const ClassTables> classes) override {
    inner_->setStatisticalClasses(std::move(classes));
  }

  TileRenderer& inner() { return *inner_; }

 private:
  std::unique_ptr<TileRenderer> inner_;
  bool shaded_ = false;  // the last tile went through the pass
  std::vector<std::uint8_t> pixels_;
  std::vector<float> depths_;
  std::vector<float> scratch_;
};

}  // namespace pointillist::render
