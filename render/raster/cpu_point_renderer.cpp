#include "render/raster/cpu_point_renderer.hpp"

#include <algorithm>
#include <bit>
#include <chrono>
#include <cmath>
#include <cstring>
#include <limits>
#include <string>
#include <thread>

#include "common/errors.hpp"

// Highway compiles the SIMD part once per target by including this file again.
#undef HWY_TARGET_INCLUDE
#define HWY_TARGET_INCLUDE "render/raster/cpu_point_renderer.cpp"
#include <hwy/foreach_target.h>  // IWYU pragma: keep
// foreach_target.h must come first.
#include <hwy/cache_control.h>
#include <hwy/highway.h>

// The kernel must round exactly as the scalar reference does: explicit Mul
// then Add (never MulAdd; the file is built with -ffp-contract=off), exact Div
// and Sqrt, and selects where the reference branches. Lanes never mix.
HWY_BEFORE_NAMESPACE();
namespace pointillist::render {
namespace HWY_NAMESPACE {
namespace hn = hwy::HWY_NAMESPACE;

using DF = hn::ScalableTag<float>;
using DI = hn::RebindToSigned<DF>;
using DU = hn::RebindToUnsigned<DF>;
using VF = hn::Vec<DF>;
using VI = hn::Vec<DI>;
using VU = hn::Vec<DU>;
using MF = hn::Mask<DF>;

// Calls sink(i, drawn, x0, y0, x1, y1, depth, color) for the vectors of
// splats [i, i + lanes) that cover [from, to); lanes outside it are not drawn.
template <bool kConstantSize, bool kLighting, class Sink>
HWY_INLINE void projectSplats(const PointRaster& r, const PointCell& c, std::size_t from,
                              std::size_t to, Sink& sink) {
  const DF df;
  const DI di;
  const DU du;
  const std::size_t lanes = hn::Lanes(df);
  static_assert(HWY_MAX_BYTES / 4 <= PointCell::kPad, "a vector must fit in a cell's group");
  const float* m = &r.viewProjection[0][0];  // m[4 * column + row]
  const auto entry = [&](int column, int row) { return hn::Set(df, m[4 * column + row]); };
  const VF m00 = entry(0, 0), m10 = entry(1, 0), m20 = entry(2, 0), m30 = entry(3, 0);
  const VF m01 = entry(0, 1), m11 = entry(1, 1), m21 = entry(2, 1), m31 = entry(3, 1);
  const VF m02 = entry(0, 2), m12 = entry(1, 2), m22 = entry(2, 2), m32 = entry(3, 2);
  const VF m03 = entry(0, 3), m13 = entry(1, 3), m23 = entry(2, 3), m33 = entry(3, 3);
  const VF zero = hn::Zero(df), half = hn::Set(df, 0.5f), one = hn::Set(df, 1.0f);
  const VF two = hn::Set(df, 2.0f), minusOne = hn::Set(df, -1.0f);
  const VF frameWidth = hn::Set(df, r.frameWidth), frameHeight = hn::Set(df, r.frameHeight);
  const VF diameterScale = hn::Set(df, r.diameterScale), maxSize = hn::Set(df, r.maxSize);
  const VF tileX = hn::Set(df, static_cast<float>(r.tileX));
  const VF tileY = hn::Set(df, static_cast<float>(r.tileY));
  const VF tileRight = hn::Set(df, static_cast<float>(r.tileX + r.tileWidth));
  const VF tileTop = hn::Set(df, static_cast<float>(r.tileY + r.tileHeight));
  const VI tileXi = hn::Set(di, r.tileX), tileYi = hn::Set(di, r.tileY);
  const VF eyeX = hn::Set(df, r.eye.x), eyeY = hn::Set(df, r.eye.y), eyeZ = hn::Set(df, r.eye.z);
  const VF quarter = hn::Set(df, 0.25f), ambient = hn::Set(df, r.ambient);
  const VF diffuse = hn::Set(df, 1.0f - r.ambient);
  const VU byte = hn::Set(du, 0xFFu), alpha = hn::Set(du, 0xFF000000u);
  const auto clampSize = [&](VF size) {  // std::clamp(floor(size + 0.5), 1, maxSize), NaN kept
    size = hn::Floor(hn::Add(size, half));
    size = hn::IfThenElse(hn::Lt(size, one), one, size);
    return hn::IfThenElse(hn::Lt(maxSize, size), maxSize, size);
  };
  const VF constantSize = clampSize(hn::Set(df, r.constantSize));

  // The fields of splat i onwards, from a base held in a register: the sink's
  // stores could alias the cell's members, and reloading them costs.
  const float* const values = c.values();
  constexpr std::size_t kPad = PointCell::kPad;
  constexpr std::size_t kPrefetchGroups = 4;
  for (std::size_t i = from - from % lanes; i < to; i += lanes) {
    const MF inside = hn::AndNot(hn::FirstN(df, from > i ? from - i : 0),
                                 hn::FirstN(df, std::min(to - i, lanes)));
    const float* const group = values + PointCell::valueIndex(PointCell::kX, i);
    if (i % kPad == 0) {
      // One stream (the cell's groups in order) would be read at the pace
      // the hardware prefetcher keeps for one stream; fetching a few groups
      // ahead keeps a long range as fast as eight field arrays were.
      const float* const ahead = group + kPrefetchGroups * PointCell::kGroupValues;
      for (std::size_t k = 0; k < PointCell::kFields; ++k) hwy::Prefetch(ahead + k * kPad);
    }
    const VF x = hn::Load(df, group);
    const VF y = hn::Load(df, group + PointCell::kY * kPad);
    const VF z = hn::Load(df, group + PointCell::kZ * kPad);
    const VF cw = hn::Add(hn::Add(hn::Add(hn::Mul(m03, x), hn::Mul(m13, y)), hn::Mul(m23, z)), m33);
    MF drawn = hn::And(inside, hn::Gt(cw, zero));  // not behind the eye
    const VF inverse = hn::Div(one, cw);
    const VF nz = hn::Mul(
        hn::Add(hn::Add(hn::Add(hn::Mul(m02, x), hn::Mul(m12, y)), hn::Mul(m22, z)), m32), inverse);
    drawn = hn::And(drawn, hn::And(hn::Ge(nz, minusOne), hn::Le(nz, one)));
    const VF nx = hn::Mul(
        hn::Add(hn::Add(hn::Add(hn::Mul(m00, x), hn::Mul(m10, y)), hn::Mul(m20, z)), m30), inverse);
    const VF ny = hn::Mul(
        hn::Add(hn::Add(hn::Add(hn::Mul(m01, x), hn::Mul(m11, y)), hn::Mul(m21, z)), m31), inverse);
    VF size = constantSize;
    if constexpr (!kConstantSize) {
      size = clampSize(hn::Mul(
          hn::Mul(hn::Load(df, group + PointCell::kRadius * kPad), diameterScale), inverse));
    }
    const VF wx = hn::Mul(hn::Add(hn::Mul(nx, half), half), frameWidth);
    const VF wy = hn::Mul(hn::Add(hn::Mul(ny, half), half), frameHeight);
    // fmod(size, 2) == 1 for the whole numbers (or NaN, inf) that size holds.
    const MF odd = hn::Eq(hn::Sub(size, hn::Mul(two, hn::Floor(hn::Mul(size, half)))), one);
    const VF sx = hn::IfThenElse(odd, hn::Add(hn::Floor(wx), half), hn::Floor(hn::Add(wx, half)));
    const VF sy = hn::IfThenElse(odd, hn::Add(hn::Floor(wy), half), hn::Floor(hn::Add(wy, half)));
    const VF halfSize = hn::Mul(half, size);
    const VF x0f = hn::Floor(hn::Add(hn::Sub(sx, halfSize), half));
    const VF y0f = hn::Floor(hn::Add(hn::Sub(sy, halfSize), half));
    const VF x1f = hn::Add(x0f, size), y1f = hn::Add(y0f, size);
    drawn = hn::And(drawn, hn::And(hn::And(hn::Lt(x0f, tileRight), hn::Gt(x1f, tileX)),
                                   hn::And(hn::Lt(y0f, tileTop), hn::Gt(y1f, tileY))));
    // Lanes not drawn become 0 before conversion: no NaN or huge value to convert.
    const auto pixel = [&](VF v, VI origin) {
      return hn::Sub(hn::ConvertTo(di, hn::IfThenElseZero(drawn, v)), origin);
    };
    const VI x0 = pixel(hn::Max(x0f, tileX), tileXi), y0 = pixel(hn::Max(y0f, tileY), tileYi);
    const VI x1 = pixel(hn::Min(x1f, tileRight), tileXi);
    const VI y1 = pixel(hn::Min(y1f, tileTop), tileYi);

    VU color =
        hn::Load(du, reinterpret_cast<const std::uint32_t*>(group + PointCell::kColor * kPad));
    if constexpr (kLighting) {
      const VF nnx = hn::Load(df, group + PointCell::kNormalX * kPad);
      const VF nny = hn::Load(df, group + PointCell::kNormalY * kPad);
      const VF nnz = hn::Load(df, group + PointCell::kNormalZ * kPad);
      const VF lengthSquared =
          hn::Add(hn::Add(hn::Mul(nnx, nnx), hn::Mul(nny, nny)), hn::Mul(nnz, nnz));
      MF lit = hn::And(drawn, hn::Gt(lengthSquared, quarter));
      if (!hn::AllFalse(df, lit)) {
        const VF tx = hn::Sub(eyeX, x), ty = hn::Sub(eyeY, y), tz = hn::Sub(eyeZ, z);
        const VF distanceSquared =
            hn::Add(hn::Add(hn::Mul(tx, tx), hn::Mul(ty, ty)), hn::Mul(tz, tz));
        lit = hn::And(lit, hn::Gt(distanceSquared, zero));
        const VF dot = hn::Add(hn::Add(hn::Mul(nnx, tx), hn::Mul(nny, ty)), hn::Mul(nnz, tz));
        const VF cosine = hn::Div(dot, hn::Sqrt(hn::Mul(lengthSquared, distanceSquared)));
        // Unlit lanes get shade 1, which keeps their channels (and no NaN).
        const VF shade =
            hn::IfThenElse(lit, hn::Add(ambient, hn::Mul(diffuse, hn::Abs(cosine))), one);
        const auto channel = [&](VU value) {
          const VF shaded =
              hn::Add(hn::Mul(hn::ConvertTo(df, hn::BitCast(di, value)), shade), half);
          return hn::BitCast(du, hn::ConvertTo(di, shaded));
        };
        const VU red = channel(hn::And(color, byte));
        const VU green = channel(hn::And(hn::ShiftRight<8>(color), byte));
        const VU blue = channel(hn::And(hn::ShiftRight<16>(color), byte));
        color = hn::Or(hn::Or(red, hn::ShiftLeft<8>(green)),
                       hn::Or(hn::ShiftLeft<16>(blue), hn::And(color, alpha)));
      }
    }
    const VU depth = hn::BitCast(du, hn::Add(hn::Mul(nz, half), half));
    sink(i, drawn, x0, y0, x1, y1, depth, color);
  }
}

// Collects the drawn splats of a few vectors, packed, then draws them: the
// SIMD part has no per-splat branch and the scatter loop has few.
class Scatter {
 public:
  Scatter(std::uint64_t* buffer, std::int32_t stride) : buffer_(buffer), stride_(stride) {}

  HWY_INLINE void operator()(std::size_t, MF drawnF, VI x0, VI y0, VI x1, VI y1, VU depth,
                             VU color) {
    const DI di;
    const DU du;
    const auto drawn = hn::RebindMask(di, drawnF);
    const VI width = hn::Sub(x1, x0), height = hn::Sub(y1, y0);
    const VI index = hn::Add(hn::Mul(y0, hn::Set(di, stride_)), x0);
    hn::StoreU(hn::Compress(index, drawn), di, index_ + count_);
    hn::StoreU(hn::Compress(width, drawn), di, width_ + count_);
    hn::StoreU(hn::Compress(height, drawn), di, height_ + count_);
    hn::StoreU(hn::Compress(depth, hn::RebindMask(du, drawn)), du, depth_ + count_);
    hn::StoreU(hn::Compress(color, hn::RebindMask(du, drawn)), du, color_ + count_);
    extent_ = hn::Max(extent_, hn::IfThenElseZero(drawn, hn::Max(width, height)));
    count_ += hn::CountTrue(di, drawn);
    if (count_ >= kBatch) flush();
  }

  void flush() {
    const DI di;
    const std::int32_t extent = hn::GetLane(hn::MaxOfLanes(di, extent_));
    extent_ = hn::Zero(di);
    if (extent <= 1) {  // all 1x1: distant points, or a constant size of 1
      for (std::size_t k = 0; k < count_; ++k) {
        hwy::Prefetch(buffer_ + index_[k + kAhead]);
        std::uint64_t& pixel = buffer_[index_[k]];
        pixel = std::min(pixel, word(k));
      }
    } else {
      for (std::size_t k = 0; k < count_; ++k) {
        hwy::Prefetch(buffer_ + index_[k + kAhead]);
        hwy::Prefetch(buffer_ + index_[k + kAhead] + stride_);
        if (width_[k] <= 2 && height_[k] <= 2) {
          drawSmall(k);
        } else {
          drawSquare(k);
        }
      }
    }
    count_ = 0;
  }

 private:
  static constexpr std::size_t kBatch = 256;
  static constexpr std::size_t kAhead = 32;
  static constexpr std::size_t kRoom = kBatch + kAhead + HWY_MAX_BYTES / 4;

  std::uint64_t word(std::size_t k) const {
    return (static_cast<std::uint64_t>(depth_[k]) << 32) | color_[k];
  }

  // 1x1 to 2x2 without a branch on the size: the corners, some of them the
  // same pixel, all read before any is written (the minimum is idempotent).
  void drawSmall(std::size_t k) {
    const std::uint64_t w = word(k);
    std::uint64_t* p = buffer_ + index_[k];
    const auto dx = static_cast<std::size_t>(width_[k] - 1);
    const auto dy = static_cast<std::size_t>(height_[k] - 1) * static_cast<std::size_t>(stride_);
    const std::uint64_t a = p[0], b = p[dx], c = p[dy], d = p[dy + dx];
    p[0] = std::min(a, w);
    p[dx] = std::min(b, w);
    p[dy] = std::min(c, w);
    p[dy + dx] = std::min(d, w);
  }

  void drawSquare(std::size_t k) {
    const std::uint64_t w = word(k);
    std::uint64_t* row = buffer_ + index_[k];
    const std::int32_t width = width_[k], height = height_[k];
    for (std::int32_t y = 0; y < height; ++y, row += stride_) {
      for (std::int32_t x = 0; x < width; ++x) row[x] = std::min(row[x], w);
    }
  }

  std::uint64_t* buffer_;
  std::int32_t stride_;
  std::size_t count_ = 0;
  VI extent_ = hn::Zero(DI());
  // Past count_: zeros or earlier pixels, which the prefetches may touch.
  HWY_ALIGN std::int32_t index_[kRoom] = {};
  HWY_ALIGN std::int32_t width_[kRoom];
  HWY_ALIGN std::int32_t height_[kRoom];
  HWY_ALIGN std::uint32_t depth_[kRoom];
  HWY_ALIGN std::uint32_t color_[kRoom];
};

// Keeps every lane's result, for tests.
class Record {
 public:
  Record(std::size_t from, std::size_t to, PointFootprint* out) : from_(from), to_(to), out_(out) {}

  void operator()(std::size_t i, MF drawn, VI x0, VI y0, VI x1, VI y1, VU depth, VU color) {
    const DF df;
    const DI di;
    const DU du;
    HWY_ALIGN std::int32_t lanes[5][HWY_MAX_BYTES / 4];
    HWY_ALIGN std::uint32_t words[2][HWY_MAX_BYTES / 4];
    hn::Store(hn::BitCast(di, hn::VecFromMask(df, drawn)), di, lanes[0]);
    hn::Store(x0, di, lanes[1]);
    hn::Store(y0, di, lanes[2]);
    hn::Store(x1, di, lanes[3]);
    hn::Store(y1, di, lanes[4]);
    hn::Store(depth, du, words[0]);
    hn::Store(color, du, words[1]);
    for (std::size_t k = 0; k < hn::Lanes(df); ++k) {
      if (i + k < from_ || i + k >= to_) continue;
      PointFootprint& f = out_[i + k - from_];
      f = {};
      if (lanes[0][k] == 0) continue;
      f = {lanes[1][k], lanes[2][k], lanes[3][k], lanes[4][k],
           (static_cast<std::uint64_t>(words[0][k]) << 32) | words[1][k]};
    }
  }

 private:
  std::size_t from_, to_;
  PointFootprint* out_;
};

template <class Sink>
void projectAll(const PointRaster& r, const PointCell& c, std::size_t from, std::size_t to,
                Sink& sink) {
  const bool constantSize = r.constantSize > 0.0f;
  const bool lighting = r.lighting && c.hasNormals;
  if (constantSize && lighting) {
    projectSplats<true, true>(r, c, from, to, sink);
  } else if (constantSize) {
    projectSplats<true, false>(r, c, from, to, sink);
  } else if (lighting) {
    projectSplats<false, true>(r, c, from, to, sink);
  } else {
    projectSplats<false, false>(r, c, from, to, sink);
  }
}

void RasterizeCell(const PointRaster& r, const PointCell& c, std::size_t from, std::size_t to,
                   std::uint64_t* buffer) {
  Scatter scatter(buffer, r.tileWidth);
  projectAll(r, c, from, to, scatter);
  scatter.flush();
}

void RasterizeRanges(const PointRaster& r, const PointRange* ranges, std::size_t count,
                     std::uint64_t* buffer) {
  Scatter scatter(buffer, r.tileWidth);
  for (std::size_t k = 0; k < count; ++k) {
    if (ranges[k].from < ranges[k].to) {
      projectAll(r, *ranges[k].cell, ranges[k].from, ranges[k].to, scatter);
    }
  }
  scatter.flush();
}

void CellFootprints(const PointRaster& r, const PointCell& c, std::size_t from, std::size_t to,
                    PointFootprint* out) {
  Record record(from, to, out);
  projectAll(r, c, from, to, record);
}

// Words to RGBA8: the low half is the colour; an empty pixel (high half all
// ones, which no depth in [0, 1] has) becomes the background.
void WordsToRgba(const std::uint64_t* words, std::size_t count, std::uint32_t background,
                 std::uint8_t* rgba) {
  std::size_t i = 0;
#if HWY_TARGET != HWY_SCALAR  // one lane has no even and odd halves
  const DU du;
  const std::size_t lanes = hn::Lanes(du);
  const auto* halves = reinterpret_cast<const std::uint32_t*>(words);
  auto* out = reinterpret_cast<std::uint32_t*>(rgba);
  const VU empty = hn::Set(du, ~0u), fill = hn::Set(du, background);
  for (; i + lanes <= count; i += lanes) {
    const VU lo = hn::LoadU(du, halves + 2 * i), hi = hn::LoadU(du, halves + 2 * i + lanes);
    const VU color = hn::ConcatEven(du, hi, lo), depth = hn::ConcatOdd(du, hi, lo);
    hn::StoreU(hn::IfThenElse(hn::Eq(depth, empty), fill, color), du, out + i);
  }
#endif
  for (; i < count; ++i) {
    const std::uint32_t color =
        words[i] == kEmptyPixel ? background : static_cast<std::uint32_t>(words[i]);
    std::memcpy(rgba + 4 * i, &color, 4);
  }
}

// Words to eye-space depth as DepthLinearizer computes it (the same float
// operations in every lane and in the tail); an empty pixel becomes +infinity.
void WordsToDepth(const std::uint64_t* words, std::size_t count, float numerator, float farPlane,
                  float range, float* depth) {
  constexpr float kNothing = std::numeric_limits<float>::infinity();
  std::size_t i = 0;
#if HWY_TARGET != HWY_SCALAR  // one lane has no even and odd halves
  const DF df;
  const DU du;
  const std::size_t lanes = hn::Lanes(du);
  const auto* halves = reinterpret_cast<const std::uint32_t*>(words);
  const VU empty = hn::Set(du, ~0u);
  const VF top = hn::Set(df, numerator), far = hn::Set(df, farPlane), span = hn::Set(df, range);
  for (; i + lanes <= count; i += lanes) {
    const VU lo = hn::LoadU(du, halves + 2 * i), hi = hn::LoadU(du, halves + 2 * i + lanes);
    const VU high = hn::ConcatOdd(du, hi, lo);
    const VF eye = hn::Div(top, hn::Sub(far, hn::Mul(hn::BitCast(df, high), span)));
    hn::StoreU(hn::IfThenElse(hn::RebindMask(df, hn::Eq(high, empty)), hn::Set(df, kNothing), eye),
               df, depth + i);
  }
#endif
  for (; i < count; ++i) {
    const auto window = std::bit_cast<float>(static_cast<std::uint32_t>(words[i] >> 32));
    depth[i] = words[i] == kEmptyPixel ? kNothing : numerator / (farPlane - window * range);
  }
}

const char* KernelTargetName() {
  return hwy::TargetName(HWY_TARGET);
}

}  // namespace HWY_NAMESPACE
}  // namespace pointillist::render
HWY_AFTER_NAMESPACE();

#if HWY_ONCE
namespace pointillist::render {

HWY_EXPORT(RasterizeCell);
HWY_EXPORT(RasterizeRanges);
HWY_EXPORT(CellFootprints);
HWY_EXPORT(WordsToRgba);
HWY_EXPORT(WordsToDepth);
HWY_EXPORT(KernelTargetName);

namespace {

std::uint8_t unitToByte(float value) {
  return static_cast<std::uint8_t>(std::clamp(value, 0.0f, 1.0f) * 255.0f + 0.5f);
}

// The box of the pixels for which `drawn(row, x)` holds, rows bottom-up.
template <typename Drawn>
PixelBox drawnBox(std::uint32_t width, std::uint32_t height, const Drawn& drawn) {
  std::uint32_t left = width, right = 0, bottom = height, top = 0;
  for (std::uint32_t y = 0; y < height; ++y) {
    // From both ends: a row's drawn pixels are found without reading between
    // its first and last once the box already spans them.
    std::uint32_t first = 0;
    while (first < width && !drawn(y, first)) ++first;
    if (first == width) continue;
    std::uint32_t last = width - 1;
    while (last > first && last > right && !drawn(y, last)) --last;
    left = std::min(left, first);
    right = std::max(right, last);
    bottom = std::min(bottom, y);
    top = y;
  }
  if (bottom == height) return {};
  return {left, bottom, right - left + 1, top - bottom + 1};
}

void checkTile(std::size_t pixels, std::uint32_t width, std::uint32_t height, const char* what) {
  if (pixels != std::size_t{width} * height)
    throw UsageError(std::string(what) + ": " + std::to_string(pixels) + " pixels for a " +
                     std::to_string(width) + "x" + std::to_string(height) + " tile");
}

}  // namespace

PixelBox drawnWordsBox(std::span<const std::uint64_t> words, std::uint32_t width,
                       std::uint32_t height) {
  checkTile(words.size(), width, height, "drawnWordsBox");
  return drawnBox(width, height, [&](std::uint32_t y, std::uint32_t x) {
    return words[std::size_t{y} * width + x] != kEmptyPixel;
  });
}

PixelBox drawnRgbaBox(std::span<const std::uint8_t> rgba, std::uint32_t width, std::uint32_t height,
                      const std::array<std::uint8_t, 4>& background) {
  checkTile(rgba.size() / 4, width, height, "drawnRgbaBox");
  std::uint32_t empty;
  std::memcpy(&empty, background.data(), 4);
  return drawnBox(width, height, [&](std::uint32_t y, std::uint32_t x) {
    std::uint32_t pixel;
    std::memcpy(&pixel, rgba.data() + 4 * (std::size_t{y} * width + x), 4);
    return pixel != empty;
  });
}

PointRaster pointRaster(const Camera& camera, const TileRect& rect,
                        const RenderSettings& settings) {
  PointRaster raster;
  raster.viewProjection = viewProjectionMatrix(camera);
  raster.frameWidth = static_cast<float>(camera.image_width());
  raster.frameHeight = static_cast<float>(camera.image_height());
  const float scale = settings.sizeScale > 0.0f ? settings.sizeScale : 1.0f;
  raster.diameterScale = 2.0f * pixelsPerUnit(camera, 1.0f) * scale;
  raster.constantSize = std::max(settings.pointSize, 0.0f);
  raster.maxSize = std::max(1.0f, std::floor(settings.maxPointSize));
  raster.lighting = settings.lighting;
  raster.ambient = std::clamp(settings.ambient, 0.0f, 1.0f);
  raster.eye = cameraEye(camera);
  raster.tileX = static_cast<std::int32_t>(rect.x());
  raster.tileY = static_cast<std::int32_t>(rect.y());
  raster.tileWidth = static_cast<std::int32_t>(rect.width());
  raster.tileHeight = static_cast<std::int32_t>(rect.height());
  return raster;
}

PointFootprint pointFootprintScalar(const PointRaster& r, const Splat& s) {
  const glm::mat4& m = r.viewProjection;  // column-major: m[column][row]
  const auto tileX = static_cast<float>(r.tileX);
  const auto tileY = static_cast<float>(r.tileY);
  const auto tileRight = static_cast<float>(r.tileX + r.tileWidth);
  const auto tileTop = static_cast<float>(r.tileY + r.tileHeight);
  const float x = s.position[0], y = s.position[1], z = s.position[2];
  const float cw = m[0][3] * x + m[1][3] * y + m[2][3] * z + m[3][3];
  if (!(cw > 0.0f)) return {};  // behind the eye
  const float inverse = 1.0f / cw;
  const float nz = (m[0][2] * x + m[1][2] * y + m[2][2] * z + m[3][2]) * inverse;
  if (!(nz >= -1.0f && nz <= 1.0f)) return {};  // before the near or beyond the far plane
  const float nx = (m[0][0] * x + m[1][0] * y + m[2][0] * z + m[3][0]) * inverse;
  const float ny = (m[0][1] * x + m[1][1] * y + m[2][1] * z + m[3][1]) * inverse;
  float size = r.constantSize > 0.0f ? r.constantSize : s.radius * r.diameterScale * inverse;
  size = std::clamp(std::floor(size + 0.5f), 1.0f, r.maxSize);
  // As GL points: odd sizes centred on a pixel centre, even ones on a corner.
  const float wx = (nx * 0.5f + 0.5f) * r.frameWidth;
  const float wy = (ny * 0.5f + 0.5f) * r.frameHeight;
  const bool odd = std::fmod(size, 2.0f) == 1.0f;
  const float sx = odd ? std::floor(wx) + 0.5f : std::floor(wx + 0.5f);
  const float sy = odd ? std::floor(wy) + 0.5f : std::floor(wy + 0.5f);
  const float half = 0.5f * size;
  const float x0f = std::floor(sx - half + 0.5f);
  const float y0f = std::floor(sy - half + 0.5f);
  if (!(x0f < tileRight && x0f + size > tileX && y0f < tileTop && y0f + size > tileY)) {
    return {};  // misses the tile (also NaN and far outside)
  }
  PointFootprint f;
  f.x0 = static_cast<std::int32_t>(std::max(x0f, tileX)) - r.tileX;
  f.y0 = static_cast<std::int32_t>(std::max(y0f, tileY)) - r.tileY;
  f.x1 = static_cast<std::int32_t>(std::min(x0f + size, tileRight)) - r.tileX;
  f.y1 = static_cast<std::int32_t>(std::min(y0f + size, tileTop)) - r.tileY;

  // Headlight: |cos| between the normal and the direction to the eye, with
  // one square root and one division (as the kernel computes it).
  float shade = 1.0f;
  const float n0 = s.normal[0], n1 = s.normal[1], n2 = s.normal[2];
  const float lengthSquared = n0 * n0 + n1 * n1 + n2 * n2;
  if (r.lighting && lengthSquared > 0.25f) {  // no normal: unshaded
    const float tx = r.eye.x - x, ty = r.eye.y - y, tz = r.eye.z - z;
    const float distanceSquared = tx * tx + ty * ty + tz * tz;
    if (distanceSquared > 0.0f) {
      const float cosine =
          (n0 * tx + n1 * ty + n2 * tz) / std::sqrt(lengthSquared * distanceSquared);
      shade = r.ambient + (1.0f - r.ambient) * std::abs(cosine);
    }
  }
  const auto channel = [shade](std::uint8_t value) {
    return static_cast<std::uint32_t>(static_cast<float>(value) * shade + 0.5f);
  };
  const std::uint32_t color =
      packColor(channel(s.color[0]), channel(s.color[1]), channel(s.color[2]), s.color[3]);
  f.word =
      (static_cast<std::uint64_t>(std::bit_cast<std::uint32_t>(nz * 0.5f + 0.5f)) << 32) | color;
  return f;
}

void rasterizePointsScalar(const PointRaster& r, std::span<const Splat> splats,
                           std::uint64_t* buffer) {
  const std::size_t stride = static_cast<std::size_t>(r.tileWidth);
  for (const Splat& s : splats) {
    const PointFootprint f = pointFootprintScalar(r, s);
    for (std::int32_t py = f.y0; py < f.y1; ++py) {
      std::uint64_t* row = buffer + static_cast<std::size_t>(py) * stride;
      for (std::int32_t px = f.x0; px < f.x1; ++px) row[px] = std::min(row[px], f.word);
    }
  }
}

PointCell makePointCell(std::span<const Splat> splats) {
  PointCell cell;
  appendToPointCell(cell, splats);
  return cell;
}

PointCell PointCell::view(const float* values, std::size_t count, bool hasNormals) {
  PointCell cell;
  cell.view_ = values;
  cell.count = count;
  cell.hasNormals = hasNormals;
  return cell;
}

void PointCell::reserve(std::size_t splats) {
  const std::size_t padded = (splats + kPad - 1) / kPad * kPad;
  if (view_ == nullptr && padded <= capacity_) return;
  std::unique_ptr<std::byte[], BlockDeleter> block(static_cast<std::byte*>(
      ::operator new (PointGroups::blockBytes(padded), std::align_val_t{PointGroups::kAlignment})));
  // Groups are whole: the held ones move as one block, the rest are zero.
  const std::size_t held = PointGroups::blockBytes(count);
  if (held > 0) std::memcpy(block.get(), values(), held);
  std::memset(block.get() + held, 0, PointGroups::blockBytes(padded) - held);
  block_ = std::move(block);
  view_ = nullptr;
  capacity_ = padded;
}

void writeToPointCell(PointCell& cell, std::size_t first, std::span<const Splat> splats,
                      std::size_t room) {
  if (splats.empty()) return;
  const std::size_t end = first + splats.size();
  if (cell.isView() || end > cell.capacity_) cell.reserve(std::max(end, room));
  cell.count = std::max(cell.count, end);
  const bool normals = writePointGroups(splats, first, reinterpret_cast<float*>(cell.block_.get()));
  cell.hasNormals = cell.hasNormals || normals;
}

void appendToPointCell(PointCell& cell, std::span<const Splat> splats) {
  writeToPointCell(cell, cell.count, splats);
}

void rasterizePoints(const PointRaster& raster, const PointCell& cell, std::size_t from,
                     std::size_t to, std::uint64_t* buffer) {
  if (from >= to) return;
  HWY_DYNAMIC_DISPATCH(RasterizeCell)(raster, cell, from, to, buffer);
}

void rasterizePointRanges(const PointRaster& raster, std::span<const PointRange> ranges,
                          std::uint64_t* buffer) {
  if (ranges.empty()) return;
  HWY_DYNAMIC_DISPATCH(RasterizeRanges)(raster, ranges.data(), ranges.size(), buffer);
}

std::vector<PointFootprint> pointFootprints(const PointRaster& raster, const PointCell& cell,
                                            std::size_t from, std::size_t to) {
  std::vector<PointFootprint> out(to > from ? to - from : 0);
  if (from < to) HWY_DYNAMIC_DISPATCH(CellFootprints)(raster, cell, from, to, out.data());
  return out;
}

std::string pointKernelTargetName() {
  return HWY_DYNAMIC_DISPATCH(KernelTargetName)();
}

std::vector<std::int64_t> pointKernelTargets() {
  return hwy::SupportedAndGeneratedTargets();
}

void forcePointKernelTarget(std::int64_t target) {
  hwy::SetSupportedTargetsForTest(target);
}

CpuPointRenderer::CpuPointRenderer(unsigned threads) : threads_(std::max(1u, threads)) {}

void CpuPointRenderer::uploadCell(std::uint32_t id, std::span<const Splat> splats) {
  cells_[id] = makePointCell(splats);
}

void CpuPointRenderer::writeToCell(std::uint32_t id, std::uint32_t first,
                                   std::span<const Splat> splats, std::size_t room) {
  writeToPointCell(cells_[id], first, splats, room);
}

bool CpuPointRenderer::viewCell(std::uint32_t id, const float* groups, std::size_t count,
                                bool hasNormals) {
  cells_[id] = PointCell::view(groups, count, hasNormals);
  return true;
}

void CpuPointRenderer::forEachCell(const CellVisitor& visit) const {
  std::vector<Splat> splats;
  for (const auto& [id, cell] : cells_) {
    splats.resize(cell.count);
    for (std::size_t i = 0; i < cell.count; ++i) {
      Splat& s = splats[i];
      s.position[0] = *cell.x(i);
      s.position[1] = *cell.y(i);
      s.position[2] = *cell.z(i);
      s.normal[0] = *cell.nx(i);
      s.normal[1] = *cell.ny(i);
      s.normal[2] = *cell.nz(i);
      s.radius = *cell.radius(i);
      for (int c = 0; c < 4; ++c) {
        s.color[c] = static_cast<std::uint8_t>(*cell.color(i) >> (8 * c));
      }
    }
    visit(id, splats);
  }
}

void CpuPointRenderer::releaseCell(std::uint32_t id) {
  cells_.erase(id);
}

std::string CpuPointRenderer::describe() const {
  return "cpu: point kernel (" + pointKernelTargetName() + "), " + std::to_string(threads_) +
         " thread(s) per tile";
}

RenderStats CpuPointRenderer::render(const Camera& camera, const TileRect& rect,
                                     std::span<const DrawRange> ranges,
                                     const RenderSettings& settings) {
  if (settings.mode != SplatMode::Points) {
    throw UsageError(std::string("the cpu renderer draws points only, not ") +
                     splatModeName(settings.mode));
  }
  validateCamera(camera);
  if (!tileInsideFrame(camera, rect)) {
    throw UsageError("CpuPointRenderer::render: tile rectangle is empty or outside the image");
  }
  const auto start = std::chrono::steady_clock::now();
  // The splats to draw, as ranges of cached cells.
  struct Part {
    const PointCell* cell;
    std::size_t offset, count;
  };
  std::vector<Part> parts;
  parts.reserve(ranges.size());
  RenderStats stats;
  for (const DrawRange& range : ranges) {
    const auto found = cells_.find(range.cell);
    if (found == cells_.end()) {
      throw UsageError("CpuPointRenderer::render: cell " + std::to_string(range.cell) +
                       " is not uploaded");
    }
    const PointCell& cell = found->second;
    if (range.offset > cell.count || range.count > cell.count - range.offset) {
      throw UsageError("CpuPointRenderer::render: range " + std::to_string(range.offset) + "+" +
                       std::to_string(range.count) + " is outside cell " +
                       std::to_string(range.cell) + " (" + std::to_string(cell.count) + " splats)");
    }
    if (range.count == 0) continue;
    parts.push_back({&cell, range.offset, range.count});
    stats.splats += range.count;
  }
  stats.drawCalls = static_cast<std::uint32_t>(parts.size());

  const PointRaster raster = pointRaster(camera, rect, settings);
  const std::size_t tilePixels = static_cast<std::size_t>(rect.width()) * rect.height();
  // More threads than a few thousand splats each would cost more than they save.
  const auto threads =
      static_cast<unsigned>(std::clamp<std::uint64_t>(stats.splats / 8192, 1, threads_));
  buffers_.assign(tilePixels * threads, kEmptyPixel);
  const auto drawShare = [&](unsigned share) {
    std::uint64_t* buffer = buffers_.data() + tilePixels * share;
    // Splats [begin, end) of the whole list, cut across parts.
    const std::uint64_t begin = stats.splats * share / threads;
    const std::uint64_t end = stats.splats * (share + 1) / threads;
    std::vector<PointRange> shareRanges;
    shareRanges.reserve(parts.size());
    std::uint64_t at = 0;
    for (const Part& part : parts) {
      const std::uint64_t partEnd = at + part.count;
      if (partEnd > begin && at < end) {
        const std::uint64_t from = std::max(begin, at) - at;
        const std::uint64_t to = std::min(end, partEnd) - at;
        shareRanges.push_back({part.cell, part.offset + from, part.offset + to});
      }
      at = partEnd;
    }
    rasterizePointRanges(raster, shareRanges, buffer);
  };
  if (threads == 1) {
    drawShare(0);
  } else {
    std::vector<std::jthread> workers;
    for (unsigned share = 1; share < threads; ++share) workers.emplace_back(drawShare, share);
    drawShare(0);
    workers.clear();  // joins
    for (unsigned share = 1; share < threads; ++share) {
      const std::uint64_t* other = buffers_.data() + tilePixels * share;
      for (std::size_t i = 0; i < tilePixels; ++i) buffers_[i] = std::min(buffers_[i], other[i]);
    }
  }

  const std::uint32_t background =
      packColor(unitToByte(settings.clearColor[0]), unitToByte(settings.clearColor[1]),
                unitToByte(settings.clearColor[2]), unitToByte(settings.clearColor[3]));
  pixels_.resize(tilePixels * 4);
  HWY_DYNAMIC_DISPATCH(WordsToRgba)(buffers_.data(), tilePixels, background, pixels_.data());
  if (!settings.keepDepth) {
    depths_.clear();
  } else {
    const DepthLinearizer linearize(camera);
    depths_.resize(tilePixels);
    HWY_DYNAMIC_DISPATCH(WordsToDepth)
    (buffers_.data(), tilePixels, linearize.numerator, linearize.farPlane, linearize.range,
     depths_.data());
  }
  stats.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return stats;
}

}  // namespace pointillist::render
#endif  // HWY_ONCE
