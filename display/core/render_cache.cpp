#include "display/core/render_cache.hpp"

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstring>
#include <limits>
#include <utility>

#include <glm/gtc/matrix_inverse.hpp>

#include "common/clock.hpp"
#include "common/errors.hpp"

#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
// The passes over whole images and all points also get an AVX2 build, chosen
// when the program loads (ifunc): twice the lanes of the x86-64 baseline,
// and the binary still runs on machines without AVX2.
#define POINTILLIST_VECTOR_KERNEL __attribute__((target_clones("avx2", "default")))
#else
#define POINTILLIST_VECTOR_KERNEL
#endif

namespace pointillist::display {
namespace {

// The z-buffer holds one word per pixel: the eye depth's bits above (positive
// floats order as their bits) and a payload below, so one compare finds the
// nearest point and carries what the pass needs of it: the point's index for
// insert, its colour and age for reproject (no lookup into the cloud after).
constexpr std::uint64_t kNoSample = ~std::uint64_t{0};
constexpr std::size_t kPointBlock = 4096;  // points projected at a time (stays in L1/L2)
constexpr std::uint32_t kReach = 3;        // the 7x7 neighbourhood's half width
constexpr float kFar = std::numeric_limits<float>::infinity();

// The rows of the view-projection matrix a point needs, and the viewport.
struct ScreenProjection {
  float x0, x1, x2, x3;  // clip x
  float y0, y1, y2, y3;  // clip y
  float w0, w1, w2, w3;  // clip w: the eye depth
  float nearPlane, farPlane;
  float halfWidth, halfHeight, width, height;
  std::uint32_t rowPixels;
  // Where points outside the frame go: a word past the z-buffer's pixels, so
  // that the z-test needs no branch.
  std::uint32_t outside;
};

ScreenProjection screenProjection(const Camera& camera) {
  const glm::mat4 m = viewProjectionMatrix(camera);
  return {m[0][0],
          m[1][0],
          m[2][0],
          m[3][0],
          m[0][1],
          m[1][1],
          m[2][1],
          m[3][1],
          m[0][3],
          m[1][3],
          m[2][3],
          m[3][3],
          camera.near_plane(),
          camera.far_plane(),
          0.5f * static_cast<float>(camera.image_width()),
          0.5f * static_cast<float>(camera.image_height()),
          static_cast<float>(camera.image_width()),
          static_cast<float>(camera.image_height()),
          camera.image_width(),
          camera.image_width() * camera.image_height()};
}

// Pixel (p.outside outside the frame or the depth range) and eye depth of
// each point (its bits; positive inside); branch-free so that it vectorises.
// Returns how many points landed in the frame.
POINTILLIST_VECTOR_KERNEL
std::uint32_t projectPoints(const ScreenProjection p, const float* __restrict xs,
                            const float* __restrict ys, const float* __restrict zs,
                            std::size_t count, std::uint32_t* __restrict pixels,
                            std::uint32_t* __restrict depthBits) {
  std::uint32_t landed = 0;
  for (std::size_t i = 0; i < count; ++i) {
    const float px = xs[i], py = ys[i], pz = zs[i];
    const float w = p.w0 * px + p.w1 * py + p.w2 * pz + p.w3;
    const float cx = p.x0 * px + p.x1 * py + p.x2 * pz + p.x3;
    const float cy = p.y0 * px + p.y1 * py + p.y2 * pz + p.y3;
    const float inverseW = 1.0f / w;
    const float wx = (cx * inverseW + 1.0f) * p.halfWidth;
    const float wy = (cy * inverseW + 1.0f) * p.halfHeight;
    const bool inside = (w > p.nearPlane) & (w < p.farPlane) & (wx >= 0.0f) & (wx < p.width) &
                        (wy >= 0.0f) & (wy < p.height);
    // Converted only in range (NaN and overflow are undefined as integers).
    const auto column = static_cast<std::uint32_t>(static_cast<std::int32_t>(inside ? wx : 0.0f));
    const auto row = static_cast<std::uint32_t>(static_cast<std::int32_t>(inside ? wy : 0.0f));
    pixels[i] = inside ? row * p.rowPixels + column : p.outside;
    depthBits[i] = std::bit_cast<std::uint32_t>(w);
    landed += inside ? 1u : 0u;
  }
  return landed;
}

// The z-test of a block of projected points: the nearest wins (on equal
// depths, the lower payload); no branch. The z-buffer is larger than the
// caches and points that were hidden in the last frame land anywhere: the
// pixels a few points ahead are fetched early. `pixels` holds
// kPrefetchAhead entries past `count`, any value (clamped to `outside`).
constexpr std::size_t kPrefetchAhead = 128;
template <class PayloadOf>
void depthTest(const std::uint32_t* __restrict pixels, const std::uint32_t* __restrict depthBits,
               std::size_t count, std::uint32_t outside, PayloadOf payloadOf,
               std::uint64_t* __restrict zbuffer) {
  for (std::size_t i = 0; i < count; ++i) {
    __builtin_prefetch(zbuffer + std::min(pixels[i + kPrefetchAhead], outside), 1);
    const std::uint64_t key = (std::uint64_t{depthBits[i]} << 32) | payloadOf(i);
    std::uint64_t& word = zbuffer[pixels[i]];
    word = key < word ? key : word;
  }
}

// One row of the z-buffer split into eye depths (+infinity where no sample)
// and payloads, and cleared for the next frame: the only pass that reads the
// z-buffer's (large) words. Returns the samples.
POINTILLIST_VECTOR_KERNEL
std::uint32_t splitRow(std::uint64_t* __restrict keys, std::uint32_t width, float* __restrict depth,
                       std::uint32_t* __restrict payload) {
  std::uint32_t samples = 0;
  for (std::uint32_t x = 0; x < width; ++x) {
    const std::uint64_t key = keys[x];
    const bool sample = key != kNoSample;
    depth[x] = sample ? std::bit_cast<float>(static_cast<std::uint32_t>(key >> 32)) : kFar;
    payload[x] = static_cast<std::uint32_t>(key);
    keys[x] = kNoSample;
    samples += sample ? 1u : 0u;
  }
  return samples;
}

// By value: std::min returns a reference, which can keep a loop from vectorising.
inline float least(float a, float b) {
  return b < a ? b : a;
}

// out = least of seven rows, element by element.
POINTILLIST_VECTOR_KERNEL
void minOfSevenRows(const std::array<const float*, 7> rows, std::uint32_t width,
                    float* __restrict out) {
  const float* __restrict r0 = rows[0];
  const float* __restrict r1 = rows[1];
  const float* __restrict r2 = rows[2];
  const float* __restrict r3 = rows[3];
  const float* __restrict r4 = rows[4];
  const float* __restrict r5 = rows[5];
  const float* __restrict r6 = rows[6];
  for (std::uint32_t x = 0; x < width; ++x) {
    const float a = least(least(r0[x], r1[x]), least(r2[x], r3[x]));
    const float b = least(least(r4[x], r5[x]), r6[x]);
    out[x] = least(a, b);
  }
}

// Least of in[x-3 .. x+3], clipped at the ends of the row.
float leastAround(const float* in, std::uint32_t width, std::uint32_t x) {
  float lowest = kFar;
  const std::uint32_t last = std::min(x + kReach, width - 1);
  for (std::uint32_t xx = x < kReach ? 0 : x - kReach; xx <= last; ++xx) {
    lowest = least(lowest, in[xx]);
  }
  return lowest;
}

// out[x] = least of in[x-3 .. x+3] (clipped at the ends).
POINTILLIST_VECTOR_KERNEL
void minOfSevenColumns(const float* __restrict in, std::uint32_t width, float* __restrict out) {
  if (width <= 2 * kReach) {
    for (std::uint32_t x = 0; x < width; ++x) out[x] = leastAround(in, width, x);
    return;
  }
  const std::uint32_t end = width - kReach;
  for (std::uint32_t x = 0; x < kReach; ++x) out[x] = leastAround(in, width, x);
  for (std::uint32_t x = kReach; x < end; ++x) {
    const float a = least(least(in[x - 3], in[x - 2]), least(in[x - 1], in[x]));
    const float b = least(least(in[x + 1], in[x + 2]), in[x + 3]);
    out[x] = least(a, b);
  }
  for (std::uint32_t x = end; x < width; ++x) out[x] = leastAround(in, width, x);
}

// The top bit of each byte of `bytes` that holds kPriorityHole (0xff), the
// other bits clear; exact for every byte (no borrow from one to the next).
constexpr std::uint64_t holeBytes(std::uint64_t bytes) {
  static_assert(kPriorityHole == 0xff);
  constexpr std::uint64_t kLow7 = 0x7f7f7f7f7f7f7f7full;
  const std::uint64_t inverted = ~bytes;  // holes are the zero bytes now
  return ~(((inverted & kLow7) + kLow7) | inverted | kLow7);
}
static_assert(holeBytes(0x00ff7f80fe01ffffull) == 0x0080000000008080ull);

// Lists the pixels of a row without a sample (hole priority) but with some
// sample in their 7x7 box (least depth there finite); returns how many, and
// how many pixels have no sample. A vectorised look at each 64 pixels first:
// most spans have no candidate (all samples, or open sky).
POINTILLIST_VECTOR_KERNEL
std::pair<std::uint32_t, std::uint32_t> interpolationCandidates(
    const std::uint8_t* __restrict priorities, const float* __restrict boxMin, std::uint32_t width,
    std::uint32_t* __restrict listed) {
  constexpr std::uint32_t kSpan = 64;
  std::uint32_t count = 0, withoutSample = 0;
  for (std::uint32_t first = 0; first < width; first += kSpan) {
    const std::uint32_t end = std::min(width, first + kSpan);
    std::uint32_t empty = 0, candidates = 0;
    for (std::uint32_t x = first; x < end; ++x) {
      const bool noSample = priorities[x] == kPriorityHole;
      empty += noSample ? 1u : 0u;
      candidates += (noSample & (boxMin[x] != kFar)) ? 1u : 0u;
    }
    withoutSample += empty;
    if (candidates == 0) continue;
    // Eight priorities at a time: the holes' bits, then one look each.
    for (std::uint32_t x = first; x < end; x += 8) {
      std::uint64_t bytes = 0;  // past the row's end: 0, not a hole
      std::memcpy(&bytes, priorities + x, std::min<std::uint32_t>(8, end - x));
      for (std::uint64_t holes = holeBytes(bytes); holes != 0; holes &= holes - 1) {
        const std::uint32_t at = x + static_cast<std::uint32_t>(std::countr_zero(holes)) / 8;
        listed[count] = at;
        count += boxMin[at] != kFar ? 1u : 0u;
      }
    }
  }
  return {count, withoutSample};
}

// The depth cull of one row's interior (see reproject): `nearRows` are the
// 7-column minima of the three rows below and the three above. Writes the
// row's depths with the culled samples gone (+infinity); returns how many.
POINTILLIST_VECTOR_KERNEL
std::uint32_t cullRow(const float* __restrict depth, const float* __restrict columnMin,
                      const std::array<const float*, 6> nearRows, std::uint32_t width,
                      float pullForward, float* __restrict shownDepth) {
  const float* __restrict below3 = nearRows[0];
  const float* __restrict below2 = nearRows[1];
  const float* __restrict below1 = nearRows[2];
  const float* __restrict above1 = nearRows[3];
  const float* __restrict above2 = nearRows[4];
  const float* __restrict above3 = nearRows[5];
  std::uint32_t culled = 0;
  const std::uint32_t end = width - kReach;  // callers: width > 2 * kReach
  for (std::uint32_t x = 0; x < kReach; ++x) shownDepth[x] = depth[x];
  for (std::uint32_t x = kReach; x < end; ++x) {
    const float nearer = depth[x] * pullForward;
    const float left = least(least(columnMin[x - 1], columnMin[x - 2]), columnMin[x - 3]);
    const float right = least(least(columnMin[x + 1], columnMin[x + 2]), columnMin[x + 3]);
    const float below = least(least(below1[x], below2[x]), below3[x]);
    const float above = least(least(above1[x], above2[x]), above3[x]);
    const bool cull = (left < nearer) & (right < nearer) & (below < nearer) & (above < nearer) &
                      (depth[x] != kFar);
    shownDepth[x] = cull ? kFar : depth[x];
    culled += cull ? 1u : 0u;
  }
  for (std::uint32_t x = end; x < width; ++x) shownDepth[x] = depth[x];
  return culled;
}

// The colour (opaque) and priority of one row: its samples' (depth finite),
// background and the hole priority elsewhere (interpolation comes after).
// Returns the samples.
POINTILLIST_VECTOR_KERNEL
std::uint32_t shadeRow(const float* __restrict depth, const std::uint32_t* __restrict payload,
                       std::uint32_t width, std::uint32_t background, std::uint8_t* __restrict rgba,
                       std::uint8_t* __restrict priority) {
  std::uint32_t samples = 0;
  for (std::uint32_t x = 0; x < width; ++x) {
    const bool sample = depth[x] != kFar;
    const std::uint32_t aged =
        std::min<std::uint32_t>(kPriorityDense - 1, (payload[x] >> 24) * kPriorityPerAge);
    const std::uint32_t colour = sample ? (payload[x] | 0xff000000u) : background;
    std::memcpy(rgba + 4 * std::size_t{x}, &colour, 4);
    priority[x] = static_cast<std::uint8_t>(sample ? kPriorityFreshSample + aged : kPriorityHole);
    samples += sample ? 1u : 0u;
  }
  return samples;
}

std::uint32_t packRgba(const std::uint8_t* rgba) {
  std::uint32_t value;
  std::memcpy(&value, rgba, 4);
  return value;
}

// A weighted mean of the colours of samples; pixels without one add nothing.
struct Blend {
  unsigned weight = 0, r = 0, g = 0, b = 0;
  // `shift` 0: weight 1, 1: weight 2. Masks, not multiplies or branches.
  void add(std::uint32_t colour, bool sample, unsigned shift) {
    const unsigned mask = sample ? ~0u : 0u;
    const auto c = colour & mask;
    weight += (1u & mask) << shift;
    r += (c & 0xffu) << shift;
    g += ((c >> 8) & 0xffu) << shift;
    b += ((c >> 16) & 0xffu) << shift;
  }
  // The mean, rounded (one reciprocal, not three integer divisions).
  void write(std::uint8_t* rgba) const {
    const float inverse = 1.0f / static_cast<float>(weight);
    rgba[0] = static_cast<std::uint8_t>(static_cast<float>(r) * inverse + 0.5f);
    rgba[1] = static_cast<std::uint8_t>(static_cast<float>(g) * inverse + 0.5f);
    rgba[2] = static_cast<std::uint8_t>(static_cast<float>(b) * inverse + 0.5f);
    rgba[3] = 255;
  }
  // A sum kept as {weight, r, g, b}.
  std::array<std::uint32_t, 4> sums() const { return {weight, r, g, b}; }
  void add(const std::array<std::uint32_t, 4>& sums) {
    weight += sums[0];
    r += sums[1];
    g += sums[2];
    b += sums[3];
  }
};

// Eye rays of pixel centres: world = eye + depth * (forward + ndcX sx right + ndcY sy up).
struct PixelUnprojector {
  explicit PixelUnprojector(const Camera& camera)
      : width(static_cast<float>(camera.image_width())),
        height(static_cast<float>(camera.image_height())) {
    const glm::mat4 inverseView = glm::inverse(viewMatrix(camera));
    const glm::mat4 projection = projectionMatrix(camera);
    eye = glm::vec3(inverseView[3]);
    right = glm::vec3(inverseView[0]) / projection[0][0];
    up = glm::vec3(inverseView[1]) / projection[1][1];
    forward = -glm::vec3(inverseView[2]);
  }
  glm::vec3 operator()(std::uint32_t x, std::uint32_t y, float depth) const {
    const float ndcX = 2.0f * (static_cast<float>(x) + 0.5f) / width - 1.0f;
    const float ndcY = 2.0f * (static_cast<float>(y) + 0.5f) / height - 1.0f;
    return eye + depth * (forward + ndcX * right + ndcY * up);
  }

  float width, height;
  glm::vec3 eye, right, up, forward;
};

}  // namespace

double InterimFrame::filledShare() const {
  const std::uint64_t all = pixels();
  return all > 0 ? static_cast<double>(samples + dense + sparse) / static_cast<double>(all) : 0.0;
}

double meanPriority(const InterimFrame& frame, const TileRect& rect) {
  const std::uint32_t width = frame.image.width();
  if (frame.priority.empty() || rect.width() == 0 || rect.height() == 0 ||
      rect.x() + rect.width() > width || rect.y() + rect.height() > frame.image.height()) {
    return 0.0;
  }
  std::uint64_t sum = 0;
  for (std::uint32_t y = rect.y(); y < rect.y() + rect.height(); ++y) {
    const std::uint8_t* row = frame.priority.data() + static_cast<std::size_t>(y) * width;
    for (std::uint32_t x = rect.x(); x < rect.x() + rect.width(); ++x) sum += row[x];
  }
  return static_cast<double>(sum) / (static_cast<double>(rect.width()) * rect.height());
}

RenderCache::RenderCache(RenderCacheOptions options) : options_(options) {}

std::size_t RenderCache::size() const {
  const std::shared_lock lock(pointsMutex_);
  return points_.size();
}

std::uint32_t RenderCache::oldestAge() const {
  const std::shared_lock lock(pointsMutex_);
  std::uint8_t oldest = 0;
  for (std::size_t i = 0; i < points_.size(); ++i) oldest = std::max(oldest, points_.age(i));
  return oldest;
}

void RenderCache::clear() {
  const std::unique_lock lock(pointsMutex_);
  points_.clear();
}

void RenderCache::Points::clear() {
  x.clear();
  y.clear();
  z.clear();
  colourAndAge.clear();
}

void RenderCache::Points::reserve(std::size_t count) {
  x.reserve(count);
  y.reserve(count);
  z.reserve(count);
  colourAndAge.reserve(count);
}

void RenderCache::Points::push(const glm::vec3& position, std::uint32_t rgba,
                               std::uint8_t pointAge) {
  x.push_back(position.x);
  y.push_back(position.y);
  z.push_back(position.z);
  colourAndAge.push_back((rgba & 0x00ffffffu) | (std::uint32_t{pointAge} << 24));
}

std::uint64_t RenderCache::project(const Camera& camera, Payload payload, ZBuffer& zbuffer) const {
  validateCamera(camera);
  const std::size_t pixels = static_cast<std::size_t>(camera.image_width()) * camera.image_height();
  // The passes that read the z-buffer leave it clear for the next frame
  // (their rows are in cache then; a separate pass costs a trip to memory).
  // One word more: where points outside the frame go.
  if (zbuffer.words.size() != pixels + 1 || !zbuffer.clear) {
    zbuffer.words.assign(pixels + 1, kNoSample);
  }
  zbuffer.clear = false;
  zbuffer.blockPixel.resize(kPointBlock + kPrefetchAhead);
  zbuffer.blockDepth.resize(kPointBlock);
  const std::shared_lock lock(pointsMutex_);
  const ScreenProjection projection = screenProjection(camera);
  std::uint64_t landed = 0;
  const std::size_t count = points_.size();
  // In blocks: the projection vectorises, the scattered z-test cannot, and
  // the block between them stays in cache.
  for (std::size_t first = 0; first < count; first += kPointBlock) {
    const std::size_t n = std::min(kPointBlock, count - first);
    landed += projectPoints(projection, points_.x.data() + first, points_.y.data() + first,
                            points_.z.data() + first, n, zbuffer.blockPixel.data(),
                            zbuffer.blockDepth.data());
    if (payload == Payload::pointIndex) {
      const auto firstPoint = static_cast<std::uint32_t>(first);
      depthTest(
          zbuffer.blockPixel.data(), zbuffer.blockDepth.data(), n, projection.outside,
          [firstPoint](std::size_t i) { return firstPoint + static_cast<std::uint32_t>(i); },
          zbuffer.words.data());
    } else {
      const std::uint32_t* colourAndAge = points_.colourAndAge.data() + first;
      depthTest(
          zbuffer.blockPixel.data(), zbuffer.blockDepth.data(), n, projection.outside,
          [colourAndAge](std::size_t i) { return colourAndAge[i]; }, zbuffer.words.data());
    }
  }
  return landed;
}

void RenderCache::insert(const Camera& camera, const Image& image, std::span<const float> depth) {
  validateCamera(camera);
  const std::uint32_t width = camera.image_width();
  const std::uint32_t height = camera.image_height();
  const std::size_t pixels = static_cast<std::size_t>(width) * height;
  if (image.width() != width || image.height() != height || depth.size() != pixels) {
    throw UsageError("render cache: a " + std::to_string(width) + "x" + std::to_string(height) +
                     " frame came with a " + std::to_string(image.width()) + "x" +
                     std::to_string(image.height()) + " image and " + std::to_string(depth.size()) +
                     " depth values");
  }
  if (options_.capacity == 0) options_.capacity = 2 * pixels;
  const std::size_t capacity = options_.capacity;
  ++counters_.framesInserted;
  // Only insert changes points_ (at the swap), so it reads them unlocked.
  project(camera, Payload::pointIndex, insertZbuffer_);
  std::uint64_t* keys = insertZbuffer_.words.data();
  const std::size_t previous = size();
  taken_.assign(previous, 0);  // replaced by the frame's sample, or wrong
  next_.clear();
  next_.reserve(std::min(capacity, previous + pixels));

  // The frame's samples first, in pixel order: the next camera is close to
  // this one, so its reprojection then reads the points almost in order.
  const PixelUnprojector unproject(camera);
  const float behind = 1.0f + options_.sameSurfaceFraction;
  const float inFront = 1.0f - options_.sameSurfaceFraction;
  for (std::uint32_t y = 0; y < height; ++y) {
    const std::uint8_t* colours = image.pixel(0, y);
    for (std::uint32_t x = 0; x < width; ++x) {
      const std::size_t pixel = static_cast<std::size_t>(y) * width + x;
      const std::uint64_t key = keys[pixel];
      keys[pixel] = kNoSample;
      const auto index = static_cast<std::uint32_t>(key);
      const float d = depth[pixel];
      const bool covered = std::isfinite(d) && d > 0.0f;
      if (key != kNoSample) {
        if (!covered) {  // the frame sees nothing along this ray: the point was wrong
          taken_[index] = 1;
          ++counters_.removedWrong;
          continue;
        }
        const float cachedDepth = std::bit_cast<float>(static_cast<std::uint32_t>(key >> 32));
        if (cachedDepth > d * behind) {
          ++counters_.added;  // hidden behind the frame's surface: it stays
        } else {
          taken_[index] = 1;  // this sample replaces it
          if (cachedDepth < d * inFront) {
            ++counters_.removedWrong;  // it lay in front of the surface the frame shows
          } else {
            ++counters_.refreshed;
          }
        }
      } else if (covered) {
        ++counters_.added;
      } else {
        continue;
      }
      if (next_.size() == capacity) continue;  // a frame larger than the cache
      const glm::vec3 world = unproject(x, y, d);
      next_.push(world, packRgba(colours + 4 * std::size_t{x}), 0);
    }
  }

  insertZbuffer_.clear = true;  // the loop cleared each pixel it read

  // Then the cached points the frame did not replace, a frame older. Those
  // past maxAge leave; when the cache is full the eldest make room.
  std::array<std::size_t, 256> byAge{};
  for (std::size_t i = 0; i < previous; ++i) {
    if (taken_[i] != 0) continue;
    const auto age = static_cast<std::uint8_t>(std::min(255, points_.age(i) + 1));
    if (age > options_.maxAge) {
      taken_[i] = 1;
      ++counters_.removedOld;
      continue;
    }
    ++byAge[age];
  }
  std::size_t candidates = 0;
  for (const std::size_t count : byAge) candidates += count;
  const std::size_t room = capacity - next_.size();
  std::size_t excess = candidates > room ? candidates - room : 0;
  counters_.evictedFull += excess;
  // Every point older than `threshold` goes, and the first `atThreshold` at it.
  std::size_t threshold = byAge.size() - 1;
  std::size_t older = 0;
  while (threshold > 0 && older + byAge[threshold] < excess) {
    older += byAge[threshold];
    --threshold;
  }
  std::size_t atThreshold = excess > older ? excess - older : 0;
  if (excess == 0) threshold = byAge.size();  // nothing to evict
  for (std::size_t i = 0; i < previous; ++i) {
    if (taken_[i] != 0) continue;
    const auto age = static_cast<std::uint8_t>(std::min(255, points_.age(i) + 1));
    if (age > threshold) continue;
    if (age == threshold && atThreshold > 0) {
      --atThreshold;
      continue;
    }
    next_.push({points_.x[i], points_.y[i], points_.z[i]}, points_.colourAndAge[i], age);
  }
  const std::unique_lock lock(pointsMutex_);
  std::swap(points_, next_);
}

InterimFrame RenderCache::reproject(const Camera& camera) {
  const auto start = Clock::now();
  InterimFrame frame;
  frame.pointsInView = project(camera, Payload::colourAndAge, zbuffer_);
  const std::uint32_t width = camera.image_width();
  const std::uint32_t height = camera.image_height();
  const std::size_t pixels = static_cast<std::size_t>(width) * height;
  // Every pixel and priority is written below.
  frame.image = Image::uninitialized(width, height);
  frame.priority.resize(pixels);
  if (frame.pointsInView == 0) {  // nothing cached in view: all holes
    frame.image.fill(options_.background);
    std::fill(frame.priority.begin(), frame.priority.end(), kPriorityHole);
    frame.holes = pixels;
    zbuffer_.clear = true;  // nothing landed
    frame.seconds = secondsBetween(start, Clock::now());
    return frame;
  }
  std::uint64_t* keys = zbuffer_.words.data();
  const auto keyRow = [&](std::int64_t y) { return keys + static_cast<std::size_t>(y) * width; };

  // The passes after the projection run as a pipeline down the rows, a few
  // rows apart, so that the rows each pass reads are still in cache (the
  // z-buffer itself is far larger than the caches):
  //   row t      its z-buffer words split into depths and payloads (and
  //              cleared), the depths' least over 7 columns;
  //   row t - 3  the least depth over 7 rows, the depth cull, the colours
  //              and priorities;
  //   row t - 6  interpolation, which reads the shaded rows 3 above.
  //
  // Depth cull, the paper's filtered-depth test taken per side: a sample is
  // culled when each side of its 7x7 neighbourhood (the three columns left,
  // the three right, the three rows below, the three above) holds a sample
  // nearer than its depth pulled forward by depthCullFraction: it shows
  // through a gap of a nearer surface. The paper's filter, the mean of the
  // 3x3 neighbourhood, also culls the far side of every silhouette (a
  // background pixel beside an object); one side alone never culls here.
  constexpr std::uint32_t kRing = 8;  // rows kept of each per-row buffer
  const auto ring = [&]<class T>(std::vector<T>& buffer, std::int64_t y) {
    return buffer.data() + static_cast<std::size_t>(y % kRing) * width;
  };
  const auto clampRow = [&](std::int64_t y) {
    return std::clamp<std::int64_t>(y, 0, std::int64_t{height} - 1);
  };
  sampleDepth_.resize(std::size_t{kRing} * width);
  samplePayload_.resize(std::size_t{kRing} * width);
  rowMinDepth_.resize(std::size_t{kRing} * width);
  columnMinDepth_.resize(width);
  boxMinDepth_.resize(std::size_t{kRing} * width);
  shownDepth_.resize(width);
  const float pullForward = 1.0f / (1.0f + options_.depthCullFraction);
  const std::uint32_t background = packRgba(options_.background.data());
  columnBlend_.resize(width);
  columnBlendRow_.assign(width, ~std::uint32_t{0});
  candidates_.resize(width);
  const std::int64_t rows = height;
  // Rows with no sample within three rows (open sky) are holes throughout:
  // no filter, cull or interpolation runs there.
  std::array<std::uint32_t, kRing> rowSamples{};
  std::array<bool, kRing> emptyAround{};
  const auto slot = [](std::int64_t y) { return static_cast<std::size_t>(y % kRing); };
  for (std::int64_t t = 0; t < rows + 2 * kReach; ++t) {
    if (t < rows) {
      rowSamples[slot(t)] =
          splitRow(keyRow(t), width, ring(sampleDepth_, t), ring(samplePayload_, t));
      if (rowSamples[slot(t)] == 0) {
        std::fill_n(ring(rowMinDepth_, t), width, kFar);
      } else {
        minOfSevenColumns(ring(sampleDepth_, t), width, ring(rowMinDepth_, t));
      }
    }
    if (const std::int64_t y = t - kReach; y >= 0 && y < rows) {
      std::uint32_t near = 0;
      constexpr auto kSignedReach = static_cast<std::int64_t>(kReach);
      for (std::int64_t k = -kSignedReach; k <= kSignedReach; ++k) {
        near += rowSamples[slot(clampRow(y + k))];
      }
      emptyAround[slot(y)] = near == 0;
    }
    if (const std::int64_t y = t - kReach; y >= 0 && y < rows && !emptyAround[slot(y)]) {
      // Rows past the border repeat the edge row: the least of a set is
      // unchanged by repeats.
      std::array<const float*, 7> around{};
      for (std::size_t k = 0; k < around.size(); ++k) {
        around[k] = ring(sampleDepth_, clampRow(y + static_cast<std::int64_t>(k) - kReach));
      }
      minOfSevenRows(around, width, columnMinDepth_.data());
      minOfSevenColumns(columnMinDepth_.data(), width, ring(boxMinDepth_, y));
    }
    if (const std::int64_t y = t - kReach; y >= 0 && y < rows) {
      const float* depth = ring(sampleDepth_, y);
      if (!emptyAround[slot(y)] && y >= kReach && y + kReach < rows && width > 2 * kReach) {
        frame.culled += cullRow(
            depth, columnMinDepth_.data(),
            {ring(rowMinDepth_, y - 3), ring(rowMinDepth_, y - 2), ring(rowMinDepth_, y - 1),
             ring(rowMinDepth_, y + 1), ring(rowMinDepth_, y + 2), ring(rowMinDepth_, y + 3)},
            width, pullForward, shownDepth_.data());
        depth = shownDepth_.data();
      }
      frame.samples += shadeRow(depth, ring(samplePayload_, y), width, background,
                                frame.image.pixel(0, static_cast<std::uint32_t>(y)),
                                frame.priority.data() + static_cast<std::size_t>(y) * width);
    }
    if (const std::int64_t y = t - 2 * kReach; y >= 0) {
      if (emptyAround[slot(y)]) {
        frame.holes += width;
      } else {
        interpolateRow(static_cast<std::uint32_t>(y), ring(boxMinDepth_, y), frame);
      }
    }
  }
  zbuffer_.clear = true;  // splitRow cleared each row
  frame.seconds = secondsBetween(start, Clock::now());
  return frame;
}

// The pixels of row `y` without a sample take a weighted mean of the samples
// near: 3x3 where there are some, else a 7x7 box. `boxMin`, the least depth
// over each pixel's 7x7 box, says at once whether there is any (culled
// samples count there, so a box may still turn out empty).
void RenderCache::interpolateRow(std::uint32_t y, const float* boxMin, InterimFrame& frame) {
  const std::uint32_t width = frame.image.width();
  const std::uint32_t height = frame.image.height();
  // Samples are the pixels shaded with a sample's priority (interpolated
  // ones, from this row or those below, are not).
  const std::uint8_t* shadedPriority = frame.priority.data();
  const std::uint8_t* shadedColour = frame.image.bytes().data();
  const auto addSample = [&](Blend& blend, std::uint32_t x, std::uint32_t yy, unsigned shift) {
    const std::size_t at = static_cast<std::size_t>(yy) * width + x;
    std::uint32_t colour;
    std::memcpy(&colour, shadedColour + 4 * at, 4);
    blend.add(colour, shadedPriority[at] < kPriorityDense, shift);
  };
  const std::uint32_t y0 = y < kReach ? 0 : y - kReach, y1 = std::min(y + kReach, height - 1);
  // The 7x7 box as seven columns of seven: the sparse pixels of a row share
  // most columns with their neighbours, so each column is summed once a row.
  const auto columnBlend = [&](std::uint32_t x) -> const std::array<std::uint32_t, 4>& {
    if (columnBlendRow_[x] != y) {
      Blend column;
      for (std::uint32_t yy = y0; yy <= y1; ++yy) addSample(column, x, yy, 0);
      columnBlend_[x] = column.sums();
      columnBlendRow_[x] = y;
    }
    return columnBlend_[x];
  };
  // Pixels without a sample have the hole priority so far (shadeRow). Those
  // with samples near are listed first, without branches (a row of sky is
  // as quick as a row of samples); the others stay holes.
  std::uint8_t* priorities = frame.priority.data() + static_cast<std::size_t>(y) * width;
  const auto [candidates, withoutSample] =
      interpolationCandidates(priorities, boxMin, width, candidates_.data());
  frame.holes += withoutSample - candidates;
  for (std::uint32_t i = 0; i < candidates; ++i) {
    const std::uint32_t x = candidates_[i];
    // 3x3, centre-weighted: edge neighbours count twice the corners.
    // Without branches on which neighbours hold samples: in sparse regions
    // that is a coin toss.
    Blend blend;
    const std::uint32_t left = x == 0 ? 0 : x - 1, right = std::min(x + 1, width - 1);
    const std::uint32_t down = y == 0 ? 0 : y - 1, up = std::min(y + 1, height - 1);
    const auto add = [&](std::uint32_t xx, std::uint32_t yy, unsigned shift) {
      addSample(blend, xx, yy, shift);
    };
    // Clamped at the image's edge, where a neighbour may count twice.
    add(left, down, 0), add(x, down, 1), add(right, down, 0);
    add(left, y, 1), add(right, y, 1);
    add(left, up, 0), add(x, up, 1), add(right, up, 0);
    std::uint8_t priority = kPriorityDense;
    if (blend.weight == 0) {
      const std::uint32_t x0 = x < kReach ? 0 : x - kReach, x1 = std::min(x + kReach, width - 1);
      for (std::uint32_t xx = x0; xx <= x1; ++xx) blend.add(columnBlend(xx));
      priority = kPrioritySparse;
    }
    if (blend.weight == 0) {
      ++frame.holes;
      continue;
    }
    blend.write(frame.image.pixel(x, y));
    priorities[x] = priority;
    if (priority == kPriorityDense) {
      ++frame.dense;
    } else {
      ++frame.sparse;
    }
  }
}

}  // namespace pointillist::display
