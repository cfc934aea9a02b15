#include "render/gl/splat_renderer.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "common/errors.hpp"
#include "render_test_util.hpp"

namespace pointillist::render {
namespace {

using testing::makeSplat;
using testing::mixedScene;

constexpr std::array<float, 4> kBlack{0.0f, 0.0f, 0.0f, 1.0f};

// Looks down -z at the origin from distance 5.
Camera frontCamera(std::uint32_t w = 160, std::uint32_t h = 120) {
  return makeCamera({0, 0, 5}, {0, 0, 0}, {0, 1, 0}, 40.0f, 1.0f, 10.0f, w, h);
}

std::vector<std::pair<std::uint32_t, std::uint32_t>> litPixels(const Image& image) {
  std::vector<std::pair<std::uint32_t, std::uint32_t>> lit;
  for (std::uint32_t y = 0; y < image.height(); ++y) {
    for (std::uint32_t x = 0; x < image.width(); ++x) {
      const Rgba8 p = image.at(x, y);
      if (p[0] != 0 || p[1] != 0 || p[2] != 0) lit.emplace_back(x, y);
    }
  }
  return lit;
}

RenderSettings settingsFor(SplatMode mode) {
  RenderSettings settings;
  settings.mode = mode;
  settings.clearColor = kBlack;
  return settings;
}

class Renderer : public ::testing::Test {
 protected:
  Image draw(const Camera& camera, std::span<const Splat> splats, const RenderSettings& settings) {
    renderer_.renderSplats(camera, fullFrameRect(camera), splats, settings);
    return context_.image();
  }

  OffscreenContext context_{1, 1, GlProfile::Compatibility};
  SplatRenderer renderer_{context_};
};

TEST_F(Renderer, KnownPointsLandOnTheirPixels) {
  const Camera camera = frontCamera();
  std::vector<Splat> splats;
  std::vector<std::pair<std::uint32_t, std::uint32_t>> expected;
  const float coords[][3] = {{0.0f, 0.0f, 0.0f},
                             {0.73f, 0.41f, 0.2f},
                             {-1.1f, -0.62f, -0.5f},
                             {1.3f, -0.9f, 1.0f},
                             {-0.35f, 0.87f, -2.0f}};
  for (const auto& c : coords) {
    splats.push_back(makeSplat(c[0], c[1], c[2], 0.001f, 255, 255, 255));
    const glm::vec4 w = projectToWindow(camera, {c[0], c[1], c[2]});
    expected.emplace_back(static_cast<std::uint32_t>(std::floor(w.x)),
                          static_cast<std::uint32_t>(std::floor(w.y)));
  }
  std::sort(expected.begin(), expected.end(),
            [](auto a, auto b) { return a.second != b.second ? a.second < b.second : a < b; });
  RenderSettings settings = settingsFor(SplatMode::Points);
  settings.pointSize = 1.0f;
  EXPECT_EQ(litPixels(draw(camera, splats, settings)), expected);
  // The origin lands at the frame centre: pixel (80, 60) touches it from above-right.
  EXPECT_EQ(expected[2], (std::pair<std::uint32_t, std::uint32_t>{80, 60}));
}

TEST_F(Renderer, PointSizeFollowsProjectedRadius) {
  const Camera camera = frontCamera();
  const float pixel = 1.0f / pixelsPerUnit(camera, 5.0f);  // world size of a pixel at z = 0
  auto count = [&](float radius, float pointSize, float scale) {
    const Splat s = makeSplat(0.013f, -0.021f, 0.0f, radius, 200, 100, 50);
    RenderSettings settings = settingsFor(SplatMode::Points);
    settings.pointSize = pointSize;
    settings.sizeScale = scale;
    return litPixels(draw(camera, {&s, 1}, settings)).size();
  };
  EXPECT_EQ(count(2.5f * pixel, 0.0f, 1.0f), 25u);   // diameter 5 px
  EXPECT_EQ(count(2.0f * pixel, 0.0f, 1.0f), 16u);   // diameter 4 px
  EXPECT_EQ(count(0.1f * pixel, 0.0f, 1.0f), 1u);    // never below one pixel
  EXPECT_EQ(count(2.5f * pixel, 3.0f, 1.0f), 9u);    // constant size
  EXPECT_EQ(count(2.5f * pixel, 0.0f, 2.0f), 100u);  // size scale
}

// GL clips points by their centre; the renderer's guard band keeps the part of
// a wide point (and of a splat) that reaches into the frame from outside.
TEST_F(Renderer, WidePointsJustOutsideTheFrameShowTheirInsidePart) {
  const Camera camera = frontCamera();
  const float ppu = pixelsPerUnit(camera, 5.0f);
  // Window position (-2.3, 60.4): centre snapped to (-2.5, 60.5); a 9 px
  // point covers x in [-7, 2), y in [56, 65).
  const Splat s =
      makeSplat((-2.3f - 80.0f) / ppu, (60.4f - 60.0f) / ppu, 0.0f, 0.001f, 255, 255, 255, 0, 0, 1);
  RenderSettings settings = settingsFor(SplatMode::Points);
  settings.pointSize = 9.0f;
  const auto lit = litPixels(draw(camera, {&s, 1}, settings));
  ASSERT_EQ(lit.size(), 18u);
  for (const auto& [x, y] : lit) {
    EXPECT_LE(x, 1u);
    EXPECT_GE(y, 56u);
    EXPECT_LE(y, 64u);
  }
  // A splat centred outside the frame shows its inside part too.
  const Splat disk =
      makeSplat((-3.0f - 80.0f) / ppu, 0.0f, 0.0f, 6.0f / ppu, 255, 255, 255, 0, 0, 1);
  EXPECT_GT(litPixels(draw(camera, {&disk, 1}, settingsFor(SplatMode::Splats))).size(), 10u);
}

TEST_F(Renderer, NearSplatWinsTheDepthTest) {
  const Camera camera = frontCamera();
  const Splat nearRed = makeSplat(0.1f, 0.1f, 0.5f, 0.05f, 255, 0, 0, 0, 0, 1);
  const Splat farGreen = makeSplat(0.1f, 0.1f, -0.5f, 0.05f, 0, 255, 0, 0, 0, 1);
  const glm::vec4 w = projectToWindow(camera, {0.1f, 0.1f, 0.5f});
  const auto x = static_cast<std::uint32_t>(w.x), y = static_cast<std::uint32_t>(w.y);
  for (const SplatMode mode : {SplatMode::Points, SplatMode::Splats}) {
    RenderSettings settings = settingsFor(mode);
    settings.lighting = false;
    const std::vector<Splat> nearFirst{nearRed, farGreen}, farFirst{farGreen, nearRed};
    EXPECT_EQ(draw(camera, nearFirst, settings).at(x, y), (Rgba8{255, 0, 0, 255}))
        << splatModeName(mode);
    EXPECT_EQ(draw(camera, farFirst, settings).at(x, y), (Rgba8{255, 0, 0, 255}))
        << splatModeName(mode);
  }
}

TEST_F(Renderer, SplatDiskCoversItsProjectedRadius) {
  const Camera camera = frontCamera(200, 200);
  const float radiusPixels = 12.0f;
  const float radius = radiusPixels / pixelsPerUnit(camera, 5.0f);
  const Splat s = makeSplat(0.0f, 0.0f, 0.0f, radius, 255, 255, 255, 0, 0, 1);
  const Image image = draw(camera, {&s, 1}, settingsFor(SplatMode::Splats));
  std::size_t lit = 0;
  for (std::uint32_t y = 0; y < 200; ++y) {
    for (std::uint32_t x = 0; x < 200; ++x) {
      const float d =
          std::hypot(static_cast<float>(x) + 0.5f - 100.0f, static_cast<float>(y) + 0.5f - 100.0f);
      const bool on = image.at(x, y)[0] != 0;
      lit += on ? 1 : 0;
      if (d < radiusPixels - 0.05f) {
        EXPECT_TRUE(on) << x << "," << y;
      }
      if (d > radiusPixels + 0.05f) {
        EXPECT_FALSE(on) << x << "," << y;
      }
    }
  }
  const double area = 3.14159265 * static_cast<double>(radiusPixels * radiusPixels);
  EXPECT_NEAR(static_cast<double>(lit), area, area * 0.03);
  // Face-on with a headlight: full brightness.
  EXPECT_EQ(image.at(100, 100), (Rgba8{255, 255, 255, 255}));

  // Tilted 60 degrees about x: an ellipse half as tall, darker.
  const float c = std::cos(glm::radians(60.0f)), sn = std::sin(glm::radians(60.0f));
  const Splat tilted = makeSplat(0.0f, 0.0f, 0.0f, radius, 255, 255, 255, 0, sn, c);
  const Image ellipse = draw(camera, {&tilted, 1}, settingsFor(SplatMode::Splats));
  std::uint32_t minY = 200, maxY = 0, minX = 200, maxX = 0;
  for (const auto& [x, y] : litPixels(ellipse)) {
    minX = std::min(minX, x);
    maxX = std::max(maxX, x);
    minY = std::min(minY, y);
    maxY = std::max(maxY, y);
  }
  EXPECT_NEAR(static_cast<float>(maxX - minX + 1), 2.0f * radiusPixels, 1.5f);
  EXPECT_NEAR(static_cast<float>(maxY - minY + 1), 2.0f * radiusPixels * c, 1.5f);
  EXPECT_LT(ellipse.at(100, 100)[0], 255);
  EXPECT_GT(ellipse.at(100, 100)[0], 100);
}

TEST_F(Renderer, BlendedModeAveragesOverlapsAndHidesWhatIsBehind) {
  const Camera camera = frontCamera(200, 200);
  const float radius = 10.0f / pixelsPerUnit(camera, 5.0f);  // 10 px
  const float shift = 5.0f / pixelsPerUnit(camera, 5.0f);
  RenderSettings settings = settingsFor(SplatMode::Blended);
  settings.lighting = false;
  // Two coplanar disks overlapping around the centre: the middle mixes both,
  // each side keeps its own colour.
  const std::vector<Splat> pair{makeSplat(-shift, 0, 0, radius, 255, 0, 0, 0, 0, 1),
                                makeSplat(shift, 0, 0, radius, 0, 0, 255, 0, 0, 1)};
  const Image mixed = draw(camera, pair, settings);
  // Pixel (100, 100) is centred 5.5 px from the red and 4.5 px from the blue centre.
  const double wRed = std::exp(-2.0 * 0.55 * 0.55), wBlue = std::exp(-2.0 * 0.45 * 0.45);
  const Rgba8 middle = mixed.at(100, 100);
  EXPECT_NEAR(middle[0], 255.0 * wRed / (wRed + wBlue), 1.5);
  EXPECT_NEAR(middle[2], 255.0 * wBlue / (wRed + wBlue), 1.5);
  EXPECT_EQ(middle[3], 255);
  EXPECT_EQ(mixed.at(88, 100), (Rgba8{255, 0, 0, 255}));
  EXPECT_EQ(mixed.at(111, 100), (Rgba8{0, 0, 255, 255}));
  EXPECT_EQ(mixed.at(100, 150), (Rgba8{0, 0, 0, 255}));  // background
  // A disk well behind (5 radii) is hidden, not blended.
  const std::vector<Splat> occluded{makeSplat(0, 0, 0, radius, 255, 0, 0, 0, 0, 1),
                                    makeSplat(0, 0, -5.0f * radius, radius, 0, 255, 0, 0, 0, 1)};
  EXPECT_EQ(draw(camera, occluded, settings).at(100, 100), (Rgba8{255, 0, 0, 255}));
}

TEST_F(Renderer, TinyDistantSplatsStayVisible) {
  const Camera camera = frontCamera();
  const Splat s = makeSplat(0.31f, 0.17f, -4.0f, 1e-5f, 255, 255, 255, 0, 0, 1);
  EXPECT_GE(litPixels(draw(camera, {&s, 1}, settingsFor(SplatMode::Splats))).size(), 1u);
}

// Splits the scene into cells, uploads them, and renders a rect drawing the
// splats that survive tile culling (runs of kept splats become ranges).
struct CellScene {
  std::vector<std::vector<Splat>> cells;
};

std::vector<DrawRange> culledRanges(const CellScene& scene, const Camera& camera,
                                    const TileRect& rect, float sizeScale) {
  const FrustumPlanes planes = tilePlanes(camera, rect, 1.0f);
  std::vector<DrawRange> ranges;
  for (std::uint32_t c = 0; c < scene.cells.size(); ++c) {
    const auto& cell = scene.cells[c];
    for (std::uint32_t i = 0; i < cell.size();) {
      const Splat& s = cell[i];
      const glm::vec3 p(s.position[0], s.position[1], s.position[2]);
      if (sphereOutside(planes, p, s.radius * sizeScale)) {
        ++i;
        continue;
      }
      // Extend the run.
      std::uint32_t j = i + 1;
      for (; j < cell.size(); ++j) {
        const Splat& t = cell[j];
        if (sphereOutside(planes, {t.position[0], t.position[1], t.position[2]},
                          t.radius * sizeScale)) {
          break;
        }
      }
      ranges.push_back({c, i, j - i});
      i = j;
    }
  }
  return ranges;
}

void expectTilesMatchFullFrame(GlProfile profile, SplatMode mode, bool cull) {
  OffscreenContext context(1, 1, profile);
  SplatRenderer renderer(context);
  const std::vector<Splat> all = mixedScene(30000, 11);
  CellScene scene;
  for (std::size_t i = 0; i < 3; ++i) {
    const auto begin = all.begin() + static_cast<std::ptrdiff_t>(i * all.size() / 3);
    const auto end = all.begin() + static_cast<std::ptrdiff_t>((i + 1) * all.size() / 3);
    scene.cells.emplace_back(begin, end);
  }
  // Cell ids need not be dense.
  const std::uint32_t ids[] = {0, 1, 2};
  for (std::uint32_t c = 0; c < 3; ++c) renderer.uploadCell(ids[c], scene.cells[c]);

  const Camera camera = cameraForBounds({-1, -1, -1}, {1, 1, 1}, 257, 190, 35.0f, 25.0f, 0.8f);
  RenderSettings settings;
  settings.mode = mode;
  settings.clearColor = {0.1f, 0.2f, 0.3f, 1.0f};
  settings.sizeScale = 1.5f;

  std::vector<DrawRange> everything;
  for (std::uint32_t c = 0; c < 3; ++c) {
    everything.push_back({c, 0, static_cast<std::uint32_t>(scene.cells[c].size())});
  }
  const auto fullStats = renderer.render(camera, fullFrameRect(camera), everything, settings);
  EXPECT_EQ(fullStats.splats, all.size());
  const Image full = context.image();
  EXPECT_GT(litPixels(full).size(), 1000u);

  Image tiled(257, 190, {1, 2, 3, 4});
  const std::uint32_t xs[] = {0, 61, 128, 129, 200, 257}, ys[] = {0, 47, 100, 190};
  std::uint64_t drawn = 0;
  for (int i = 0; i + 1 < 6; ++i) {
    for (int j = 0; j + 1 < 4; ++j) {
      const TileRect rect = makeTileRect(xs[i], ys[j], xs[i + 1] - xs[i], ys[j + 1] - ys[j]);
      const std::vector<DrawRange> ranges =
          cull ? culledRanges(scene, camera, rect, settings.sizeScale) : everything;
      drawn += renderer.render(camera, rect, ranges, settings).splats;
      blit(context.image(), tiled, rect.x(), rect.y());
    }
  }
  if (cull) {
    EXPECT_LT(drawn, 15 * all.size() / 2);  // culling did cull
  }
  const ImageDiff diff = compareImages(full, tiled);
  EXPECT_EQ(diff.differingPixels, 0u)
      << profileName(profile) << " " << splatModeName(mode) << " first at " << diff.firstX << ","
      << diff.firstY << " max diff " << diff.maxChannelDifference;
}

TEST(TiledRendering, PointsTilesMatchFullFrame) {
  expectTilesMatchFullFrame(GlProfile::Compatibility, SplatMode::Points, false);
}

TEST(TiledRendering, SplatsTilesMatchFullFrame) {
  expectTilesMatchFullFrame(GlProfile::Compatibility, SplatMode::Splats, false);
}

TEST(TiledRendering, CulledTilesMatchFullFrame) {
  expectTilesMatchFullFrame(GlProfile::Compatibility, SplatMode::Points, true);
  expectTilesMatchFullFrame(GlProfile::Compatibility, SplatMode::Splats, true);
}

TEST(TiledRendering, BlendedTilesMatchFullFrame) {
  expectTilesMatchFullFrame(GlProfile::Compatibility, SplatMode::Blended, true);
}

// Regression: tiles at the same origin whose heights differ (Mesa kept the old
// height in gl_FragCoord's y flip when no uniform changed).
TEST(TiledRendering, SameOriginDifferentHeights) {
  OffscreenContext context(1, 1);
  SplatRenderer renderer(context);
  const Camera camera = frontCamera(120, 100);
  const Splat s = makeSplat(0.2f, 0.1f, 0.0f, 0.3f, 255, 255, 255, 0, 0, 1);
  renderer.uploadCell(0, {&s, 1});
  const DrawRange range{0, 0, 1};
  const RenderSettings settings = settingsFor(SplatMode::Splats);
  renderer.render(camera, fullFrameRect(camera), {&range, 1}, settings);
  const Image full = context.image();
  ASSERT_GT(litPixels(full).size(), 10u);
  for (const std::uint32_t h : {99u, 90u, 73u, 100u, 64u}) {
    renderer.render(camera, makeTileRect(0, 0, 120, h), {&range, 1}, settings);
    EXPECT_EQ(compareImages(crop(full, 0, 0, 120, h), context.image()).differingPixels, 0u) << h;
  }
}

TEST(TiledRendering, CoreProfileTilesMatchFullFrame) {
  expectTilesMatchFullFrame(GlProfile::Core, SplatMode::Points, true);
  expectTilesMatchFullFrame(GlProfile::Core, SplatMode::Splats, true);
}

TEST_F(Renderer, CellCacheAndRangeChecks) {
  const std::vector<Splat> a = mixedScene(100, 1), b = mixedScene(50, 2);
  renderer_.uploadCell(7, a);
  renderer_.uploadCell(9, b);
  EXPECT_TRUE(renderer_.hasCell(7));
  EXPECT_EQ(renderer_.cellCount(), 2u);
  EXPECT_EQ(renderer_.cellSplatCount(9), 50u);
  EXPECT_EQ(renderer_.uploadedBytes(), 150u * sizeof(Splat));
  renderer_.uploadCell(9, a);  // replaces
  EXPECT_EQ(renderer_.uploadedBytes(), 200u * sizeof(Splat));

  const Camera camera = frontCamera();
  const RenderSettings settings = settingsFor(SplatMode::Points);
  const std::vector<DrawRange> ok{{7, 10, 20}, {9, 0, 100}, {7, 0, 5}};
  const RenderStats stats = renderer_.render(camera, makeTileRect(10, 10, 50, 40), ok, settings);
  EXPECT_EQ(stats.splats, 125u);
  EXPECT_EQ(stats.drawCalls, 2u);
  EXPECT_EQ(context_.width(), 50u);
  EXPECT_EQ(context_.height(), 40u);

  const std::vector<DrawRange> overflow{{7, 90, 11}};
  EXPECT_THROW(renderer_.render(camera, fullFrameRect(camera), overflow, settings), UsageError);
  const std::vector<DrawRange> unknown{{8, 0, 1}};
  EXPECT_THROW(renderer_.render(camera, fullFrameRect(camera), unknown, settings), UsageError);
  EXPECT_THROW(renderer_.render(camera, makeTileRect(150, 0, 20, 10), ok, settings), UsageError);

  renderer_.releaseCell(7);
  renderer_.releaseCell(12345);  // unknown: no-op
  EXPECT_FALSE(renderer_.hasCell(7));
  EXPECT_EQ(renderer_.uploadedBytes(), 100u * sizeof(Splat));
  renderer_.releaseAll();
  EXPECT_EQ(renderer_.cellCount(), 0u);
  EXPECT_EQ(renderer_.uploadedBytes(), 0u);

  // No ranges: just the clear colour.
  RenderSettings grey = settings;
  grey.clearColor = {0.5f, 0.5f, 0.5f, 1.0f};
  renderer_.render(camera, fullFrameRect(camera), {}, grey);
  EXPECT_TRUE(litPixels(context_.image()).size() == 160u * 120u);
}

// GL object names are per context: releasing a cell of one renderer while
// another context is current must not touch the other's buffers.
TEST(SplatRendererContexts, RenderersInTwoContextsStayApart) {
  OffscreenContext contextA(1, 1), contextB(1, 1);
  SplatRenderer a(contextA), b(contextB);
  const Splat s = makeSplat(0.0f, 0.0f, 0.0f, 0.2f, 255, 255, 255, 0, 0, 1);
  a.uploadCell(0, {&s, 1});
  b.uploadCell(0, {&s, 1});
  const Camera camera = frontCamera();
  const DrawRange range{0, 0, 1};
  const RenderSettings settings = settingsFor(SplatMode::Points);
  b.render(camera, fullFrameRect(camera), {&range, 1}, settings);
  const std::size_t litBefore = litPixels(contextB.image()).size();
  a.releaseCell(0);  // contextB is current here
  b.render(camera, fullFrameRect(camera), {&range, 1}, settings);
  EXPECT_GT(litBefore, 0u);
  EXPECT_EQ(litPixels(contextB.image()).size(), litBefore);
}

TEST(SplatMode, FromProtoAndNames) {
  EXPECT_EQ(splatModeFromProto(v1::RENDER_MODE_POINTS), SplatMode::Points);
  EXPECT_EQ(splatModeFromProto(v1::RENDER_MODE_SPLATS), SplatMode::Splats);
  EXPECT_EQ(splatModeFromProto(v1::RENDER_MODE_STATISTICAL), SplatMode::Statistical);
  EXPECT_EQ(splatModeToProto(SplatMode::Statistical), v1::RENDER_MODE_STATISTICAL);
  EXPECT_EQ(parseSplatMode("statistical"), SplatMode::Statistical);
  EXPECT_STREQ(splatModeName(SplatMode::Statistical), "statistical");
  EXPECT_THROW(splatModeFromProto(v1::RENDER_MODE_UNSPECIFIED), UsageError);
  EXPECT_EQ(parseSplatMode("splats"), SplatMode::Splats);
  EXPECT_EQ(parseSplatMode("blended"), SplatMode::Blended);
  EXPECT_THROW(parseSplatMode("ewa"), UsageError);
}

}  // namespace
}  // namespace pointillist::render
