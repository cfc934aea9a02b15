#include "common/pixel_runs.hpp"

#include <gtest/gtest.h>

#include <array>
#include <cstring>
#include <random>
#include <vector>

#include "common/errors.hpp"

namespace pointillist {
namespace {

constexpr std::uint64_t kEmpty = ~std::uint64_t{0};

std::span<const std::byte> emptyWord() {
  return std::as_bytes(std::span(&kEmpty, 1));
}

// A tile of words, a share of them drawn, in clumps as points on a surface are.
std::vector<std::uint64_t> clumpedTile(std::uint32_t width, std::uint32_t height, double lit,
                                       unsigned seed) {
  std::mt19937 random(seed);
  std::vector<std::uint64_t> words(std::size_t{width} * height, kEmpty);
  std::bernoulli_distribution start(lit / 8.0);
  for (std::size_t i = 0; i < words.size(); ++i) {
    if (!start(random)) continue;
    for (std::size_t k = i; k < std::min(words.size(), i + 8); ++k) words[k] = random() & 0xFFFF;
  }
  return words;
}

// Runs give back the box's pixels exactly, for boxes anywhere in the tile,
// and carry fewer bytes than the box where half of it is empty.
TEST(PixelRuns, DecodeGivesBackTheBoxExactly) {
  constexpr std::uint32_t kWidth = 61, kHeight = 37;
  for (const double lit : {0.0, 0.1, 0.5, 1.0}) {
    const std::vector<std::uint64_t> words = clumpedTile(kWidth, kHeight, lit, 3);
    for (const PixelBox box : {PixelBox{0, 0, kWidth, kHeight}, PixelBox{5, 3, 20, 30},
                               PixelBox{60, 36, 1, 1}, PixelBox{10, 10, 0, 0}}) {
      const std::vector<std::byte> runs =
          encodePixelRuns(std::as_bytes(std::span(words)), 8, kWidth, box, emptyWord());
      const std::size_t pixels = std::size_t{box.width} * box.height;
      const std::vector<std::byte> back = decodePixelRuns(runs, 8, pixels, emptyWord());
      ASSERT_EQ(back.size(), pixels * 8);
      for (std::uint32_t r = 0; r < box.height; ++r) {
        for (std::uint32_t x = 0; x < box.width; ++x) {
          std::uint64_t word;
          std::memcpy(&word, back.data() + (std::size_t{r} * box.width + x) * 8, 8);
          ASSERT_EQ(word, words[std::size_t{box.y + r} * kWidth + box.x + x])
              << "lit " << lit << ", pixel " << x << "," << r;
        }
      }
      if (lit == 0.5 && pixels > 100) {
        EXPECT_LT(runs.size(), pixels * 8 * 3 / 4) << "half empty, runs should save a quarter";
      }
    }
  }
}

TEST(PixelRuns, FourBytePixelsSkipTheBackground) {
  const std::array<std::uint8_t, 4> background{0, 0, 0, 255};
  std::vector<std::uint8_t> rgba(6 * 2 * 4);
  for (std::size_t i = 0; i < rgba.size(); i += 4) {
    std::memcpy(rgba.data() + i, background.data(), 4);
  }
  rgba[4 * 2 + 0] = 9;        // pixel (2,0)
  rgba[4 * (6 + 5) + 3] = 7;  // pixel (5,1)
  const PixelBox box{0, 0, 6, 2};
  const std::vector<std::byte> runs = encodePixelRuns(std::as_bytes(std::span(rgba)), 4, 6, box,
                                                      std::as_bytes(std::span(background)));
  // skip 2, run 1, pixel; skip 8, run 1, pixel.
  EXPECT_EQ(runs.size(), 2u * (8u + 4u));
  const std::vector<std::byte> back =
      decodePixelRuns(runs, 4, 12, std::as_bytes(std::span(background)));
  EXPECT_EQ(std::memcmp(back.data(), rgba.data(), rgba.size()), 0);
}

// Runs that do not cover the box, or bytes that do not hold them, are refused.
TEST(PixelRuns, MalformedRunsAreRefused) {
  const std::vector<std::uint64_t> words = clumpedTile(16, 4, 0.5, 9);
  const PixelBox box{0, 0, 16, 4};
  const std::vector<std::byte> runs =
      encodePixelRuns(std::as_bytes(std::span(words)), 8, 16, box, emptyWord());
  ASSERT_GT(runs.size(), 16u);
  EXPECT_THROW(decodePixelRuns(runs, 8, 63, emptyWord()), ProtocolError) << "past the box";
  EXPECT_THROW(decodePixelRuns(runs, 8, 65, emptyWord()), ProtocolError) << "short of the box";
  EXPECT_THROW(decodePixelRuns(std::span(runs).first(runs.size() - 1), 8, 64, emptyWord()),
               ProtocolError)
      << "cut short";
  EXPECT_THROW(decodePixelRuns(std::span(runs).first(5), 8, 64, emptyWord()), ProtocolError)
      << "inside a run's counts";
  std::vector<std::byte> huge(8, std::byte{0xFF});  // skip and count of 2^32 - 1
  EXPECT_THROW(decodePixelRuns(huge, 8, 64, emptyWord()), ProtocolError);
  EXPECT_THROW(
      encodePixelRuns(std::as_bytes(std::span(words)), 8, 16, PixelBox{10, 0, 7, 1}, emptyWord()),
      UsageError);
  EXPECT_THROW(encodePixelRuns(std::as_bytes(std::span(words)), 6, 16, box,
                               std::span<const std::byte>(runs).first(6)),
               UsageError);
}

}  // namespace
}  // namespace pointillist
