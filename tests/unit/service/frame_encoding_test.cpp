#include "service/core/frame_encoding.hpp"

#include <gtest/gtest.h>

#include "common/errors.hpp"
#include "service/core/latency_window.hpp"

namespace pointillist::service {
namespace {

// A picture with structure: gradients, a bright square near the bottom-left
// (rows are bottom-up, so flipping would move it to the top).
Image testImage(std::uint32_t width, std::uint32_t height) {
  Image image(width, height, {0, 0, 0, 255});
  for (std::uint32_t y = 0; y < height; ++y) {
    for (std::uint32_t x = 0; x < width; ++x) {
      image.set(x, y,
                {static_cast<std::uint8_t>(x * 255 / width),
                 static_cast<std::uint8_t>(y * 255 / height), 64, 255});
    }
  }
  for (std::uint32_t y = 4; y < 20; ++y) {
    for (std::uint32_t x = 4; x < 20; ++x) image.set(x, y, {255, 255, 255, 255});
  }
  return image;
}

TEST(FrameEncoding, RawIsTopDownRgbaAndRoundTrips) {
  const Image image = testImage(64, 48);
  const auto bytes = encodeFrame(image, v1::ENCODING_RAW_RGBA);
  ASSERT_EQ(bytes.size(), 64u * 48u * 4u);
  // The first row of the raw bytes is the picture's top row (y = 47).
  EXPECT_EQ(bytes[1], image.at(0, 47)[1]);
  EXPECT_EQ(decodeFrame(bytes, v1::ENCODING_RAW_RGBA, 64, 48), image);
}

TEST(FrameEncoding, PngIsLossless) {
  const Image image = testImage(64, 48);
  const auto bytes = encodeFrame(image, v1::ENCODING_PNG);
  EXPECT_EQ(bytes[1], 'P');
  EXPECT_EQ(decodeFrame(bytes, v1::ENCODING_PNG, 64, 48), image);
}

TEST(FrameEncoding, JpegIsCloseAndNotFlipped) {
  const Image image = testImage(160, 96);
  const auto bytes = encodeFrame(image, v1::ENCODING_JPEG, 90);
  ASSERT_GT(bytes.size(), 4u);
  EXPECT_EQ(bytes[0], 0xff);
  EXPECT_EQ(bytes[1], 0xd8);
  const Image decoded = decodeFrame(bytes, v1::ENCODING_JPEG, 160, 96);
  EXPECT_GT(measureQuality(decoded, image).psnr, 30.0);
  // The white square stays bottom-left.
  EXPECT_GT(decoded.at(10, 10)[0], 230);
  EXPECT_LT(decoded.at(10, 85)[0], 100);
  // Lower quality, fewer bytes.
  EXPECT_LT(encodeFrame(image, v1::ENCODING_JPEG, 20).size(), bytes.size());
}

TEST(FrameEncoding, RefusesWhatItCannotEncodeOrDecode) {
  const Image image = testImage(32, 32);
  EXPECT_THROW(encodeFrame(image, v1::ENCODING_UNSPECIFIED), UsageError);
  EXPECT_THROW(encodeFrame(image, v1::ENCODING_JPEG, 0), UsageError);
  const std::vector<std::uint8_t> junk(100, 7);
  EXPECT_THROW(decodeFrame(junk, v1::ENCODING_JPEG, 32, 32), InputError);
  EXPECT_THROW(decodeFrame(junk, v1::ENCODING_RAW_RGBA, 32, 32), InputError);
  const auto jpeg = encodeFrame(image, v1::ENCODING_JPEG);
  EXPECT_THROW(decodeFrame(jpeg, v1::ENCODING_JPEG, 16, 32), InputError);
}

TEST(LatencyWindow, NearestRankPercentilesOverTheWindow) {
  LatencyWindow window(100);
  for (int i = 1; i <= 100; ++i) window.add(i);
  LatencyFigures figures = window.figures();
  EXPECT_EQ(figures.count, 100u);
  EXPECT_EQ(figures.median, 50.0);
  EXPECT_EQ(figures.p95, 95.0);
  EXPECT_EQ(figures.max, 100.0);
  for (int i = 0; i < 100; ++i) window.add(1000.0);  // the window forgets the first 100
  figures = window.figures();
  EXPECT_EQ(figures.count, 200u);
  EXPECT_EQ(figures.median, 1000.0);
}

}  // namespace
}  // namespace pointillist::service
