#include "display/core/render_cache.hpp"

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstring>
#include <limits>

#include <glm/gtc/matrix_inverse.hpp>

#include "common/clock.hpp"
#include "common/errors.hpp"

namespace pointillist::display {
namespace {

constexpr std::uint64_t kNoPoint = ~std::uint64_t{0};
constexpr std::uint32_t kBlock = 8;  // hole test granularity (pixels)

std::uint32_t packRgba(const std::uint8_t* rgba) {
  std::uint32_t value;
  std::memcpy(&value, rgba, 4);
  return value;
}

void unpackRgba(std::uint32_t value, std::uint8_t* rgba) {
  std::memcpy(rgba, &value, 4);
}

std::uint8_t channel(std::uint32_t value, int index) {
  return static_cast<std::uint8_t>(value >> (8 * index));
}

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

std::uint32_t RenderCache::oldestAge() const {
  std::uint8_t oldest = 0;
  for (const std::uint8_t age : age_) oldest = std::max(oldest, age);
  return oldest;
}

void RenderCache::clear() {
  x_.clear();
  y_.clear();
  z_.clear();
  colour_.clear();
  age_.clear();
}

std::uint64_t RenderCache::project(const Camera& camera) {
  validateCamera(camera);
  const std::uint32_t width = camera.image_width();
  const std::uint32_t height = camera.image_height();
  zbuffer_.resize(static_cast<std::size_t>(width) * height);
  std::fill(zbuffer_.begin(), zbuffer_.end(), kNoPoint);
  const glm::mat4 m = viewProjectionMatrix(camera);
  const float nearPlane = camera.near_plane();
  const float farPlane = camera.far_plane();
  const float halfWidth = 0.5f * static_cast<float>(width);
  const float halfHeight = 0.5f * static_cast<float>(height);
  const float widthLimit = static_cast<float>(width);
  const float heightLimit = static_cast<float>(height);
  std::uint64_t landed = 0;
  const std::size_t count = x_.size();
  for (std::size_t i = 0; i < count; ++i) {
    const float px = x_[i], py = y_[i], pz = z_[i];
    const float w = m[0][3] * px + m[1][3] * py + m[2][3] * pz + m[3][3];
    if (!(w > nearPlane && w < farPlane)) continue;
    const float inverseW = 1.0f / w;
    const float cx = m[0][0] * px + m[1][0] * py + m[2][0] * pz + m[3][0];
    const float cy = m[0][1] * px + m[1][1] * py + m[2][1] * pz + m[3][1];
    const float wx = (cx * inverseW + 1.0f) * halfWidth;
    const float wy = (cy * inverseW + 1.0f) * halfHeight;
    if (!(wx >= 0.0f && wx < widthLimit && wy >= 0.0f && wy < heightLimit)) continue;
    ++landed;
    // Positive floats order as their bits: depth and index compare as one word.
    const std::uint64_t key =
        (std::uint64_t{std::bit_cast<std::uint32_t>(w)} << 32) | static_cast<std::uint32_t>(i);
    std::uint64_t& slot =
        zbuffer_[static_cast<std::size_t>(wy) * width + static_cast<std::size_t>(wx)];
    slot = std::min(slot, key);
  }
  return landed;
}

void RenderCache::removeMarked() {
  std::size_t kept = 0;
  const std::size_t count = x_.size();
  for (std::size_t i = 0; i < count; ++i) {
    if (remove_[i] != 0) continue;
    x_[kept] = x_[i];
    y_[kept] = y_[i];
    z_[kept] = z_[i];
    colour_[kept] = colour_[i];
    age_[kept] = age_[i];
    ++kept;
  }
  x_.resize(kept);
  y_.resize(kept);
  z_.resize(kept);
  colour_.resize(kept);
  age_.resize(kept);
}

// Evicts the eldest points until `wanted` new ones fit; returns how many fit.
std::size_t RenderCache::makeRoom(std::size_t wanted) {
  const std::size_t capacity = options_.capacity;
  if (size() + wanted <= capacity) return wanted;
  std::size_t excess = std::min(size(), size() + wanted - capacity);
  std::array<std::size_t, 256> byAge{};
  for (const std::uint8_t age : age_) ++byAge[age];
  // Every point older than `threshold` goes, and enough of those at it.
  int threshold = 255;
  std::size_t older = 0;
  while (threshold > 0 && older + byAge[static_cast<std::size_t>(threshold)] < excess) {
    older += byAge[static_cast<std::size_t>(threshold)];
    --threshold;
  }
  std::size_t atThreshold = excess - std::min(excess, older);
  remove_.assign(size(), 0);
  for (std::size_t i = 0; i < age_.size(); ++i) {
    if (age_[i] > threshold) {
      remove_[i] = 1;
    } else if (age_[i] == threshold && atThreshold > 0) {
      remove_[i] = 1;
      --atThreshold;
    }
  }
  counters_.evictedFull += excess;
  removeMarked();
  return std::min(wanted, capacity - size());
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
  ++counters_.framesInserted;
  project(camera);
  for (std::uint8_t& age : age_) age = static_cast<std::uint8_t>(std::min(255, age + 1));
  remove_.assign(size(), 0);

  const PixelUnprojector unproject(camera);
  std::vector<std::uint32_t> fresh;  // pixels that become new points
  std::size_t marked = 0;            // points marked for removal
  for (std::uint32_t y = 0; y < height; ++y) {
    for (std::uint32_t x = 0; x < width; ++x) {
      const std::size_t pixel = static_cast<std::size_t>(y) * width + x;
      const std::uint64_t key = zbuffer_[pixel];
      const float d = depth[pixel];
      const bool covered = std::isfinite(d) && d > 0.0f;
      if (key == kNoPoint) {
        if (covered) fresh.push_back(static_cast<std::uint32_t>(pixel));
        continue;
      }
      const auto index = static_cast<std::size_t>(key & 0xffffffffu);
      if (!covered) {  // the frame sees nothing along this ray: the point was wrong
        remove_[index] = 1;
        ++marked;
        ++counters_.removedWrong;
        continue;
      }
      const float cachedDepth = std::bit_cast<float>(static_cast<std::uint32_t>(key >> 32));
      if (cachedDepth > d * (1.0f + options_.sameSurfaceFraction)) {
        fresh.push_back(static_cast<std::uint32_t>(pixel));  // hidden behind: it stays
        continue;
      }
      if (cachedDepth < d * (1.0f - options_.sameSurfaceFraction)) {
        ++counters_.removedWrong;  // in front of the surface the frame shows
      } else {
        ++counters_.refreshed;
      }
      const glm::vec3 world = unproject(x, y, d);
      x_[index] = world.x;
      y_[index] = world.y;
      z_[index] = world.z;
      colour_[index] = packRgba(image.pixel(x, y));
      age_[index] = 0;
    }
  }
  for (std::size_t i = 0; i < age_.size(); ++i) {
    if (age_[i] > options_.maxAge && remove_[i] == 0) {
      remove_[i] = 1;
      ++marked;
      ++counters_.removedOld;
    }
  }
  if (marked > 0) removeMarked();  // most frames remove nothing
  const std::size_t fits = makeRoom(fresh.size());
  for (std::size_t i = 0; i < fits; ++i) {
    const std::uint32_t pixel = fresh[i];
    const std::uint32_t x = pixel % width;
    const std::uint32_t y = pixel / width;
    const glm::vec3 world = unproject(x, y, depth[pixel]);
    x_.push_back(world.x);
    y_.push_back(world.y);
    z_.push_back(world.z);
    colour_.push_back(packRgba(image.pixel(x, y)));
    age_.push_back(0);
  }
  counters_.added += fits;
}

InterimFrame RenderCache::reproject(const Camera& camera) {
  const auto start = Clock::now();
  InterimFrame frame;
  frame.pointsInView = project(camera);
  const std::uint32_t width = camera.image_width();
  const std::uint32_t height = camera.image_height();
  const std::size_t pixels = static_cast<std::size_t>(width) * height;
  // The nearest point's depth per pixel, +infinity where none landed.
  constexpr float kFar = std::numeric_limits<float>::infinity();
  sampleDepth_.resize(pixels);
  for (std::size_t pixel = 0; pixel < pixels; ++pixel) {
    const std::uint64_t key = zbuffer_[pixel];
    sampleDepth_[pixel] =
        key == kNoPoint ? kFar : std::bit_cast<float>(static_cast<std::uint32_t>(key >> 32));
  }

  // Depth cull, the paper's filtered-depth test taken per side: a sample is
  // culled when each side of its 7x7 neighbourhood (the three columns left,
  // the three right, the three rows below, the three above) holds a sample
  // nearer than its depth pulled forward by depthCullFraction: it shows
  // through a gap of a nearer surface. The paper's filter, the mean of the
  // 3x3 neighbourhood, also culls the far side of every silhouette (a
  // background pixel beside an object); one side alone never culls here.
  // Minimum depths over 7 rows, then over 7 columns: both vectorise.
  constexpr std::uint32_t kReach = 3;
  std::vector<float>& columnMin = columnMinDepth_;
  std::vector<float>& rowMin = rowMinDepth_;
  columnMin.resize(pixels);
  rowMin.resize(pixels);
  for (std::uint32_t y = 0; y < height; ++y) {
    float* out = columnMin.data() + static_cast<std::size_t>(y) * width;
    std::fill(out, out + width, kFar);
    for (std::uint32_t yy = y < kReach ? 0 : y - kReach; yy <= std::min(y + kReach, height - 1);
         ++yy) {
      const float* in = sampleDepth_.data() + static_cast<std::size_t>(yy) * width;
      for (std::uint32_t x = 0; x < width; ++x) out[x] = in[x] < out[x] ? in[x] : out[x];
    }
    // Seven shifted rows, so the interior vectorises; the borders apart.
    const float* in = sampleDepth_.data() + static_cast<std::size_t>(y) * width;
    float* across = rowMin.data() + static_cast<std::size_t>(y) * width;
    const auto edge = [&](std::uint32_t x) {
      float least = kFar;
      for (std::uint32_t xx = x < kReach ? 0 : x - kReach; xx <= std::min(x + kReach, width - 1);
           ++xx) {
        least = std::min(least, in[xx]);
      }
      across[x] = least;
    };
    if (width <= 2 * kReach) {
      for (std::uint32_t x = 0; x < width; ++x) edge(x);
      continue;
    }
    for (std::uint32_t x = 0; x < kReach; ++x) edge(x);
    for (std::uint32_t x = kReach; x + kReach < width; ++x) {
      float least = in[x - 3] < in[x - 2] ? in[x - 3] : in[x - 2];
      least = in[x - 1] < least ? in[x - 1] : least;
      least = in[x] < least ? in[x] : least;
      least = in[x + 1] < least ? in[x + 1] : least;
      least = in[x + 2] < least ? in[x + 2] : least;
      across[x] = in[x + 3] < least ? in[x + 3] : least;
    }
    for (std::uint32_t x = width - kReach; x < width; ++x) edge(x);
  }
  const float pullForward = 1.0f / (1.0f + options_.depthCullFraction);
  for (std::uint32_t y = kReach; y + kReach < height; ++y) {
    const std::size_t row = static_cast<std::size_t>(y) * width;
    for (std::uint32_t x = kReach; x + kReach < width; ++x) {
      const std::size_t pixel = row + x;
      if (zbuffer_[pixel] == kNoPoint) continue;
      const float nearer = sampleDepth_[pixel] * pullForward;
      const float* columns = columnMin.data() + pixel;
      const float* rows = rowMin.data() + pixel;
      const float left = std::min({columns[-1], columns[-2], columns[-3]});
      const float right = std::min({columns[1], columns[2], columns[3]});
      const float below = std::min({rows[-static_cast<std::ptrdiff_t>(width)],
                                    rows[-2 * static_cast<std::ptrdiff_t>(width)],
                                    rows[-3 * static_cast<std::ptrdiff_t>(width)]});
      const float above = std::min({rows[width], rows[2 * static_cast<std::size_t>(width)],
                                    rows[3 * static_cast<std::size_t>(width)]});
      if (left < nearer && right < nearer && below < nearer && above < nearer) {
        zbuffer_[pixel] = kNoPoint;  // its neighbours' tests used the depth image
        ++frame.culled;
      }
    }
  }

  // Which 8x8 blocks have a sample within reach of the 7x7 box (the block or
  // a neighbour): most empty pixels are far from any, and holes at once.
  const std::uint32_t blocksX = (width + kBlock - 1) / kBlock;
  const std::uint32_t blocksY = (height + kBlock - 1) / kBlock;
  std::vector<std::uint8_t>& blockHasSample = blockHasSample_;
  blockHasSample.assign(static_cast<std::size_t>(blocksX) * blocksY, 0);
  for (std::uint32_t y = 0; y < height; ++y) {
    const std::uint64_t* row = zbuffer_.data() + static_cast<std::size_t>(y) * width;
    std::uint8_t* blocks = blockHasSample.data() + static_cast<std::size_t>(y / kBlock) * blocksX;
    for (std::uint32_t x = 0; x < width; ++x) {
      if (row[x] != kNoPoint) blocks[x / kBlock] = 1;
    }
  }
  std::vector<std::uint8_t>& blockNear = blockNearSample_;
  blockNear.assign(blockHasSample.size(), 0);
  for (std::uint32_t by = 0; by < blocksY; ++by) {
    for (std::uint32_t bx = 0; bx < blocksX; ++bx) {
      if (blockHasSample[static_cast<std::size_t>(by) * blocksX + bx] == 0) continue;
      for (std::uint32_t ny = by == 0 ? 0 : by - 1; ny <= std::min(by + 1, blocksY - 1); ++ny) {
        for (std::uint32_t nx = bx == 0 ? 0 : bx - 1; nx <= std::min(bx + 1, blocksX - 1); ++nx) {
          blockNear[static_cast<std::size_t>(ny) * blocksX + nx] = 1;
        }
      }
    }
  }

  frame.image = Image(width, height, options_.background);
  frame.priority.assign(pixels, kPriorityHole);
  // After the cull: the colour of the point a pixel shows, if any.
  const auto sampleAt = [&](std::uint32_t x, std::uint32_t y) {
    return zbuffer_[static_cast<std::size_t>(y) * width + x] != kNoPoint;
  };
  const auto colourAt = [&](std::size_t pixel) {
    return colour_[static_cast<std::size_t>(zbuffer_[pixel] & 0xffffffffu)];
  };
  for (std::uint32_t y = 0; y < height; ++y) {
    const std::uint8_t* near = blockNear.data() + static_cast<std::size_t>(y / kBlock) * blocksX;
    for (std::uint32_t x = 0; x < width; ++x) {
      const std::size_t pixel = static_cast<std::size_t>(y) * width + x;
      if (const std::uint64_t key = zbuffer_[pixel]; key != kNoPoint) {
        const auto index = static_cast<std::size_t>(key & 0xffffffffu);
        unpackRgba(colour_[index], frame.image.pixel(x, y));
        frame.priority[pixel] = static_cast<std::uint8_t>(std::min<unsigned>(
            kPriorityDense - 1, kPriorityFreshSample + unsigned{age_[index]} * kPriorityPerAge));
        ++frame.samples;
        continue;
      }
      if (near[x / kBlock] == 0) {
        ++frame.holes;
        continue;
      }
      std::uint8_t* out = frame.image.pixel(x, y);
      // 3x3, centre-weighted: edge neighbours count twice the corners.
      unsigned weight = 0, r = 0, g = 0, b = 0;
      for (int dy = -1; dy <= 1; ++dy) {
        const int yy = static_cast<int>(y) + dy;
        if (yy < 0 || yy >= static_cast<int>(height)) continue;
        for (int dx = -1; dx <= 1; ++dx) {
          const int xx = static_cast<int>(x) + dx;
          if (xx < 0 || xx >= static_cast<int>(width) || (dx == 0 && dy == 0)) continue;
          if (!sampleAt(static_cast<std::uint32_t>(xx), static_cast<std::uint32_t>(yy))) continue;
          const unsigned w = (dx == 0 || dy == 0) ? 2u : 1u;
          const std::uint32_t c =
              colourAt(static_cast<std::size_t>(yy) * width + static_cast<std::size_t>(xx));
          weight += w;
          r += w * channel(c, 0);
          g += w * channel(c, 1);
          b += w * channel(c, 2);
        }
      }
      std::uint8_t priority = kPriorityDense;
      if (weight == 0) {
        // Sparse: a 7x7 box.
        const std::uint32_t x0 = x < 3 ? 0 : x - 3, x1 = std::min(x + 3, width - 1);
        const std::uint32_t y0 = y < 3 ? 0 : y - 3, y1 = std::min(y + 3, height - 1);
        for (std::uint32_t yy = y0; yy <= y1; ++yy) {
          for (std::uint32_t xx = x0; xx <= x1; ++xx) {
            if (!sampleAt(xx, yy)) continue;
            const std::uint32_t c = colourAt(static_cast<std::size_t>(yy) * width + xx);
            ++weight;
            r += channel(c, 0);
            g += channel(c, 1);
            b += channel(c, 2);
          }
        }
        priority = kPrioritySparse;
      }
      if (weight == 0) {
        ++frame.holes;
        continue;
      }
      out[0] = static_cast<std::uint8_t>((r + weight / 2) / weight);
      out[1] = static_cast<std::uint8_t>((g + weight / 2) / weight);
      out[2] = static_cast<std::uint8_t>((b + weight / 2) / weight);
      out[3] = 255;
      frame.priority[pixel] = priority;
      if (priority == kPriorityDense) {
        ++frame.dense;
      } else {
        ++frame.sparse;
      }
    }
  }
  frame.seconds = secondsBetween(start, Clock::now());
  return frame;
}

}  // namespace pointillist::display
