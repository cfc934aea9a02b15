#include "common/image_compression.hpp"

#include <cstdint>
#include <random>
#include <vector>

#include <gtest/gtest.h>

#include "common/errors.hpp"

namespace pointillist {
namespace {

// Pixels as a render draws them: runs of one colour along a surface, some noise.
std::vector<std::byte> surfacePixels(std::size_t pixels, std::uint32_t seed) {
  std::mt19937 random(seed);
  std::vector<std::byte> bytes;
  bytes.reserve(pixels * 4);
  std::uint32_t colour = 0xff406080u;
  for (std::size_t i = 0; i < pixels; ++i) {
    if (random() % 16 == 0) colour = 0xff000000u | (random() & 0xffffffu);
    for (int c = 0; c < 4; ++c) bytes.push_back(static_cast<std::byte>(colour >> (8 * c)));
  }
  return bytes;
}

TEST(ImageCompression, ChoicesParseAndAutoCompressesOnlyAcrossALink) {
  EXPECT_EQ(parseImageCompression("auto"), ImageCompression::Auto);
  EXPECT_EQ(parseImageCompression("zstd"), ImageCompression::Zstd);
  EXPECT_EQ(parseImageCompression("off"), ImageCompression::Off);
  EXPECT_THROW(parseImageCompression("lz4"), UsageError);
  EXPECT_STREQ(imageCompressionName(ImageCompression::Zstd), "zstd");
  EXPECT_TRUE(compressesImages(ImageCompression::Auto, false));
  EXPECT_FALSE(compressesImages(ImageCompression::Auto, true));
  EXPECT_TRUE(compressesImages(ImageCompression::Zstd, true));
  EXPECT_FALSE(compressesImages(ImageCompression::Off, false));
}

TEST(ImageCompression, FramesComeBackByteForByteAtEveryLevel) {
  const std::vector<std::byte> pixels = surfacePixels(64 * 64, 7);
  for (const int level : {-5, -1, 1, 3, 9}) {
    const std::vector<std::byte> frame = compressImageBytes(pixels, level);
    ASSERT_FALSE(frame.empty()) << level;
    EXPECT_LT(frame.size() * 2, pixels.size()) << "surfaces compress, level " << level;
    EXPECT_EQ(decompressImageBytes(frame, pixels.size(), "tile"), pixels) << level;
  }
}

TEST(ImageCompression, WhatWouldNotShrinkIsLeftAsItIs) {
  std::mt19937 random(3);
  std::vector<std::byte> noise(4096);
  for (auto& b : noise) b = static_cast<std::byte>(random());
  EXPECT_TRUE(compressImageBytes(noise, 1).empty()) << "random bytes do not shrink";
  const std::vector<std::byte> small(kMinCompressedPayload - 1, std::byte{0});
  EXPECT_TRUE(compressImageBytes(small, 1).empty()) << "too small to pay";
}

TEST(ImageCompression, ABadFrameIsAProtocolErrorNotACrash) {
  const std::vector<std::byte> pixels = surfacePixels(4096, 11);
  std::vector<std::byte> frame = compressImageBytes(pixels, 1);
  ASSERT_FALSE(frame.empty());
  EXPECT_THROW(decompressImageBytes(frame, pixels.size() + 1, "tile"), ProtocolError)
      << "another size than the header says";
  EXPECT_THROW(
      decompressImageBytes(std::span(frame).first(frame.size() - 1), pixels.size(), "tile"),
      ProtocolError)
      << "cut short";
  std::vector<std::byte> longer = frame;
  longer.push_back(std::byte{0});
  EXPECT_THROW(decompressImageBytes(longer, pixels.size(), "tile"), ProtocolError)
      << "trailing bytes";
  EXPECT_THROW(decompressImageBytes(pixels, pixels.size(), "tile"), ProtocolError) << "not zstd";
  // Every single flipped byte is refused or expands to the declared size: never more.
  for (std::size_t i = 0; i < frame.size(); i += 7) {
    std::vector<std::byte> damaged = frame;
    damaged[i] ^= std::byte{0x5a};
    try {
      EXPECT_EQ(decompressImageBytes(damaged, pixels.size(), "tile").size(), pixels.size());
    } catch (const ProtocolError&) {
    }
  }
  try {
    (void)decompressImageBytes(pixels, pixels.size(), "tile image from rank 3");
  } catch (const ProtocolError& e) {
    EXPECT_NE(std::string(e.what()).find("tile image from rank 3"), std::string::npos);
  }
}

}  // namespace
}  // namespace pointillist
