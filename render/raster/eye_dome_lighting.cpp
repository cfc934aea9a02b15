#include "render/raster/eye_dome_lighting.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstddef>
#include <limits>

#include "common/errors.hpp"

// Highway compiles the SIMD part once per target by including this file again.
#undef HWY_TARGET_INCLUDE
#define HWY_TARGET_INCLUDE "render/raster/eye_dome_lighting.cpp"
#include <hwy/foreach_target.h>  // IWYU pragma: keep
// foreach_target.h must come first.
#include <hwy/highway.h>

// Every lane computes with the same IEEE operations in the same order (no
// fused multiply-add: the library is built with -ffp-contract=off), and the
// ends of rows go through the same code with one-lane vectors, so a pixel's
// result depends neither on the target nor on where it falls in a vector.
HWY_BEFORE_NAMESPACE();
namespace pointillist::render {
namespace HWY_NAMESPACE {
namespace hn = hwy::HWY_NAMESPACE;

constexpr float kInfinity = std::numeric_limits<float>::infinity();
constexpr float kLog2e = 1.44269504088896340736f;
constexpr float kLn2 = 0.693147180559945309417f;
constexpr float kSqrt2 = 1.41421356237309504880f;

// log2 of each lane's depth, +infinity where nothing was drawn: the exponent
// plus ln(m) / ln 2 for the mantissa m in [sqrt(1/2), sqrt(2)], from the
// series ln m = 2 atanh(s) = 2 (s + s^3/3 + ... + s^9/9), s = (m - 1) / (m + 1),
// |s| <= 0.172 (truncation below 1e-9).
template <class D>
HWY_INLINE void LogDepthLanes(D df, const float* depth, float* out) {
  const hn::RebindToSigned<D> di;
  const hn::RebindToUnsigned<D> du;
  const auto z = hn::LoadU(df, depth);
  const auto bits = hn::BitCast(du, z);
  auto exponent = hn::Sub(hn::BitCast(di, hn::ShiftRight<23>(bits)), hn::Set(di, 127));
  auto m =
      hn::BitCast(df, hn::Or(hn::And(bits, hn::Set(du, 0x007fffffu)), hn::Set(du, 0x3f800000u)));
  const auto big = hn::Gt(m, hn::Set(df, kSqrt2));
  m = hn::IfThenElse(big, hn::Mul(m, hn::Set(df, 0.5f)), m);
  exponent = hn::IfThenElse(hn::RebindMask(di, big), hn::Add(exponent, hn::Set(di, 1)), exponent);
  const auto one = hn::Set(df, 1.0f);
  const auto s = hn::Div(hn::Sub(m, one), hn::Add(m, one));
  const auto s2 = hn::Mul(s, s);
  auto series = hn::Set(df, 2.0f / 9.0f);
  series = hn::Add(hn::Set(df, 2.0f / 7.0f), hn::Mul(s2, series));
  series = hn::Add(hn::Set(df, 2.0f / 5.0f), hn::Mul(s2, series));
  series = hn::Add(hn::Set(df, 2.0f / 3.0f), hn::Mul(s2, series));
  series = hn::Add(hn::Set(df, 2.0f), hn::Mul(s2, series));
  series = hn::Mul(s, series);
  const auto log2 = hn::Add(hn::ConvertTo(df, exponent), hn::Mul(series, hn::Set(df, kLog2e)));
  const auto infinity = hn::Set(df, kInfinity);
  const auto drawn =
      hn::And(hn::Ge(z, hn::Set(df, std::numeric_limits<float>::min())), hn::Lt(z, infinity));
  hn::StoreU(hn::IfThenElse(drawn, log2, infinity), df, out);
}

void LogDepthRow(const float* depth, std::size_t count, float* out) {
  const hn::ScalableTag<float> df;
  const hn::CappedTag<float, 1> d1;
  const std::size_t lanes = hn::Lanes(df);
  std::size_t x = 0;
  for (; x + lanes <= count; x += lanes) LogDepthLanes(df, depth + x, out + x);
  for (; x < count; ++x) LogDepthLanes(d1, depth + x, out + x);
}

// Shades the lanes' pixels: `centre` points into the padded log2-depth
// buffer, `neighbours` are offsets in it. shade = 2^t, t = factor * sum of
// the steps: 2^floor(t) exactly times e^u, u = (t - floor(t)) ln 2 in
// [0, ln 2), from its Taylor series (relative error below 2e-6); t is kept
// above -64, where no 8-bit channel shows anything anyway.
template <class D>
HWY_INLINE void ShadeLanes(D df, const float* centre, const std::ptrdiff_t* neighbours,
                           float factor, const std::uint8_t* source, std::uint8_t* target) {
  const hn::RebindToSigned<D> di;
  const hn::RebindToUnsigned<D> du;
  const auto zero = hn::Zero(df);
  const auto infinity = hn::Set(df, kInfinity);
  const auto step = hn::Set(df, kEdlBackgroundStep);
  const auto here = hn::LoadU(df, centre);
  auto sum = zero;
  for (std::size_t k = 0; k < 8; ++k) {
    const auto other = hn::LoadU(df, centre + neighbours[k]);
    sum = hn::Add(
        sum, hn::IfThenElse(hn::Eq(other, infinity), step, hn::Max(zero, hn::Sub(here, other))));
  }
  // Nothing drawn here: t = 0, shade 1, the background stays.
  sum = hn::IfThenElseZero(hn::Lt(here, infinity), sum);
  const auto t = hn::Max(hn::Mul(hn::Set(df, factor), sum), hn::Set(df, -64.0f));
  const auto whole = hn::Floor(t);
  const auto u = hn::Mul(hn::Sub(t, whole), hn::Set(df, kLn2));
  auto fraction = hn::Set(df, 1.0f / 5040.0f);
  for (const float coefficient :
       {1.0f / 720.0f, 1.0f / 120.0f, 1.0f / 24.0f, 1.0f / 6.0f, 1.0f / 2.0f, 1.0f, 1.0f}) {
    fraction = hn::Add(hn::Set(df, coefficient), hn::Mul(u, fraction));
  }
  const auto scale =
      hn::BitCast(df, hn::ShiftLeft<23>(hn::Add(hn::ConvertTo(di, whole), hn::Set(di, 127))));
  const auto shade = hn::Mul(fraction, scale);

  const auto pixels = hn::LoadU(du, reinterpret_cast<const std::uint32_t*>(source));
  const auto byte = hn::Set(du, 0xFFu);
  const auto half = hn::Set(df, 0.5f);
  const auto channel = [&](auto value) {
    const auto shaded = hn::Add(hn::Mul(hn::ConvertTo(df, hn::BitCast(di, value)), shade), half);
    return hn::BitCast(du, hn::ConvertTo(di, shaded));
  };
  const auto red = channel(hn::And(pixels, byte));
  const auto green = channel(hn::And(hn::ShiftRight<8>(pixels), byte));
  const auto blue = channel(hn::And(hn::ShiftRight<16>(pixels), byte));
  const auto shaded =
      hn::Or(hn::Or(red, hn::ShiftLeft<8>(green)),
             hn::Or(hn::ShiftLeft<16>(blue), hn::And(pixels, hn::Set(du, 0xFF000000u))));
  hn::StoreU(shaded, du, reinterpret_cast<std::uint32_t*>(target));
}

void ShadeRow(const float* centre, std::size_t count, const std::ptrdiff_t* neighbours,
              float factor, const std::uint8_t* source, std::uint8_t* target) {
  const hn::ScalableTag<float> df;
  const hn::CappedTag<float, 1> d1;
  const std::size_t lanes = hn::Lanes(df);
  std::size_t x = 0;
  for (; x + lanes <= count; x += lanes) {
    ShadeLanes(df, centre + x, neighbours, factor, source + 4 * x, target + 4 * x);
  }
  for (; x < count; ++x) {
    ShadeLanes(d1, centre + x, neighbours, factor, source + 4 * x, target + 4 * x);
  }
}

}  // namespace HWY_NAMESPACE
}  // namespace pointillist::render
HWY_AFTER_NAMESPACE();

#if HWY_ONCE
namespace pointillist::render {

HWY_EXPORT(LogDepthRow);
HWY_EXPORT(ShadeRow);

namespace {

bool rectInside(const TileRect& inner, const TileRect& outer) {
  return inner.x() >= outer.x() && inner.y() >= outer.y() &&
         std::uint64_t{inner.x()} + inner.width() <= std::uint64_t{outer.x()} + outer.width() &&
         std::uint64_t{inner.y()} + inner.height() <= std::uint64_t{outer.y()} + outer.height();
}

std::string rectText(const TileRect& rect) {
  return std::to_string(rect.width()) + "x" + std::to_string(rect.height()) + "+" +
         std::to_string(rect.x()) + "+" + std::to_string(rect.y());
}

}  // namespace

TileRect edlInputRect(const TileRect& output, std::uint32_t frameWidth, std::uint32_t frameHeight,
                      float radius) {
  const std::uint32_t halo = edlHaloPixels(radius);
  const std::uint32_t x0 = output.x() > halo ? output.x() - halo : 0;
  const std::uint32_t y0 = output.y() > halo ? output.y() - halo : 0;
  const auto x1 = static_cast<std::uint32_t>(
      std::min<std::uint64_t>(std::uint64_t{output.x()} + output.width() + halo, frameWidth));
  const auto y1 = static_cast<std::uint32_t>(
      std::min<std::uint64_t>(std::uint64_t{output.y()} + output.height() + halo, frameHeight));
  return makeTileRect(x0, y0, x1 > x0 ? x1 - x0 : 0, y1 > y0 ? y1 - y0 : 0);
}

std::vector<std::pair<std::int32_t, std::int32_t>> edlOffsets(float radius) {
  // Rounded in double from exact constants (no cos/sin): the same everywhere.
  const auto axial = static_cast<std::int32_t>(std::lround(static_cast<double>(radius)));
  const auto diagonal =
      static_cast<std::int32_t>(std::lround(static_cast<double>(radius) * 0.70710678118654752440));
  return {{axial, 0},  {diagonal, diagonal},   {0, axial},  {-diagonal, diagonal},
          {-axial, 0}, {-diagonal, -diagonal}, {0, -axial}, {diagonal, -diagonal}};
}

void eyeDomeLighting(const EdlImage& input, const TileRect& output, float strength, float radius,
                     std::span<std::uint8_t> out) {
  std::vector<float> scratch;
  eyeDomeLighting(input, output, strength, radius, out, scratch);
}

void eyeDomeLighting(const EdlImage& input, const TileRect& output, float strength, float radius,
                     std::span<std::uint8_t> out, std::vector<float>& scratch) {
  checkEdl(v1::RENDER_MODE_POINTS, strength, radius);
  const TileRect frame = makeTileRect(0, 0, input.frameWidth, input.frameHeight);
  const TileRect& in = input.rect;
  const std::size_t inPixels = std::size_t{in.width()} * in.height();
  if (in.width() == 0 || in.height() == 0 || !rectInside(in, frame)) {
    throw UsageError("eyeDomeLighting: input " + rectText(in) + " is empty or outside the " +
                     std::to_string(input.frameWidth) + "x" + std::to_string(input.frameHeight) +
                     " frame");
  }
  if (input.rgba.size() != inPixels * 4 || input.depth.size() != inPixels) {
    throw UsageError("eyeDomeLighting: input " + rectText(in) + " has " +
                     std::to_string(input.rgba.size()) + " colour bytes and " +
                     std::to_string(input.depth.size()) + " depths");
  }
  if (output.width() == 0 || output.height() == 0 ||
      !rectInside(edlInputRect(output, input.frameWidth, input.frameHeight, radius), in)) {
    throw UsageError("eyeDomeLighting: output " + rectText(output) +
                     " with its halo is empty or not inside the input " + rectText(in));
  }
  const std::size_t outWidth = output.width();
  if (out.size() != outWidth * output.height() * 4) {
    throw UsageError("eyeDomeLighting: " + std::to_string(out.size()) + " bytes for output " +
                     rectText(output));
  }

  // log2 depth once per pixel, in a buffer padded by the halo with
  // "nothing drawn" (what lies beyond the input lies beyond the frame), so
  // neighbours need no bounds checks.
  const std::uint32_t halo = edlHaloPixels(radius);
  const std::size_t stride = std::size_t{in.width()} + 2 * halo;
  constexpr float kNothing = std::numeric_limits<float>::infinity();
  std::vector<float>& logDepth = scratch;
  logDepth.resize(stride * (std::size_t{in.height()} + 2 * halo));
  std::fill_n(logDepth.begin(), stride * halo, kNothing);
  std::fill(logDepth.end() - static_cast<std::ptrdiff_t>(stride * halo), logDepth.end(), kNothing);
  for (std::uint32_t y = 0; y < in.height(); ++y) {
    float* row = logDepth.data() + (std::size_t{y} + halo) * stride;
    std::fill_n(row, halo, kNothing);
    std::fill_n(row + halo + in.width(), halo, kNothing);
    HWY_DYNAMIC_DISPATCH(LogDepthRow)
    (input.depth.data() + std::size_t{y} * in.width(), in.width(), row + halo);
  }
  std::ptrdiff_t neighbours[8];
  const auto offsets = edlOffsets(radius);
  for (std::size_t k = 0; k < 8; ++k) {
    neighbours[k] =
        static_cast<std::ptrdiff_t>(offsets[k].second) * static_cast<std::ptrdiff_t>(stride) +
        offsets[k].first;
  }
  // shade = exp(-strength * scale * sum / 8) = 2^(factor * sum)
  constexpr float kLog2e = 1.44269504088896340736f;
  const float factor = -strength * kEdlResponseScale / 8.0f * kLog2e;

  const std::uint32_t dx = output.x() - in.x(), dy = output.y() - in.y();
  for (std::uint32_t y = 0; y < output.height(); ++y) {
    HWY_DYNAMIC_DISPATCH(ShadeRow)
    (logDepth.data() + (std::size_t{y} + dy + halo) * stride + halo + dx, outWidth, neighbours,
     factor, input.rgba.data() + ((std::size_t{y} + dy) * in.width() + dx) * 4,
     out.data() + std::size_t{y} * outWidth * 4);
  }
}

EdlTileRenderer::EdlTileRenderer(std::unique_ptr<TileRenderer> inner) : inner_(std::move(inner)) {
  if (!inner_) throw UsageError("EdlTileRenderer: no renderer to wrap");
}

RenderStats EdlTileRenderer::render(const Camera& camera, const TileRect& rect,
                                    std::span<const DrawRange> ranges,
                                    const RenderSettings& settings) {
  shaded_ = false;
  if (!settings.edl.enabled) return inner_->render(camera, rect, ranges, settings);
  checkEdl(splatModeToProto(settings.mode), settings.edl.strength, settings.edl.radius);
  validateCamera(camera);
  if (!tileInsideFrame(camera, rect)) {
    throw UsageError("EdlTileRenderer::render: tile rectangle is empty or outside the image");
  }
  const TileRect grown =
      edlInputRect(rect, camera.image_width(), camera.image_height(), settings.edl.radius);
  RenderSettings drawing = settings;
  drawing.edl.enabled = false;
  drawing.keepDepth = true;
  RenderStats stats = inner_->render(camera, grown, ranges, drawing);

  const auto start = std::chrono::steady_clock::now();
  const std::size_t width = rect.width(), height = rect.height();
  pixels_.resize(width * height * 4);
  const EdlImage image{inner_->pixels(), inner_->depths(), grown, camera.image_width(),
                       camera.image_height()};
  eyeDomeLighting(image, rect, settings.edl.strength, settings.edl.radius, pixels_, scratch_);
  if (!settings.keepDepth) {
    depths_.clear();
  } else {
    const std::size_t dx = rect.x() - grown.x(), dy = rect.y() - grown.y();
    depths_.resize(width * height);
    for (std::size_t y = 0; y < height; ++y) {
      const float* source = image.depth.data() + (y + dy) * grown.width() + dx;
      std::copy(source, source + width, depths_.data() + y * width);
    }
  }
  shaded_ = true;
  stats.seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return stats;
}

}  // namespace pointillist::render
#endif  // HWY_ONCE
