#include "common/image.hpp"

#include <gtest/gtest.h>
#include <png.h>

#include <unistd.h>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>

#include "common/errors.hpp"

namespace pointillist {
namespace {

Image gradient(std::uint32_t w, std::uint32_t h) {
  Image image(w, h);
  for (std::uint32_t y = 0; y < h; ++y) {
    for (std::uint32_t x = 0; x < w; ++x) {
      image.set(x, y,
                {static_cast<std::uint8_t>(x * 7), static_cast<std::uint8_t>(y * 11),
                 static_cast<std::uint8_t>(x ^ y), static_cast<std::uint8_t>(255 - x)});
    }
  }
  return image;
}

std::filesystem::path tempPath(const std::string& name) {
  return std::filesystem::temp_directory_path() /
         ("pointillist_image_test_" + std::to_string(::getpid()) + "_" + name);
}

TEST(Image, PngRoundTripOnDisk) {
  const Image image = gradient(37, 23);
  const auto path = tempPath("rgba.png");
  writePng(image, path);
  EXPECT_FALSE(std::filesystem::exists(path.string() + ".tmp"));
  const Image back = readPng(path);
  std::filesystem::remove(path);
  EXPECT_EQ(back, image);
}

TEST(Image, PngWithoutAlphaReadsOpaque) {
  const Image image = gradient(8, 5);
  const Image back = decodePng(encodePng(image, true));
  ASSERT_EQ(back.width(), 8u);
  for (std::uint32_t y = 0; y < 5; ++y) {
    for (std::uint32_t x = 0; x < 8; ++x) {
      const Rgba8 a = image.at(x, y), b = back.at(x, y);
      EXPECT_EQ(a[0], b[0]);
      EXPECT_EQ(a[1], b[1]);
      EXPECT_EQ(a[2], b[2]);
      EXPECT_EQ(b[3], 255);
    }
  }
}

// The service's fast setting trades bytes for time, never pixels.
TEST(Image, FastPngKeepsEveryPixel) {
  const Image image = gradient(64, 48);
  EXPECT_EQ(decodePng(encodePng(image, false, PngSpeed::Fast)), image);
  const Image opaque = decodePng(encodePng(image, true, PngSpeed::Fast));
  EXPECT_EQ(opaque, decodePng(encodePng(image, true, PngSpeed::Small)));
}

TEST(Image, PngIsWrittenTopDown) {
  // Bottom row red, top row blue in our bottom-up storage.
  Image image(2, 2, {0, 0, 255, 255});
  image.set(0, 0, {255, 0, 0, 255});
  image.set(1, 0, {255, 0, 0, 255});
  const std::vector<std::uint8_t> png = encodePng(image);
  // Decode with a top-down stride by hand: libpng's first row is the top.
  png_image reader{};
  reader.version = PNG_IMAGE_VERSION;
  ASSERT_TRUE(png_image_begin_read_from_memory(&reader, png.data(), png.size()));
  reader.format = PNG_FORMAT_RGBA;
  std::vector<std::uint8_t> topDown(16);
  ASSERT_TRUE(png_image_finish_read(&reader, nullptr, topDown.data(), 8, nullptr));
  EXPECT_EQ(topDown[2], 255);  // first row (top) is blue
  EXPECT_EQ(topDown[8], 255);  // second row (bottom) is red
  EXPECT_EQ(topDown[10], 0);
}

TEST(Image, DamagedPngIsAnInputError) {
  const auto path = tempPath("bad.png");
  {
    std::ofstream out(path, std::ios::binary);
    out << "\x89PNG\r\n\x1a\n garbage";
  }
  EXPECT_THROW(readPng(path), InputError);
  std::filesystem::remove(path);
  EXPECT_THROW(readPng(tempPath("missing.png")), InputError);
  std::vector<std::uint8_t> truncated = encodePng(gradient(16, 16));
  truncated.resize(truncated.size() / 2);
  EXPECT_THROW(decodePng(truncated), InputError);
}

TEST(Image, BlitCropAndCompare) {
  const Image frameSource = gradient(20, 10);
  Image frame(20, 10);
  // Four uneven tiles put back together give the original.
  const std::uint32_t xs[] = {0, 7, 20}, ys[] = {0, 3, 10};
  for (int i = 0; i < 2; ++i) {
    for (int j = 0; j < 2; ++j) {
      const Image tile = crop(frameSource, xs[i], ys[j], xs[i + 1] - xs[i], ys[j + 1] - ys[j]);
      blit(tile, frame, xs[i], ys[j]);
    }
  }
  EXPECT_EQ(compareImages(frame, frameSource).differingPixels, 0u);
  EXPECT_EQ(frame, frameSource);

  frame.set(4, 6, {0, 0, 0, 0});
  const ImageDiff diff = compareImages(frame, frameSource);
  EXPECT_EQ(diff.differingPixels, 1u);
  EXPECT_EQ(diff.firstX, 4u);
  EXPECT_EQ(diff.firstY, 6u);
  EXPECT_GT(diff.maxChannelDifference, 0);
  EXPECT_EQ(compareImages(frame, frameSource, 255).differingPixels, 0u);

  EXPECT_THROW(blit(gradient(5, 5), frame, 16, 0), UsageError);
  EXPECT_THROW(compareImages(frame, gradient(3, 3)), UsageError);
  EXPECT_THROW(crop(frame, 15, 0, 6, 1), UsageError);
}

}  // namespace
}  // namespace pointillist

namespace pointillist {
namespace {

TEST(ImageQuality, IdenticalFramesHaveInfinitePsnr) {
  Image truth(8, 4, {0, 0, 0, 255});
  truth.set(1, 1, {10, 20, 30, 255});
  const ImageQuality quality = measureQuality(truth, truth);
  EXPECT_TRUE(std::isinf(quality.psnr));
  EXPECT_EQ(quality.covered, 1u);
  EXPECT_EQ(quality.identical, 1u);
  EXPECT_DOUBLE_EQ(quality.identicalShare(), 1.0);
}

TEST(ImageQuality, PsnrAndSharesFollowTheirDefinitions) {
  Image truth(10, 10, {0, 0, 0, 255}), frame(10, 10, {0, 0, 0, 255});
  for (std::uint32_t x = 0; x < 4; ++x) {
    truth.set(x, 0, {100, 100, 100, 255});
    frame.set(x, 0, {100, 100, 100, 255});
  }
  frame.set(3, 0, {110, 100, 100, 255});  // one channel off by 10
  frame.set(9, 9, {0, 0, 51, 255});       // a pixel the truth does not cover
  const ImageQuality quality = measureQuality(frame, truth);
  EXPECT_EQ(quality.covered, 5u);
  EXPECT_EQ(quality.identical, 3u);
  EXPECT_DOUBLE_EQ(quality.identicalShare(), 0.6);
  // MSE over 300 samples: (10^2 + 51^2) / 300.
  const double mse = (100.0 + 51.0 * 51.0) / 300.0;
  EXPECT_NEAR(quality.psnr, 10.0 * std::log10(255.0 * 255.0 / mse), 1e-9);
  EXPECT_THROW(measureQuality(frame, Image(10, 9)), UsageError);
}

}  // namespace
}  // namespace pointillist
