#include "render/raster/cpu_point_renderer.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <random>
#include <vector>

#include "common/errors.hpp"
#include "common/image.hpp"
#include "display/core/tile_parts.hpp"
#include "render/gl/tile_renderers.hpp"
#include "render_test_util.hpp"

namespace pointillist::render {
namespace {

using testing::makeSplat;
using testing::mixedScene;

Camera frontCamera(std::uint32_t w = 160, std::uint32_t h = 120) {
  return makeCamera({0, 0, 5}, {0, 0, 0}, {0, 1, 0}, 40.0f, 1.0f, 10.0f, w, h);
}

RenderSettings pointSettings() {
  RenderSettings settings;
  settings.mode = SplatMode::Points;
  settings.clearColor = {0.0f, 0.0f, 0.0f, 1.0f};
  return settings;
}

Image draw(TileRenderer& renderer, const Camera& camera, const TileRect& rect,
           std::span<const Splat> splats, const RenderSettings& settings) {
  renderer.uploadCell(0, splats);
  const DrawRange range{0, 0, static_cast<std::uint32_t>(splats.size())};
  const RenderStats stats = renderer.render(camera, rect, {&range, 1}, settings);
  EXPECT_EQ(stats.splats, splats.size());
  return Image(rect.width(), rect.height(), renderer.pixels());
}

Image drawFrame(TileRenderer& renderer, const Camera& camera, std::span<const Splat> splats,
                const RenderSettings& settings) {
  return draw(renderer, camera, fullFrameRect(camera), splats, settings);
}

std::uint64_t litCount(const Image& image) {
  std::uint64_t lit = 0;
  for (std::uint32_t y = 0; y < image.height(); ++y) {
    for (std::uint32_t x = 0; x < image.width(); ++x) {
      const Rgba8 p = image.at(x, y);
      lit += (p[0] | p[1] | p[2]) != 0 ? 1u : 0u;
    }
  }
  return lit;
}

TEST(CpuPointRenderer, KnownPointsLandOnTheirPixels) {
  const Camera camera = frontCamera();
  std::vector<Splat> splats;
  const float coords[][3] = {{0.0f, 0.0f, 0.0f},
                             {0.73f, 0.41f, 0.2f},
                             {-1.1f, -0.62f, -0.5f},
                             {1.3f, -0.9f, 1.0f},
                             {-0.35f, 0.87f, -2.0f}};
  for (const auto& c : coords) splats.push_back(makeSplat(c[0], c[1], c[2], 0.001f, 255, 255, 255));
  RenderSettings settings = pointSettings();
  settings.pointSize = 1.0f;
  CpuPointRenderer renderer;
  const Image image = drawFrame(renderer, camera, splats, settings);
  EXPECT_EQ(litCount(image), std::size(coords));
  for (const auto& c : coords) {
    const glm::vec4 w = projectToWindow(camera, {c[0], c[1], c[2]});
    const Rgba8 p = image.at(static_cast<std::uint32_t>(std::floor(w.x)),
                             static_cast<std::uint32_t>(std::floor(w.y)));
    EXPECT_EQ(p, (Rgba8{255, 255, 255, 255})) << c[0] << "," << c[1] << "," << c[2];
  }
}

// The CPU kernel draws what GL points draw: same squares at the same places.
// Rounding at pixel boundaries may differ in a handful of pixels.
TEST(CpuPointRenderer, CoversThePixelsGlPointsCover) {
  const Camera camera = cameraForBounds({-1, -1, -1}, {1, 1, 1}, 257, 190, 35.0f, 25.0f, 0.8f);
  const std::vector<Splat> splats = mixedScene(20000, 5);
  RenderSettings settings = pointSettings();
  settings.lighting = false;
  CpuPointRenderer cpu;
  const auto gl = makeTileRenderer(v1::RENDERER_GL, GlProfile::Compatibility);
  const Image a = drawFrame(cpu, camera, splats, settings);
  const Image b = drawFrame(*gl, camera, splats, settings);
  std::uint64_t coverageDiffers = 0;
  for (std::uint32_t y = 0; y < a.height(); ++y) {
    for (std::uint32_t x = 0; x < a.width(); ++x) {
      const Rgba8 p = a.at(x, y), q = b.at(x, y);
      coverageDiffers += ((p[0] | p[1] | p[2]) != 0) != ((q[0] | q[1] | q[2]) != 0) ? 1u : 0u;
    }
  }
  const std::uint64_t lit = litCount(b);
  EXPECT_GT(lit, 15000u);
  EXPECT_LT(coverageDiffers, lit / 200) << "of " << lit << " lit pixels";
  // Where both draw, the nearest splat wins in both: most pixels are equal.
  const ImageDiff diff = compareImages(a, b);
  EXPECT_LT(diff.differingPixels, lit / 20);
}

TEST(CpuPointRenderer, TilesAndThreadsMatchTheFullFrame) {
  const Camera camera = cameraForBounds({-1, -1, -1}, {1, 1, 1}, 257, 190, 35.0f, 25.0f, 0.8f);
  const std::vector<Splat> splats = mixedScene(60000, 11);
  RenderSettings settings = pointSettings();
  settings.clearColor = {0.1f, 0.2f, 0.3f, 1.0f};
  settings.sizeScale = 1.5f;
  CpuPointRenderer single(1);
  const Image full = drawFrame(single, camera, splats, settings);
  EXPECT_GT(litCount(full), 10000u);

  CpuPointRenderer threaded(4);
  EXPECT_EQ(compareImages(full, drawFrame(threaded, camera, splats, settings)).differingPixels, 0u);

  Image tiled(257, 190, {1, 2, 3, 4});
  const std::uint32_t xs[] = {0, 61, 128, 129, 200, 257}, ys[] = {0, 47, 100, 190};
  for (int i = 0; i + 1 < 6; ++i) {
    for (int j = 0; j + 1 < 4; ++j) {
      const TileRect rect = makeTileRect(xs[i], ys[j], xs[i + 1] - xs[i], ys[j + 1] - ys[j]);
      blit(draw(threaded, camera, rect, splats, settings), tiled, rect.x(), rect.y());
    }
  }
  const ImageDiff diff = compareImages(full, tiled);
  EXPECT_EQ(diff.differingPixels, 0u) << "first at " << diff.firstX << "," << diff.firstY;
}

// A split tile (docs/scheduling.md §9): parts drawn by different renderers
// from different cells, sent as the kernel's words and composed by the
// display's TilePartCompositor in any order, equal the tile drawn whole.
TEST(CpuPointRenderer, SplitTilePartsComposedAtTheDisplayEqualTheWholeTile) {
  const Camera camera = cameraForBounds({-1, -1, -1}, {1, 1, 1}, 257, 190, 35.0f, 25.0f, 0.8f);
  std::vector<Splat> splats = mixedScene(40000, 21);
  // Cells of nearby points, as the octree's are, so parts draw in a part of the tile.
  std::sort(splats.begin(), splats.end(),
            [](const Splat& a, const Splat& b) { return a.position[0] < b.position[0]; });
  // Exact depth ties across parts: the same position in two cells, two colours.
  for (int i = 0; i < 200; ++i) {
    Splat twin = splats[static_cast<std::size_t>(i) * 7];
    twin.color[1] = static_cast<std::uint8_t>(twin.color[1] ^ 0x3c);
    splats.push_back(twin);
  }
  RenderSettings settings = pointSettings();
  settings.clearColor = {0.0f, 0.0f, 0.0f, 1.0f};  // the display's background
  const TileRect rect = makeTileRect(37, 21, 150, 111);
  CpuPointRenderer whole(1);
  const Image expected = draw(whole, camera, rect, splats, settings);
  EXPECT_GT(litCount(expected), 5000u);

  // Five cells of different sizes, drawn as three parts on three renderers.
  const std::uint32_t cellEnd[] = {9000, 9001, 22000, 31000,
                                   static_cast<std::uint32_t>(splats.size())};
  const std::vector<std::vector<std::uint32_t>> partCells = {{0, 1}, {2}, {3, 4}};
  std::vector<std::vector<std::uint64_t>> partWords;
  for (const auto& cells : partCells) {
    CpuPointRenderer renderer(2);
    std::vector<DrawRange> ranges;
    for (std::uint32_t cell : cells) {
      const std::uint32_t begin = cell == 0 ? 0 : cellEnd[cell - 1];
      renderer.uploadCell(cell,
                          std::span<const Splat>(splats).subspan(begin, cellEnd[cell] - begin));
      ranges.push_back({cell, 0, cellEnd[cell] - begin});
    }
    renderer.render(camera, rect, ranges, settings);
    const auto words = renderer.pointWords();
    ASSERT_EQ(words.size(), std::size_t{rect.width()} * rect.height());
    partWords.emplace_back(words.begin(), words.end());
  }
  for (const bool boxed : {false, true}) {
    for (const std::vector<std::size_t>& order :
         {std::vector<std::size_t>{0, 1, 2}, std::vector<std::size_t>{2, 0, 1}}) {
      display::TilePartCompositor compositor;
      for (std::size_t part : order) {
        if (!boxed) {
          compositor.merge(4, 9, 1, rect, std::as_bytes(std::span(partWords[part])));
          continue;
        }
        // As a render sends a part: only the box it drew in.
        const PixelBox box = drawnWordsBox(partWords[part], rect.width(), rect.height());
        EXPECT_GT(box.width, 0u);
        if (part == 0) {
          EXPECT_LT(box.width, rect.width()) << "the first part's box should be narrower";
        }
        TileRect drawn;
        drawn.set_x(rect.x() + box.x);
        drawn.set_y(rect.y() + box.y);
        drawn.set_width(box.width);
        drawn.set_height(box.height);
        compositor.merge(
            4, 9, 1, rect, drawn,
            pixelsInBox(std::as_bytes(std::span(partWords[part])), 8, rect.width(), box));
      }
      const std::vector<std::uint8_t> rgba =
          compositor.take(4, 9, 1, display::packRgba({0, 0, 0, 255}));
      const ImageDiff diff = compareImages(expected, Image(rect.width(), rect.height(), rgba));
      EXPECT_EQ(diff.differingPixels, 0u)
          << (boxed ? "boxed" : "whole") << ", first at " << diff.firstX << "," << diff.firstY;
      EXPECT_EQ(compositor.tilesHeld(), 0u);
    }
  }
}

// The box holds every drawn word and is no bigger: each side touches one.
TEST(CpuPointRenderer, DrawnWordsBoxIsTheSmallestHoldingEveryDrawnWord) {
  constexpr std::uint32_t kWidth = 37, kHeight = 23;
  std::vector<std::uint64_t> words(kWidth * kHeight, kEmptyPixel);
  EXPECT_EQ(drawnWordsBox(words, kWidth, kHeight), PixelBox{});
  EXPECT_TRUE(pixelsInBox(std::as_bytes(std::span(words)), 8, kWidth, PixelBox{}).empty());
  const auto at = [&](std::uint32_t x, std::uint32_t y) -> std::uint64_t& {
    return words[std::size_t{y} * kWidth + x];
  };
  at(5, 7) = 1;
  EXPECT_EQ(drawnWordsBox(words, kWidth, kHeight), (PixelBox{5, 7, 1, 1}));
  at(30, 2) = 2;
  at(12, 20) = 3;
  at(0, 9) = 0;  // a drawn word may be zero (depth 0, black)
  const PixelBox box = drawnWordsBox(words, kWidth, kHeight);
  EXPECT_EQ(box, (PixelBox{0, 2, 31, 19}));
  const std::vector<std::byte> bytes = pixelsInBox(std::as_bytes(std::span(words)), 8, kWidth, box);
  ASSERT_EQ(bytes.size(), std::size_t{box.width} * box.height * 8);
  std::size_t drawn = 0;
  for (std::size_t i = 0; i < bytes.size() / 8; ++i) {
    std::uint64_t word;
    std::memcpy(&word, bytes.data() + 8 * i, 8);
    const std::uint32_t x = box.x + static_cast<std::uint32_t>(i % box.width);
    const std::uint32_t y = box.y + static_cast<std::uint32_t>(i / box.width);
    EXPECT_EQ(word, at(x, y)) << x << "," << y;
    drawn += word != kEmptyPixel ? 1 : 0;
  }
  EXPECT_EQ(drawn, 4u);
  at(kWidth - 1, kHeight - 1) = 4;
  EXPECT_EQ(drawnWordsBox(words, kWidth, kHeight), (PixelBox{0, 2, kWidth, kHeight - 2}));
  EXPECT_THROW(drawnWordsBox(words, kWidth, kHeight - 1), UsageError);
}

// A whole tile's box: every pixel that is not the background, any channel.
TEST(CpuPointRenderer, DrawnRgbaBoxHoldsEveryPixelThatIsNotTheBackground) {
  constexpr std::uint32_t kWidth = 20, kHeight = 10;
  const std::array<std::uint8_t, 4> background{0, 0, 0, 255};
  std::vector<std::uint8_t> rgba(kWidth * kHeight * 4);
  for (std::size_t i = 0; i < rgba.size(); i += 4)
    std::copy(background.begin(), background.end(), rgba.begin() + static_cast<std::ptrdiff_t>(i));
  EXPECT_EQ(drawnRgbaBox(rgba, kWidth, kHeight, background), PixelBox{});
  const auto set = [&](std::uint32_t x, std::uint32_t y, std::size_t channel, std::uint8_t v) {
    rgba[(std::size_t{y} * kWidth + x) * 4 + channel] = v;
  };
  set(4, 3, 3, 254);  // alpha alone differs
  set(15, 6, 0, 1);
  const PixelBox box = drawnRgbaBox(rgba, kWidth, kHeight, background);
  EXPECT_EQ(box, (PixelBox{4, 3, 12, 4}));
  const std::vector<std::byte> bytes = pixelsInBox(std::as_bytes(std::span(rgba)), 4, kWidth, box);
  ASSERT_EQ(bytes.size(), 12u * 4u * 4u);
  EXPECT_EQ(std::to_integer<int>(bytes[3]), 254) << "the box's first pixel is (4,3)";
  EXPECT_EQ(std::to_integer<int>(bytes[((3 * 12) + 11) * 4]), 1) << "its last is (15,6)";
  EXPECT_THROW(drawnRgbaBox(rgba, kWidth + 1, kHeight, background), UsageError);
}

// Depth and colour are compared as one word, so the drawing order never shows.
TEST(CpuPointRenderer, OrderOfSplatsDoesNotMatter) {
  const Camera camera = frontCamera(200, 150);
  std::vector<Splat> splats = mixedScene(30000, 3);
  // Exact depth ties: the same position twice with different colours.
  for (int i = 0; i < 100; ++i) {
    Splat twin = splats[static_cast<std::size_t>(i)];
    twin.color[0] = static_cast<std::uint8_t>(twin.color[0] ^ 0x55);
    splats.push_back(twin);
  }
  CpuPointRenderer renderer;
  const RenderSettings settings = pointSettings();
  const Image before = drawFrame(renderer, camera, splats, settings);
  std::shuffle(splats.begin(), splats.end(), std::mt19937(9));
  EXPECT_EQ(compareImages(before, drawFrame(renderer, camera, splats, settings)).differingPixels,
            0u);
}

TEST(CpuPointRenderer, NearPointWinsTheDepthTest) {
  const Camera camera = frontCamera();
  const std::vector<Splat> splats = {makeSplat(0, 0, 0.5f, 0.05f, 0, 255, 0),
                                     makeSplat(0, 0, -0.5f, 0.2f, 255, 0, 0)};
  CpuPointRenderer renderer;
  const Image image = drawFrame(renderer, camera, splats, pointSettings());
  EXPECT_EQ(image.at(80, 60), (Rgba8{0, 255, 0, 255}));  // the near green point
  // The red point is 2 * 0.2 * 165 / 5.5 = 12 px wide: it shows around the green one.
  EXPECT_EQ(image.at(76, 60), (Rgba8{255, 0, 0, 255}));
  EXPECT_EQ(image.at(72, 60), (Rgba8{0, 0, 0, 255}));
}

// A sphere with outward normals: shaded, its middle faces the eye and is
// brighter than its rim; unshaded, every lit pixel has the splats' colour.
void expectShadingShowsShape(TileRenderer& renderer) {
  const Camera camera = frontCamera(160, 120);
  std::vector<Splat> splats;
  std::mt19937 rng(4);
  std::normal_distribution<float> n(0.0f, 1.0f);
  for (int i = 0; i < 40000; ++i) {
    glm::vec3 d(n(rng), n(rng), n(rng));
    d = glm::normalize(d);
    const glm::vec3 p = d * 1.2f;
    splats.push_back(makeSplat(p.x, p.y, p.z, 0.01f, 200, 200, 200, d.x, d.y, d.z));
  }
  splats.push_back(makeSplat(-2.0f, 1.5f, 0.0f, 0.05f, 200, 200, 200));  // no normal
  RenderSettings lit = pointSettings();
  RenderSettings unlit = lit;
  unlit.lighting = false;
  const Image shaded = drawFrame(renderer, camera, splats, lit);
  const Image flat = drawFrame(renderer, camera, splats, unlit);
  const glm::vec4 centre = projectToWindow(camera, {0, 0, 1.2f});
  const glm::vec4 rim = projectToWindow(camera, {1.15f, 0, 0.3f});
  const glm::vec4 bare = projectToWindow(camera, {-2.0f, 1.5f, 0.0f});
  const auto at = [](const Image& image, glm::vec4 w) {
    return image.at(static_cast<std::uint32_t>(w.x), static_cast<std::uint32_t>(w.y));
  };
  EXPECT_EQ(at(flat, centre), (Rgba8{200, 200, 200, 255})) << renderer.describe();
  EXPECT_EQ(at(flat, rim), (Rgba8{200, 200, 200, 255})) << renderer.describe();
  EXPECT_GE(at(shaded, centre)[0], 190) << renderer.describe();
  EXPECT_LT(at(shaded, rim)[0], 150) << renderer.describe();
  EXPECT_GT(at(shaded, rim)[0], 55) << renderer.describe();  // ambient keeps the rim visible
  EXPECT_EQ(at(shaded, bare), (Rgba8{200, 200, 200, 255})) << renderer.describe();
  EXPECT_GT(compareImages(shaded, flat, 8).differingPixels, litCount(flat) / 4)
      << renderer.describe();
}

TEST(ShadedPoints, CpuShadingShowsShape) {
  CpuPointRenderer renderer;
  expectShadingShowsShape(renderer);
}

TEST(ShadedPoints, GlShadingShowsShape) {
  const auto renderer = makeTileRenderer(v1::RENDERER_GL, GlProfile::Compatibility);
  expectShadingShowsShape(*renderer);
}

TEST(CpuPointRenderer, RefusesWhatItCannotDraw) {
  CpuPointRenderer renderer;
  const std::vector<Splat> splats = mixedScene(100, 1);
  renderer.uploadCell(7, splats);
  const Camera camera = frontCamera();
  RenderSettings settings = pointSettings();
  const DrawRange inside{7, 90, 10}, outside{7, 95, 10}, unknown{8, 0, 1};
  EXPECT_EQ(renderer.render(camera, fullFrameRect(camera), {&inside, 1}, settings).splats, 10u);
  EXPECT_THROW(renderer.render(camera, fullFrameRect(camera), {&outside, 1}, settings), UsageError);
  EXPECT_THROW(renderer.render(camera, fullFrameRect(camera), {&unknown, 1}, settings), UsageError);
  EXPECT_THROW(renderer.render(camera, makeTileRect(150, 0, 20, 10), {&inside, 1}, settings),
               UsageError);
  renderer.releaseCell(7);
  EXPECT_THROW(renderer.render(camera, fullFrameRect(camera), {&inside, 1}, settings), UsageError);
  settings.mode = SplatMode::Splats;
  EXPECT_THROW(renderer.render(camera, fullFrameRect(camera), {}, settings), UsageError);
}

}  // namespace
}  // namespace pointillist::render
