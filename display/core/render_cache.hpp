#pragma once
// Seed 001's render cache at the display (MPI-free): the samples of recent
// final frames kept as coloured 3D points with an age, reprojected to a new
// camera at once, so a client sees an interim frame while the tiles of the
// exact one are still being drawn, and the tiles where the cache knows least
// are drawn first.
//
//   insert     a final frame with its eye-space depth. Each covered pixel
//              becomes a point (the pixel centre at its depth). A cached
//              point that lands on that pixel at about that depth is
//              replaced by it; one that lands in front of the frame's
//              surface, or where the frame shows background, was wrong and
//              goes; hidden ones behind it stay. Points not seen again age
//              and leave after maxAge frames; when the cache is full the
//              eldest make room (the paper's fixed-size point cloud). The
//              cloud is rebuilt in the frame's pixel order, so the next
//              reprojection (a camera close to this one) reads it in order.
//   reproject  one pass over the points with a z-buffer whose words carry
//              depth, colour and age (projection in blocks the compiler
//              vectorises, then one compare per point, no branch), then a
//              pipeline down the rows, each pass a few rows behind the last
//              so the rows it reads are still in cache: each z-buffer row
//              read once (split into depth and payload rows, and cleared for
//              the next frame), the depth cull (a sample goes when
//              every side of its 7x7 neighbourhood holds a nearer one, by
//              more than depthCullFraction: it shows through a gap of a
//              nearer surface; the paper's filtered depth, per side),
//              colour and priority (age of the sample, or how far the
//              nearest samples are), interpolation (a 3x3 centre-weighted
//              kernel where neighbours remain, a 7x7 box where samples are
//              sparse).
//
// The whole-image passes also get an AVX2 build chosen at load time. On this
// project's 2-core VM a 1280x720 reprojection takes about 7 ms on one core
// for a fully covered frame and 1.25 M cached points, 4 ms for a quarter
// covered one (pointillist-bench-render-cache).
#include <array>
#include <cstdint>
#include <shared_mutex>
#include <span>
#include <vector>

#include "common/camera.hpp"
#include "common/image.hpp"

namespace pointillist::display {

struct RenderCacheOptions {
  // Points held; 0: twice the pixels of the first frame inserted.
  std::size_t capacity = 0;
  // Final frames a point survives without being seen again.
  std::uint32_t maxAge = 16;
  // Depth cull threshold, relative to the filtered depth. The paper pushes
  // its filtered depth back by 5 % of the scene's size; relative to the depth
  // itself the same test holds for a camera in a street and far above a city.
  float depthCullFraction = 0.05f;
  // Refresh in place when a cached point lies within this share of the
  // frame's depth at its pixel.
  float sameSurfaceFraction = 0.02f;
  Rgba8 background{0, 0, 0, 255};
};

// Priority image values (0: nothing to gain from a new sample, 255: no sample
// anywhere near). A sample's priority grows with its age.
inline constexpr std::uint8_t kPriorityFreshSample = 0;
inline constexpr std::uint8_t kPriorityPerAge = 12;
inline constexpr std::uint8_t kPriorityDense = 128;   // filled from the 3x3 neighbourhood
inline constexpr std::uint8_t kPrioritySparse = 192;  // filled from the 7x7 neighbourhood
inline constexpr std::uint8_t kPriorityHole = 255;

struct InterimFrame {
  Image image;
  // One value per pixel, rows bottom-up as the image.
  UninitializedBytes priority;
  std::uint64_t pointsInView = 0;  // points that landed on a pixel (before the z-test)
  std::uint64_t samples = 0;       // pixels showing a cached point
  std::uint64_t culled = 0;        // samples the depth cull removed
  std::uint64_t dense = 0;         // pixels interpolated from the 3x3 neighbourhood
  std::uint64_t sparse = 0;        // ... from the 7x7 neighbourhood
  std::uint64_t holes = 0;         // pixels left at the background colour
  double seconds = 0.0;            // reproject() from start to end
  std::uint64_t pixels() const { return samples + dense + sparse + holes; }
  // Pixels the cache coloured (sampled or interpolated), over all pixels.
  double filledShare() const;
};

// Mean priority of the pixels of `rect` (0 when the frame has no priority image).
double meanPriority(const InterimFrame& frame, const TileRect& rect);

struct RenderCacheCounters {
  std::uint64_t framesInserted = 0;
  std::uint64_t refreshed = 0;  // points refreshed in place
  std::uint64_t added = 0;      // new points
  std::uint64_t removedWrong = 0;
  std::uint64_t removedOld = 0;   // past maxAge
  std::uint64_t evictedFull = 0;  // eldest, to make room
};

// One insert and one reprojection may run at the same time on two threads
// (a display inserts the last final frame while it reprojects for the next
// camera): insert builds the new cloud beside the old one and swaps them
// under a lock, and the two keep their own scratch. Two inserts, or two
// reprojections, at once are not allowed, nor clear() or counters() during
// an insert.
class RenderCache {
 public:
  explicit RenderCache(RenderCacheOptions options = {});

  // The cache's view from `camera` (any image size); not a copy of any frame,
  // so it may be called for every camera a client sends.
  InterimFrame reproject(const Camera& camera);
  // A final frame of `camera`: `depth` holds each pixel's eye-space depth as
  // the image (rows bottom-up), +infinity (or any non-finite value) where
  // the frame shows background. Throws UsageError on a size mismatch.
  void insert(const Camera& camera, const Image& image, std::span<const float> depth);

  std::size_t size() const;
  std::size_t capacity() const { return options_.capacity; }
  bool empty() const { return size() == 0; }
  std::uint32_t oldestAge() const;
  const RenderCacheCounters& counters() const { return counters_; }
  const RenderCacheOptions& options() const { return options_; }
  void clear();

 private:
  // What the z-buffer keeps of the nearest point beside its depth.
  enum class Payload { pointIndex, colourAndAge };
  struct ZBuffer {
    std::vector<std::uint64_t> words;       // depth bits above, the payload below
    bool clear = false;                     // all empty: project need not clear it
    std::vector<std::uint32_t> blockPixel;  // projection of a block of points
    std::vector<std::uint32_t> blockDepth;
  };
  // Fills `zbuffer` with the nearest point per pixel of `camera`'s frame;
  // returns how many points landed in the frame.
  std::uint64_t project(const Camera& camera, Payload payload, ZBuffer& zbuffer) const;
  void interpolateRow(std::uint32_t y, const float* boxMin, InterimFrame& frame);

  // Structure of arrays, so that the projection streams the positions.
  struct Points {
    std::vector<float> x, y, z;
    // RGB as in the image's bytes, the age in place of alpha: the z-buffer
    // payload as it is (one stream less to read).
    std::vector<std::uint32_t> colourAndAge;
    std::size_t size() const { return x.size(); }
    void clear();
    void reserve(std::size_t count);
    void push(const glm::vec3& position, std::uint32_t rgba, std::uint8_t pointAge);
    std::uint8_t age(std::size_t i) const {
      return static_cast<std::uint8_t>(colourAndAge[i] >> 24);
    }
  };

  RenderCacheOptions options_;
  // Read by both; swapped (written) only by insert, under a unique lock.
  mutable std::shared_mutex pointsMutex_;
  Points points_;
  // Each insert builds the new cloud here, then the two swap (the scratch
  // keeps its memory for the next frame).
  Points next_;
  std::vector<std::uint8_t> taken_;  // per cached point: replaced or removed by this insert
  // Scratch kept between calls (fresh pages cost more than the work here).
  ZBuffer insertZbuffer_;
  ZBuffer zbuffer_;  // reproject's
  // Rows of reproject's pipeline (see there).
  std::vector<float> sampleDepth_;                         // the z-buffer's depths
  std::vector<std::uint32_t> samplePayload_;               // ... and payloads
  std::vector<float> shownDepth_;                          // a row's depths after the cull
  std::vector<float> columnMinDepth_;                      // least depth over 7 rows
  std::vector<float> rowMinDepth_;                         // least depth over 7 columns
  std::vector<float> boxMinDepth_;                         // least depth over the 7x7 box
  std::vector<std::array<std::uint32_t, 4>> columnBlend_;  // sparse interpolation: 7-row sums
  std::vector<std::uint32_t> columnBlendRow_;              // the row each column sum is for
  std::vector<std::uint32_t> candidates_;                  // a row's pixels to interpolate
  RenderCacheCounters counters_;
};

}  // namespace pointillist::display
