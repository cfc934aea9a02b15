#pragma once
// RGBA8 images as the renderer produces them: rows stored bottom-up (row 0 is
// the bottom of the picture, as in GL and in TileImageHeader payloads). PNG
// files are written and read top-down as the format requires.
#include <array>
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <span>
#include <string>
#include <vector>

#include "common/uninitialized_allocator.hpp"

namespace pointillist {

using Rgba8 = std::array<std::uint8_t, 4>;

// The background of a composed frame: the display's blank image, and what a
// tile shows where its render sent nothing (a background tile, or outside a
// tile image's drawn_rect).
inline constexpr Rgba8 kFrameBackground{0, 0, 0, 255};

// Bytes that resize() leaves unwritten.
using UninitializedBytes = std::vector<std::uint8_t, UninitializedAllocator<std::uint8_t>>;

class Image {
 public:
  Image() = default;
  Image(std::uint32_t width, std::uint32_t height, Rgba8 fill = {0, 0, 0, 0});
  // Copies width*height*4 bytes, rows bottom-up. Throws UsageError on a size mismatch.
  Image(std::uint32_t width, std::uint32_t height, std::span<const std::uint8_t> rgbaBottomUp);
  // Pixels left unwritten: for a caller that writes every one.
  static Image uninitialized(std::uint32_t width, std::uint32_t height);

  std::uint32_t width() const { return width_; }
  std::uint32_t height() const { return height_; }
  bool empty() const { return width_ == 0 || height_ == 0; }
  std::size_t byteSize() const { return pixels_.size(); }

  // (x, y) with y counted from the bottom row.
  std::uint8_t* pixel(std::uint32_t x, std::uint32_t y) { return pixels_.data() + offset(x, y); }
  const std::uint8_t* pixel(std::uint32_t x, std::uint32_t y) const {
    return pixels_.data() + offset(x, y);
  }
  Rgba8 at(std::uint32_t x, std::uint32_t y) const;
  void set(std::uint32_t x, std::uint32_t y, Rgba8 value);
  void fill(Rgba8 value);

  std::span<std::uint8_t> bytes() { return pixels_; }
  std::span<const std::uint8_t> bytes() const { return pixels_; }

  bool operator==(const Image& other) const = default;

 private:
  std::size_t offset(std::uint32_t x, std::uint32_t y) const {
    return (static_cast<std::size_t>(y) * width_ + x) * 4;
  }

  std::uint32_t width_ = 0;
  std::uint32_t height_ = 0;
  UninitializedBytes pixels_;
};

// How hard PNG encoding works. Small: libpng's default zlib level and filters
// (files). Fast: zlib level 1 and the Sub filter, about nine times as fast on
// a 1280x720 city frame for 4 % more bytes (the service's frames; README).
enum class PngSpeed { Small, Fast };

// PNG (8-bit RGBA, or RGB when dropAlpha) in memory and on disk. Writing goes
// to a temporary file renamed at the end, so no half-written PNG is left.
// Reading throws InputError naming the file; writing throws Error.
std::vector<std::uint8_t> encodePng(const Image& image, bool dropAlpha = false,
                                    PngSpeed speed = PngSpeed::Small);
Image decodePng(std::span<const std::uint8_t> png, const std::string& where = "PNG data");
void writePng(const Image& image, const std::filesystem::path& path, bool dropAlpha = false);
Image readPng(const std::filesystem::path& path);

// Copies `tile` into `frame` with the tile's bottom-left pixel at (x, y) of the
// frame (bottom-left origin, TileRect convention). Throws UsageError when the
// tile does not fit.
void blit(const Image& tile, Image& frame, std::uint32_t x, std::uint32_t y);
// The same from raw bottom-up RGBA8 rows (e.g. a TileImageHeader payload).
void blit(std::span<const std::uint8_t> tileRgba, std::uint32_t tileWidth, std::uint32_t tileHeight,
          Image& frame, std::uint32_t x, std::uint32_t y);
// The rectangle [x, x+width) x [y, y+height) of `image` (bottom-left origin).
Image crop(const Image& image, std::uint32_t x, std::uint32_t y, std::uint32_t width,
           std::uint32_t height);

struct ImageDiff {
  std::uint64_t differingPixels = 0;     // pixels where any channel differs by more than tolerance
  int maxChannelDifference = 0;          // over all pixels and channels
  std::uint32_t firstX = 0, firstY = 0;  // first differing pixel (bottom-up scan), if any
};
// Throws UsageError when the sizes differ.
ImageDiff compareImages(const Image& a, const Image& b, int tolerance = 0);

// How close a frame comes to a truth frame of the same camera (e.g. a level of
// detail against full detail), over RGB.
struct ImageQuality {
  double psnr = 0.0;            // dB over every pixel; infinity when identical
  std::uint64_t covered = 0;    // pixels off the background in either frame
  std::uint64_t identical = 0;  // of those, pixels with equal RGB
  double identicalShare() const {
    return covered > 0 ? static_cast<double>(identical) / static_cast<double>(covered) : 1.0;
  }
};
// Throws UsageError when the sizes differ.
ImageQuality measureQuality(const Image& frame, const Image& truth,
                            Rgba8 background = {0, 0, 0, 255});

}  // namespace pointillist
