// The simulator's lit pixels: a box's count and runs are the pixel-runs
// encoder's, and with them a frame's tile images carry its lit pixels
// however it is cut (docs/scheduling.md §21).
#include <gtest/gtest.h>
#include <cstring>
#include <filesystem>
#include <random>

#include "common/dataset_writer.hpp"
#include "common/errors.hpp"
#include "common/image.hpp"
#include "common/image_compression.hpp"
#include "common/pixel_runs.hpp"
#include "render/raster/cpu_point_renderer.hpp"
#include "simulator/lit_pixels.hpp"
#include "simulator/scene.hpp"
#include "simulator/simulation.hpp"
#include "test_city.hpp"

namespace {

using namespace pointillist;
using namespace pointillist::simulator;

TEST(FrameCoverage, CountsLitPixelsAndRunsAsThePixelRunsEncoderDoes) {
  constexpr std::uint32_t kWidth = 150, kHeight = 40;  // rows of three words, the last part-used
  std::mt19937 rng(3);
  std::vector<std::uint64_t> words(std::size_t{kWidth} * kHeight, render::kEmptyPixel);
  // Stretches of lit pixels of any length, as splats leave them.
  for (std::uint32_t y = 0; y < kHeight; ++y)
    for (std::uint32_t x = 0; x < kWidth;) {
      const std::uint32_t length = 1 + static_cast<std::uint32_t>(rng() % 90);
      const bool lit = rng() % 2 == 0;
      for (std::uint32_t k = x; k < std::min(kWidth, x + length); ++k)
        if (lit) words[std::size_t{y} * kWidth + k] = rng() % 1000;
      x += length;
    }
  const FrameCoverage coverage(words, kWidth, kHeight, render::kEmptyPixel);
  std::uint64_t all = 0;
  for (const std::uint64_t w : words) all += w != render::kEmptyPixel ? 1u : 0u;
  EXPECT_EQ(coverage.litPixels(), all);

  const std::span<const std::byte> bytes(reinterpret_cast<const std::byte*>(words.data()),
                                         words.size() * sizeof(std::uint64_t));
  std::array<std::byte, 8> empty;
  std::memcpy(empty.data(), &render::kEmptyPixel, 8);
  for (int trial = 0; trial < 2000; ++trial) {
    const auto x = static_cast<std::uint32_t>(rng() % kWidth);
    const auto y = static_cast<std::uint32_t>(rng() % kHeight);
    const auto w = 1 + static_cast<std::uint32_t>(rng() % (kWidth - x));
    const auto h = 1 + static_cast<std::uint32_t>(rng() % (kHeight - y));
    std::uint64_t lit = 0;
    for (std::uint32_t r = y; r < y + h; ++r)
      for (std::uint32_t c = x; c < x + w; ++c)
        lit += words[std::size_t{r} * kWidth + c] != render::kEmptyPixel ? 1u : 0u;
    const std::size_t encoded = encodePixelRuns(bytes, 8, kWidth, {x, y, w, h}, empty).size();
    const LitRuns counted = coverage.count(makeTileRect(x, y, w, h));
    ASSERT_EQ(counted.lit, lit) << x << "," << y << " " << w << "x" << h;
    // Each run is 8 bytes of counts before its pixels.
    ASSERT_EQ(counted.runs * 8 + counted.lit * 8, encoded) << x << "," << y << " " << w << "x" << h;
  }
  // A box reaching past the frame counts its part inside.
  EXPECT_EQ(coverage.count(makeTileRect(100, 20, 500, 500)),
            coverage.count(makeTileRect(100, 20, 50, 20)));
  EXPECT_EQ(coverage.count(makeTileRect(kWidth, 0, 10, 10)), LitRuns{});
}

// The city written to disk, so a scene can read its points.
const std::filesystem::path& cityDataset() {
  static const fixtures::TempDir dir("lit-pixels-test");
  static const bool written = [] {
    DatasetContent content = fixtures::smallCityContent(60'000, 11);
    writeDataset(dir.path() / "city", content);
    return true;
  }();
  (void)written;
  static const std::filesystem::path city = dir.path() / "city";
  return city;
}

ViewOptions view() {
  ViewOptions v;
  v.cameraPath = "orbit";
  v.frames = 8;
  v.size = "640x360";
  return v;
}

SimulationConfig unsplitCost(double tilesPerRender) {
  SimulationConfig c;
  c.scheduler = display::SchedulerKind::Cost;
  c.renders = 8;
  c.traverses = 2;
  c.datasends = 2;
  c.tileSplit = false;
  c.tilesPerRender = tilesPerRender;
  return c;
}

// Every lit pixel belongs to one tile: the images of a frame cut into 16 or
// into 256 tiles carry the same lit pixels (only the runs' counts, a run
// per stretch, grow as tiles cut stretches), where a pixel a splat grew with
// the tiles, since a tile counts every splat of the cells it touches.
TEST(LitPixels, TileImagesCarryTheFrameLitPixelsHoweverItIsCut) {
  const Scene lit = Scene::load(cityDataset().string(), view(), true, 2);
  const Scene splats = Scene::load(cityDataset().string(), view(), false);
  ASSERT_TRUE(lit.hasLitPixels());
  ASSERT_FALSE(splats.hasLitPixels());
  ModelParameters p;
  p.traverseSecondsPerCell = 1e-7;
  const auto images = [&](const Scene& scene, double tilesPerRender) {
    return simulate(scene, unsplitCost(tilesPerRender), p).figures.imageBytesPerFrameSteady;
  };
  const double litFew = images(lit, 2), litMany = images(lit, 32);
  const double splatFew = images(splats, 2), splatMany = images(splats, 32);
  EXPECT_GT(litFew, 0.0);
  EXPECT_LT(litMany, litFew * 1.10) << litFew << " -> " << litMany;
  EXPECT_GT(litMany, litFew * 0.95) << litFew << " -> " << litMany;
  EXPECT_GT(splatMany, splatFew * 1.10) << splatFew << " -> " << splatMany;

  // The frame's lit pixels bound every box's; the runs of a frame-sized box
  // are those of the whole frame.
  const TileRect frame = fullFrameRect(lit.cameras().front());
  const LitRuns whole = lit.litRuns(0, frame);
  EXPECT_GT(whole.lit, 0u);
  EXPECT_LT(whole.lit, std::uint64_t{frame.width()} * frame.height());
  const LitRuns half = lit.litRuns(0, makeTileRect(0, 0, frame.width() / 2, frame.height()));
  EXPECT_LE(half.lit, whole.lit);
}

// The ratio a frame's tile images compress by is that of its blocks' runs,
// each compressed apart as a render compresses a tile image.
TEST(LitPixels, CompressionIsMeasuredOnTheRunsOfEachBlock) {
  constexpr std::uint32_t kWidth = 150, kHeight = 90;
  std::vector<std::uint32_t> pixels(std::size_t{kWidth} * kHeight, 0xff000000u);  // background
  for (std::uint32_t y = 10; y < 80; ++y)
    for (std::uint32_t x = 20; x < 140; ++x)
      pixels[std::size_t{y} * kWidth + x] = 0xff204080u + (x / 16);
  const auto bytes = std::as_bytes(std::span(pixels));
  const auto empty = std::as_bytes(std::span(kFrameBackground));
  std::uint64_t plain = 0, packed = 0;
  for (std::uint32_t y = 0; y < kHeight; y += kCompressionBlock)
    for (std::uint32_t x = 0; x < kWidth; x += kCompressionBlock) {
      const PixelBox box{x, y, std::min(kCompressionBlock, kWidth - x),
                         std::min(kCompressionBlock, kHeight - y)};
      const auto runs = encodePixelRuns(bytes, 4, kWidth, box, empty);
      const auto frame = compressImageBytes(runs, 3);
      plain += runs.size();
      packed += frame.empty() ? runs.size() : frame.size();
    }
  const double ratio = measureCompression(bytes, 4, kWidth, kHeight, empty, 3);
  EXPECT_DOUBLE_EQ(ratio, static_cast<double>(plain) / static_cast<double>(packed));
  EXPECT_GT(ratio, 4.0) << "flat colours compress";
  const std::vector<std::uint32_t> blank(pixels.size(), 0xff000000u);
  EXPECT_EQ(measureCompression(std::as_bytes(std::span(blank)), 4, kWidth, kHeight, empty, 3), 1.0)
      << "nothing lit: no image travels";
}

// Compressed, a frame's images cross the display's link smaller by the
// ratio measured on its pixels, and still expand to the same bytes; and a
// display that expands them too slowly holds the frame rate, since a tile
// counts as arrived only once its image is handled.
TEST(LitPixels, CompressedImagesAreSmallerAndTheirExpansionCanHoldTheDisplay) {
  const Scene scene = Scene::load(cityDataset().string(), view(), true, 2, 3);
  ASSERT_EQ(scene.compressionLevel(), 3);
  const double whole = scene.imageCompression(2, false);
  const double part = scene.imageCompression(2, true);
  EXPECT_GT(whole, 1.2);
  EXPECT_GT(part, 1.2);
  ModelParameters p;
  p.traverseSecondsPerCell = 1e-7;
  p.compressImages = false;
  const display::KeyFigures plain = simulate(scene, unsplitCost(2), p).figures;
  p.compressImages = true;
  const display::KeyFigures packed = simulate(scene, unsplitCost(2), p).figures;
  EXPECT_LT(packed.imageBytesPerFrameSteady, plain.imageBytesPerFrameSteady / 1.2);
  EXPECT_GT(packed.imageBytesUncompressedPerFrameSteady, plain.imageBytesPerFrameSteady * 0.9);
  EXPECT_LT(packed.imageBytesUncompressedPerFrameSteady, plain.imageBytesPerFrameSteady * 1.1);

  // One image thread at 1 us a byte: a frame takes about its bytes' time (the
  // steady window of 8 frames begins with some expanded already).
  p.decompressSecondsPerByte = 1e-6;
  p.displayImageThreads = 1;
  const display::KeyFigures slow = simulate(scene, unsplitCost(2), p).figures;
  const double bound = 1.0 / (slow.imageBytesUncompressedPerFrameSteady * 1e-6);
  EXPECT_LT(slow.framesPerSecondSteady, bound * 1.15);
  EXPECT_LT(slow.framesPerSecondSteady * 2.0, packed.framesPerSecondSteady);
  // Eight threads expand eight images at once.
  p.displayImageThreads = 8;
  EXPECT_GT(simulate(scene, unsplitCost(2), p).figures.framesPerSecondSteady,
            slow.framesPerSecondSteady * 2.0);
}

}  // namespace
