#include "render/raster/eye_dome_lighting.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstring>
#include <limits>
#include <random>
#include <vector>

#include "common/errors.hpp"
#include "common/image.hpp"
#include "render/gl/tile_renderers.hpp"
#include "render/raster/cpu_point_renderer.hpp"
#include "render_test_util.hpp"

namespace pointillist::render {
namespace {

using testing::makeSplat;
using testing::mixedScene;

constexpr float kNothing = std::numeric_limits<float>::infinity();
constexpr Rgba8 kBackground{0, 0, 0, 255};

// A frame's colours and eye-space depths, both rows bottom-up.
struct Frame {
  std::uint32_t width = 0, height = 0;
  std::vector<std::uint8_t> rgba;
  std::vector<float> depth;

  Frame(std::uint32_t w, std::uint32_t h, Rgba8 colour, float z)
      : width(w), height(h), depth(std::size_t{w} * h, z) {
    for (std::size_t i = 0; i < depth.size(); ++i)
      rgba.insert(rgba.end(), colour.begin(), colour.end());
  }
  void set(std::uint32_t x, std::uint32_t y, Rgba8 colour, float z) {
    const std::size_t i = std::size_t{y} * width + x;
    std::copy(colour.begin(), colour.end(), rgba.begin() + static_cast<std::ptrdiff_t>(4 * i));
    depth[i] = z;
  }
  EdlImage image() const { return {rgba, depth, makeTileRect(0, 0, width, height), width, height}; }
  Image colours() const { return Image(width, height, rgba); }
};

Image shadeFrame(const Frame& frame, float strength = kDefaultEdlStrength,
                 float radius = kDefaultEdlRadius) {
  Image out(frame.width, frame.height);
  eyeDomeLighting(frame.image(), makeTileRect(0, 0, frame.width, frame.height), strength, radius,
                  out.bytes());
  return out;
}

int brightness(const Image& image, std::uint32_t x, std::uint32_t y) {
  const Rgba8 p = image.at(x, y);
  return p[0] + p[1] + p[2];
}

TEST(EyeDomeLighting, FlatDepthIsNotDarkened) {
  // A plane facing the camera: one eye-space depth everywhere.
  Frame frame(48, 40, {200, 150, 100, 255}, 7.5f);
  const Image shaded = shadeFrame(frame);
  const Image flat = frame.colours();
  for (std::uint32_t y = 1; y + 1 < frame.height; ++y) {
    for (std::uint32_t x = 1; x + 1 < frame.width; ++x) {
      ASSERT_EQ(shaded.at(x, y), flat.at(x, y)) << x << "," << y;
    }
  }
  // The frame's border sees beyond the frame, which counts as background.
  EXPECT_LT(brightness(shaded, 0, 20), brightness(flat, 0, 20));
  EXPECT_LT(brightness(shaded, 20, frame.height - 1), brightness(flat, 20, frame.height - 1));
}

TEST(EyeDomeLighting, DepthStepDarkensTheFarSideOnly) {
  // Near on the left (x < 30), far on the right: the step is a silhouette of
  // the near part against the far one.
  Frame frame(64, 48, {200, 200, 200, 255}, 4.0f);
  for (std::uint32_t y = 0; y < frame.height; ++y) {
    for (std::uint32_t x = 30; x < frame.width; ++x) frame.set(x, y, {200, 200, 200, 255}, 5.0f);
  }
  for (const float radius : {1.4f, 3.0f}) {
    const Image shaded = shadeFrame(frame, 1.0f, radius);
    const auto reach = static_cast<std::uint32_t>(std::lround(radius));
    for (std::uint32_t y = reach; y + reach < frame.height; ++y) {
      // The far side, within the radius of the step: darker, and more so nearer it.
      for (std::uint32_t x = 30; x < 30 + reach; ++x) {
        EXPECT_LT(brightness(shaded, x, y), 600 * 2 / 3) << "radius " << radius << " at " << x;
      }
      EXPECT_LE(brightness(shaded, 30, y), brightness(shaded, 30 + reach - 1, y));
      // The near side and the far side beyond the radius keep their colour.
      for (std::uint32_t x = reach; x < 30; ++x) EXPECT_EQ(brightness(shaded, x, y), 600) << x;
      for (std::uint32_t x = 30 + reach; x + reach < frame.width; ++x) {
        EXPECT_EQ(brightness(shaded, x, y), 600) << x;
      }
    }
  }
  // The darkening grows with the step and with the strength.
  const auto stepTo = [&](float far) {
    Frame stepped = frame;
    for (std::uint32_t y = 0; y < frame.height; ++y) {
      for (std::uint32_t x = 30; x < frame.width; ++x) stepped.set(x, y, {200, 200, 200, 255}, far);
    }
    return stepped;
  };
  const Frame small = stepTo(4.02f), larger = stepTo(4.06f);
  EXPECT_LT(brightness(shadeFrame(small), 30, 20), 600);
  EXPECT_GT(brightness(shadeFrame(small), 30, 20), brightness(shadeFrame(larger), 30, 20));
  EXPECT_GT(brightness(shadeFrame(small, 0.5f), 30, 20), brightness(shadeFrame(small), 30, 20));
}

TEST(EyeDomeLighting, BackgroundNeighboursDarkenSilhouettes) {
  Frame frame(40, 40, kBackground, kNothing);
  for (std::uint32_t y = 10; y < 30; ++y) {
    for (std::uint32_t x = 10; x < 30; ++x) frame.set(x, y, {180, 180, 180, 255}, 3.0f);
  }
  const Image shaded = shadeFrame(frame);
  for (std::uint32_t i = 11; i < 29; ++i) {
    // Edges of the square (three background neighbours) are darker...
    EXPECT_LT(brightness(shaded, 10, i), 540 / 2);
    EXPECT_LT(brightness(shaded, 29, i), 540 / 2);
    EXPECT_LT(brightness(shaded, i, 10), 540 / 2);
    EXPECT_LT(brightness(shaded, i, 29), 540 / 2);
    // ...than its inside, which keeps its colour; the background stays.
    EXPECT_EQ(brightness(shaded, i, 11), 540);
    EXPECT_EQ(shaded.at(i, 5), kBackground);
    EXPECT_EQ(shaded.at(9, i), kBackground);
  }
  // A corner has five background neighbours: darker still.
  EXPECT_LT(brightness(shaded, 10, 10), brightness(shaded, 10, 20));
}

// A random frame: a tilted, wavy surface with depth steps and holes of background.
Frame randomFrame(std::uint32_t w, std::uint32_t h, std::uint32_t seed) {
  Frame frame(w, h, kBackground, kNothing);
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  std::uniform_int_distribution<int> byte(0, 255);
  for (std::uint32_t y = 0; y < h; ++y) {
    for (std::uint32_t x = 0; x < w; ++x) {
      if (u(rng) < 0.1f) continue;  // background
      const auto fx = static_cast<float>(x), fy = static_cast<float>(y);
      float z = 10.0f + 0.05f * fx + 0.5f * std::sin(fy * 0.3f);
      if ((x / 13 + y / 7) % 3 == 0) z *= 0.8f;  // steps
      z *= 1.0f + 0.01f * u(rng);                // noise
      frame.set(x, y,
                {static_cast<std::uint8_t>(byte(rng)), static_cast<std::uint8_t>(byte(rng)),
                 static_cast<std::uint8_t>(byte(rng)), 255},
                z);
    }
  }
  return frame;
}

TEST(EyeDomeLighting, ATileWithItsHaloEqualsTheWholeFrame) {
  const Frame frame = randomFrame(97, 71, 5);
  const std::vector<TileRect> rects = {
      makeTileRect(0, 0, 97, 71), makeTileRect(0, 0, 20, 15), makeTileRect(77, 56, 20, 15),
      makeTileRect(0, 30, 97, 5), makeTileRect(40, 0, 1, 71), makeTileRect(33, 21, 30, 29),
      makeTileRect(96, 70, 1, 1), makeTileRect(1, 1, 95, 69), makeTileRect(50, 2, 7, 3)};
  for (const float radius : {1.0f, 1.4f, 2.5f, 4.0f}) {
    const Image whole = shadeFrame(frame, 1.3f, radius);
    for (const TileRect& rect : rects) {
      const TileRect grown = edlInputRect(rect, frame.width, frame.height, radius);
      // The grown rectangle as a renderer would draw it: a crop of the frame.
      const Image colours =
          crop(frame.colours(), grown.x(), grown.y(), grown.width(), grown.height());
      std::vector<float> depth;
      for (std::uint32_t y = grown.y(); y < grown.y() + grown.height(); ++y) {
        const auto row =
            frame.depth.begin() + static_cast<std::ptrdiff_t>(y * frame.width + grown.x());
        depth.insert(depth.end(), row, row + grown.width());
      }
      Image tile(rect.width(), rect.height());
      eyeDomeLighting({colours.bytes(), depth, grown, frame.width, frame.height}, rect, 1.3f,
                      radius, tile.bytes());
      const Image expected = crop(whole, rect.x(), rect.y(), rect.width(), rect.height());
      const ImageDiff diff = compareImages(expected, tile);
      EXPECT_EQ(diff.differingPixels, 0u)
          << "radius " << radius << ", rect " << rect.x() << "," << rect.y() << " " << rect.width()
          << "x" << rect.height() << ", first at " << diff.firstX << "," << diff.firstY;
    }
    // And the pass did something on this frame.
    EXPECT_GT(compareImages(whole, frame.colours()).differingPixels, 1000u);
  }
}

// The pass is SIMD, dispatched at run time: job tiles shaded on one machine
// must equal a reference frame shaded on another.
TEST(EyeDomeLighting, EveryTargetShadesAlike) {
  const Frame frame = randomFrame(203, 67, 9);
  const Image expected = shadeFrame(frame, 0.7f, 2.0f);
  // Through the CPU kernel too: its depth comes out of the packed words by SIMD.
  EdlTileRenderer renderer(std::make_unique<CpuPointRenderer>());
  const Camera camera = cameraForBounds({-1, -1, -1}, {1, 1, 1}, 203, 67, 35.0f, 25.0f, 0.8f);
  const std::vector<Splat> splats = mixedScene(20000, 4);
  renderer.uploadCell(0, splats);
  const DrawRange range{0, 0, static_cast<std::uint32_t>(splats.size())};
  RenderSettings settings;
  settings.edl.enabled = true;
  settings.keepDepth = true;
  const auto drawn = [&] {
    renderer.render(camera, fullFrameRect(camera), {&range, 1}, settings);
    return std::make_pair(Image(203, 67, renderer.pixels()),
                          std::vector<float>(renderer.depths().begin(), renderer.depths().end()));
  };
  const auto expectedDrawn = drawn();
  const std::vector<std::int64_t> targets = pointKernelTargets();
  for (const std::int64_t target : targets) {
    forcePointKernelTarget(target);
    SCOPED_TRACE(pointKernelTargetName());
    const ImageDiff diff = compareImages(expected, shadeFrame(frame, 0.7f, 2.0f));
    EXPECT_EQ(diff.differingPixels, 0u) << "first at " << diff.firstX << "," << diff.firstY;
    const auto again = drawn();
    EXPECT_EQ(compareImages(expectedDrawn.first, again.first).differingPixels, 0u);
    EXPECT_EQ(0, std::memcmp(expectedDrawn.second.data(), again.second.data(),
                             again.second.size() * sizeof(float)));
  }
  forcePointKernelTarget(0);
  EXPECT_GT(targets.size(), 1u);
}

TEST(EyeDomeLighting, HaloAndOffsets) {
  EXPECT_EQ(edlHaloPixels(1.0f), 1u);
  EXPECT_EQ(edlHaloPixels(1.4f), 2u);
  EXPECT_EQ(edlHaloPixels(3.0f), 3u);
  for (const float radius : {1.0f, 1.4f, 2.2f, 7.9f, 16.0f}) {
    const auto offsets = edlOffsets(radius);
    ASSERT_EQ(offsets.size(), 8u);
    for (const auto& [dx, dy] : offsets) {
      EXPECT_TRUE(dx != 0 || dy != 0) << radius;  // never the pixel itself
      EXPECT_LE(static_cast<std::uint32_t>(std::abs(dx)), edlHaloPixels(radius));
      EXPECT_LE(static_cast<std::uint32_t>(std::abs(dy)), edlHaloPixels(radius));
    }
  }
  // Grown and clamped to the frame.
  const TileRect grown = edlInputRect(makeTileRect(1, 10, 20, 5), 30, 16, 1.4f);
  EXPECT_EQ(grown.x(), 0u);
  EXPECT_EQ(grown.y(), 8u);
  EXPECT_EQ(grown.width(), 23u);
  EXPECT_EQ(grown.height(), 8u);
}

TEST(EyeDomeLighting, RefusesWhatItCannotShade) {
  const Frame frame = randomFrame(30, 20, 1);
  Image out(30, 20);
  const TileRect all = makeTileRect(0, 0, 30, 20);
  EXPECT_THROW(eyeDomeLighting(frame.image(), all, 1.0f, 0.5f, out.bytes()), UsageError);
  EXPECT_THROW(eyeDomeLighting(frame.image(), all, 0.0f, 1.4f, out.bytes()), UsageError);
  EXPECT_THROW(eyeDomeLighting(frame.image(), all, 1.0f, 17.0f, out.bytes()), UsageError);
  // An input without the halo the output needs.
  EdlImage part = frame.image();
  part.rect = makeTileRect(0, 0, 30, 20);
  Image small(10, 10);
  EXPECT_NO_THROW(eyeDomeLighting(part, makeTileRect(5, 5, 10, 10), 1.0f, 1.4f, small.bytes()));
  part.frameWidth = 40;  // the frame goes on to the right: column 30 is missing
  EXPECT_THROW(eyeDomeLighting(part, makeTileRect(19, 5, 10, 10), 1.0f, 1.4f, small.bytes()),
               UsageError);
  EXPECT_THROW(eyeDomeLighting(frame.image(), all, 1.0f, 1.4f, small.bytes()), UsageError);
  EXPECT_THROW(checkEdl(v1::RENDER_MODE_BLENDED, 1.0f, 1.4f), UsageError);
  EXPECT_NO_THROW(checkEdl(v1::RENDER_MODE_SPLATS, 1.0f, 1.4f));
}

// --- Through the renderers (CPU kernel and OSMesa), wrapped by makeTileRenderer.

Camera frontCamera(std::uint32_t w = 160, std::uint32_t h = 120) {
  return makeCamera({0, 0, 5}, {0, 0, 0}, {0, 1, 0}, 40.0f, 1.0f, 10.0f, w, h);
}

RenderSettings unlitPoints(bool edl) {
  RenderSettings settings;
  settings.mode = SplatMode::Points;
  settings.lighting = false;
  settings.edl.enabled = edl;
  return settings;
}

Image draw(TileRenderer& renderer, const Camera& camera, const TileRect& rect,
           std::span<const Splat> splats, const RenderSettings& settings) {
  renderer.uploadCell(0, splats);
  const DrawRange range{0, 0, static_cast<std::uint32_t>(splats.size())};
  renderer.render(camera, rect, {&range, 1}, settings);
  return Image(rect.width(), rect.height(), renderer.pixels());
}

// A grid of points on the plane z = zPlane, facing the camera, no normals.
void addPlane(std::vector<Splat>& splats, float zPlane, float half, std::uint8_t grey) {
  for (float y = -half; y <= half; y += 0.01f) {
    for (float x = -half; x <= half; x += 0.01f) {
      splats.push_back(makeSplat(x, y, zPlane, 0.012f, grey, grey, grey));
    }
  }
}

class EdlRenderers : public ::testing::TestWithParam<v1::Renderer> {
 protected:
  std::unique_ptr<TileRenderer> make() const {
    return makeTileRenderer(GetParam(), GlProfile::Compatibility, 2);
  }
};

TEST_P(EdlRenderers, DepthsAreEyeSpaceDistances) {
  const auto renderer = make();
  const Camera camera = frontCamera();
  const std::vector<Splat> splats = {makeSplat(0, 0, 0.5f, 0.05f, 255, 0, 0),
                                     makeSplat(-1, 0, -2.0f, 0.05f, 0, 255, 0)};
  RenderSettings settings = unlitPoints(false);
  settings.keepDepth = true;
  const TileRect rect = fullFrameRect(camera);
  draw(*renderer, camera, rect, splats, settings);
  const auto depths = renderer->depths();
  ASSERT_EQ(depths.size(), std::size_t{160} * 120);
  const auto at = [&](glm::vec3 p) {
    const glm::vec4 w = projectToWindow(camera, p);
    return depths[static_cast<std::size_t>(w.y) * 160 + static_cast<std::size_t>(w.x)];
  };
  EXPECT_NEAR(at({0, 0, 0.5f}), 4.5f, 1e-3f);
  EXPECT_NEAR(at({-1, 0, -2.0f}), 7.0f, 1e-3f);
  EXPECT_EQ(depths[0], kNothing);
  // Without keepDepth nothing is kept.
  draw(*renderer, camera, rect, splats, unlitPoints(false));
  EXPECT_TRUE(renderer->depths().empty());
}

TEST_P(EdlRenderers, UnlitStepsShowUnderEdlAndFlatPartsDoNot) {
  const auto renderer = make();
  const Camera camera = frontCamera(200, 150);
  // A small plane in front of a larger one: a depth step around the small one.
  std::vector<Splat> splats;
  addPlane(splats, 0.0f, 1.0f, 200);
  addPlane(splats, 0.6f, 0.3f, 200);
  const TileRect rect = fullFrameRect(camera);
  const Image plain = draw(*renderer, camera, rect, splats, unlitPoints(false));
  const Image shaded = draw(*renderer, camera, rect, splats, unlitPoints(true));
  EXPECT_GT(compareImages(plain, shaded).differingPixels, 200u) << renderer->describe();

  // Along a row through the small plane: where the depth steps from near to
  // far, the far pixel darkens and the near one does not (both are grey 200).
  RenderSettings withDepth = unlitPoints(false);
  withDepth.keepDepth = true;
  draw(*renderer, camera, rect, splats, withDepth);
  const std::vector<float> depths(renderer->depths().begin(), renderer->depths().end());
  const auto row = static_cast<std::uint32_t>(projectToWindow(camera, {0.0f, 0.0f, 0.6f}).y);
  int steps = 0;
  for (std::uint32_t x = 1; x + 1 < 200; ++x) {
    const float before = depths[std::size_t{row} * 200 + x - 1];
    const float here = depths[std::size_t{row} * 200 + x];
    if (!(before < 4.5f && here > 4.9f && here < 5.1f)) continue;  // near, then far
    ++steps;
    EXPECT_LT(shaded.at(x, row)[0], 150) << renderer->describe() << " at " << x;
    EXPECT_EQ(shaded.at(x - 1, row)[0], 200) << renderer->describe() << " at " << x;
    EXPECT_EQ(shaded.at(x + 2, row)[0], 200) << renderer->describe() << " at " << x;
  }
  EXPECT_EQ(steps, 1) << renderer->describe();
  // Flat parts facing the camera keep their colour.
  const glm::vec4 middleNear = projectToWindow(camera, {0.0f, 0.0f, 0.6f});
  const glm::vec4 middleFar = projectToWindow(camera, {0.7f, 0.6f, 0.0f});
  for (const glm::vec4 w : {middleNear, middleFar}) {
    const auto x = static_cast<std::uint32_t>(w.x), y = static_cast<std::uint32_t>(w.y);
    for (std::uint32_t dy = 0; dy < 5; ++dy) {
      for (std::uint32_t dx = 0; dx < 5; ++dx) {
        EXPECT_EQ(shaded.at(x + dx, y + dy), plain.at(x + dx, y + dy)) << renderer->describe();
      }
    }
  }
}

TEST_P(EdlRenderers, TilesMatchTheFullFrame) {
  const auto renderer = make();
  const Camera camera = cameraForBounds({-1, -1, -1}, {1, 1, 1}, 203, 151, 35.0f, 25.0f, 0.8f);
  const std::vector<Splat> splats = mixedScene(40000, 7);
  for (const bool lighting : {true, false}) {
    RenderSettings settings = unlitPoints(true);
    settings.lighting = lighting;
    settings.edl.radius = lighting ? 2.5f : 1.4f;
    const Image full = draw(*renderer, camera, fullFrameRect(camera), splats, settings);
    RenderSettings without = settings;
    without.edl.enabled = false;
    EXPECT_GT(compareImages(full, draw(*renderer, camera, fullFrameRect(camera), splats, without))
                  .differingPixels,
              2000u);
    Image tiled(203, 151, {1, 2, 3, 4});
    const std::uint32_t xs[] = {0, 1, 61, 128, 129, 202, 203}, ys[] = {0, 47, 100, 149, 151};
    for (int i = 0; i + 1 < 7; ++i) {
      for (int j = 0; j + 1 < 5; ++j) {
        const TileRect rect = makeTileRect(xs[i], ys[j], xs[i + 1] - xs[i], ys[j + 1] - ys[j]);
        blit(draw(*renderer, camera, rect, splats, settings), tiled, rect.x(), rect.y());
      }
    }
    const ImageDiff diff = compareImages(full, tiled);
    EXPECT_EQ(diff.differingPixels, 0u)
        << renderer->describe() << ", first at " << diff.firstX << "," << diff.firstY;
  }
}

INSTANTIATE_TEST_SUITE_P(CpuAndGl, EdlRenderers,
                         ::testing::Values(v1::RENDERER_CPU, v1::RENDERER_GL),
                         [](const ::testing::TestParamInfo<v1::Renderer>& tested) {
                           return std::string(rendererName(tested.param));
                         });

TEST(EdlRenderers, GlSplatsTilesMatchTheFullFrame) {
  const auto renderer = makeTileRenderer(v1::RENDERER_GL, GlProfile::Compatibility);
  const Camera camera = cameraForBounds({-1, -1, -1}, {1, 1, 1}, 160, 120, 35.0f, 25.0f, 0.8f);
  const std::vector<Splat> splats = mixedScene(20000, 3);
  RenderSettings settings;
  settings.mode = SplatMode::Splats;
  settings.edl.enabled = true;
  const Image full = draw(*renderer, camera, fullFrameRect(camera), splats, settings);
  Image tiled(160, 120);
  for (std::uint32_t y = 0; y < 120; y += 40) {
    for (std::uint32_t x = 0; x < 160; x += 53) {
      const TileRect rect = makeTileRect(x, y, std::min(53u, 160 - x), 40);
      blit(draw(*renderer, camera, rect, splats, settings), tiled, x, y);
    }
  }
  EXPECT_EQ(compareImages(full, tiled).differingPixels, 0u);
  settings.edl.enabled = false;
  EXPECT_GT(compareImages(full, draw(*renderer, camera, fullFrameRect(camera), splats, settings))
                .differingPixels,
            1000u);
}

TEST(EdlRenderers, BlendedModeIsRefused) {
  const auto renderer = makeTileRenderer(v1::RENDERER_GL, GlProfile::Compatibility);
  const Camera camera = frontCamera();
  const std::vector<Splat> splats = mixedScene(100, 2);
  RenderSettings settings;
  settings.mode = SplatMode::Blended;
  settings.edl.enabled = true;
  EXPECT_THROW(draw(*renderer, camera, fullFrameRect(camera), splats, settings), UsageError);
  settings.edl.enabled = false;
  EXPECT_NO_THROW(draw(*renderer, camera, fullFrameRect(camera), splats, settings));
}

}  // namespace
}  // namespace pointillist::render
