#include "common/image.hpp"

#include <png.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <iterator>
#include <limits>
#include <memory>
#include <string>
#include <system_error>

#include "common/errors.hpp"

namespace pointillist {

namespace {

std::size_t rgbaBytes(std::uint32_t width, std::uint32_t height) {
  return static_cast<std::size_t>(width) * height * 4;
}

// libpng's simplified API takes a signed stride; a negative one walks the rows
// bottom-up, which is exactly our storage order.
png_int_32 bottomUpStride(std::uint32_t width, unsigned channels) {
  return -static_cast<png_int_32>(width * channels);
}

extern "C" void appendPngBytes(png_structp png, png_bytep data, png_size_t length) {
  auto* out = static_cast<std::vector<std::uint8_t>*>(png_get_io_ptr(png));
  out->insert(out->end(), data, data + length);
}

extern "C" void flushNothing(png_structp) {}

extern "C" void keepPngError(png_structp png, png_const_charp message) {
  *static_cast<std::string*>(png_get_error_ptr(png)) = message;
  png_longjmp(png, 1);
}

// One pass of libpng's writer over RGBA rows. libpng reports errors by
// longjmp: no object with a destructor may live in this frame between setjmp
// and the end, so the vectors and the message belong to the caller.
bool writePngRows(std::uint32_t width, std::uint32_t height, bool dropAlpha, PngSpeed speed,
                  std::vector<png_bytep>& rows, std::vector<std::uint8_t>& out,
                  std::string& message) {
  png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, &message, keepPngError, nullptr);
  if (png == nullptr) {
    message = "libpng cannot start a writer";
    return false;
  }
  png_infop info = png_create_info_struct(png);
  if (info == nullptr || setjmp(png_jmpbuf(png)) != 0) {
    png_destroy_write_struct(&png, &info);
    if (message.empty()) message = "libpng failed";
    return false;
  }
  png_set_write_fn(png, &out, appendPngBytes, flushNothing);
  png_set_IHDR(png, info, width, height, 8, dropAlpha ? PNG_COLOR_TYPE_RGB : PNG_COLOR_TYPE_RGBA,
               PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
  if (speed == PngSpeed::Fast) {
    png_set_compression_level(png, 1);
    png_set_filter(png, PNG_FILTER_TYPE_BASE, PNG_FILTER_SUB);
  }
  png_write_info(png, info);
  if (dropAlpha) png_set_filler(png, 0, PNG_FILLER_AFTER);  // RGBA rows in, RGB out
  png_write_image(png, rows.data());
  png_write_end(png, nullptr);
  png_destroy_write_struct(&png, &info);
  return true;
}

}  // namespace

Image::Image(std::uint32_t width, std::uint32_t height, Rgba8 fill)
    : width_(width), height_(height), pixels_(rgbaBytes(width, height)) {
  this->fill(fill);
}

Image::Image(std::uint32_t width, std::uint32_t height, std::span<const std::uint8_t> rgbaBottomUp)
    : width_(width), height_(height) {
  if (rgbaBottomUp.size() != rgbaBytes(width, height)) {
    throw UsageError("Image: " + std::to_string(rgbaBottomUp.size()) + " bytes for " +
                     std::to_string(width) + "x" + std::to_string(height) + " RGBA8");
  }
  pixels_.assign(rgbaBottomUp.begin(), rgbaBottomUp.end());
}

Image Image::uninitialized(std::uint32_t width, std::uint32_t height) {
  Image image;
  image.width_ = width;
  image.height_ = height;
  image.pixels_.resize(rgbaBytes(width, height));
  return image;
}

Rgba8 Image::at(std::uint32_t x, std::uint32_t y) const {
  const std::uint8_t* p = pixel(x, y);
  return {p[0], p[1], p[2], p[3]};
}

void Image::set(std::uint32_t x, std::uint32_t y, Rgba8 value) {
  std::memcpy(pixel(x, y), value.data(), 4);
}

void Image::fill(Rgba8 value) {
  for (std::size_t i = 0; i < pixels_.size(); i += 4) std::memcpy(&pixels_[i], value.data(), 4);
}

std::vector<std::uint8_t> encodePng(const Image& image, bool dropAlpha, PngSpeed speed) {
  if (image.empty()) throw UsageError("encodePng: empty image");
  std::vector<png_bytep> rows(image.height());
  // PNG rows run top-down; the image's run bottom-up.
  for (std::uint32_t y = 0; y < image.height(); ++y) {
    rows[image.height() - 1 - y] = const_cast<png_bytep>(image.pixel(0, y));
  }
  std::vector<std::uint8_t> out;
  out.reserve(image.byteSize() / 4);
  std::string message;
  if (!writePngRows(image.width(), image.height(), dropAlpha, speed, rows, out, message)) {
    throw Error("encodePng: " + message);
  }
  return out;
}

Image decodePng(std::span<const std::uint8_t> data, const std::string& where) {
  png_image png{};
  png.version = PNG_IMAGE_VERSION;
  if (!png_image_begin_read_from_memory(&png, data.data(), data.size())) {
    const std::string message = png.message;
    png_image_free(&png);
    throw InputError(where + ": not a readable PNG: " + message);
  }
  png.format = PNG_FORMAT_RGBA;
  if (png.width == 0 || png.height == 0 || png.width > 65536 || png.height > 65536) {
    png_image_free(&png);
    throw InputError(where + ": unsupported PNG size");
  }
  Image image(png.width, png.height);
  if (!png_image_finish_read(&png, nullptr, image.bytes().data(), bottomUpStride(png.width, 4),
                             nullptr)) {
    const std::string message = png.message;
    png_image_free(&png);
    throw InputError(where + ": damaged PNG: " + message);
  }
  return image;
}

void writePng(const Image& image, const std::filesystem::path& path, bool dropAlpha) {
  const std::vector<std::uint8_t> bytes = encodePng(image, dropAlpha);
  std::filesystem::path tmp = path;
  tmp += ".tmp";
  {
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    out.write(reinterpret_cast<const char*>(bytes.data()),
              static_cast<std::streamsize>(bytes.size()));
    out.close();
    if (!out) {
      std::error_code ignored;
      std::filesystem::remove(tmp, ignored);
      throw Error("cannot write " + path.string());
    }
  }
  std::error_code ec;
  std::filesystem::rename(tmp, path, ec);
  if (ec) {
    std::error_code ignored;
    std::filesystem::remove(tmp, ignored);
    throw Error("cannot write " + path.string() + ": " + ec.message());
  }
}

Image readPng(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError(path.string() + ": cannot open");
  const std::vector<std::uint8_t> bytes((std::istreambuf_iterator<char>(in)),
                                        std::istreambuf_iterator<char>());
  return decodePng(bytes, path.string());
}

void blit(std::span<const std::uint8_t> tileRgba, std::uint32_t tileWidth, std::uint32_t tileHeight,
          Image& frame, std::uint32_t x, std::uint32_t y) {
  if (tileRgba.size() != rgbaBytes(tileWidth, tileHeight)) {
    throw UsageError("blit: tile payload size does not match its rectangle");
  }
  if (std::uint64_t{x} + tileWidth > frame.width() ||
      std::uint64_t{y} + tileHeight > frame.height()) {
    throw UsageError("blit: tile " + std::to_string(tileWidth) + "x" + std::to_string(tileHeight) +
                     " at (" + std::to_string(x) + "," + std::to_string(y) + ") does not fit a " +
                     std::to_string(frame.width()) + "x" + std::to_string(frame.height()) +
                     " frame");
  }
  const std::size_t rowBytes = static_cast<std::size_t>(tileWidth) * 4;
  for (std::uint32_t row = 0; row < tileHeight; ++row) {
    std::memcpy(frame.pixel(x, y + row), tileRgba.data() + row * rowBytes, rowBytes);
  }
}

void blit(const Image& tile, Image& frame, std::uint32_t x, std::uint32_t y) {
  blit(tile.bytes(), tile.width(), tile.height(), frame, x, y);
}

Image crop(const Image& image, std::uint32_t x, std::uint32_t y, std::uint32_t width,
           std::uint32_t height) {
  if (std::uint64_t{x} + width > image.width() || std::uint64_t{y} + height > image.height()) {
    throw UsageError("crop: rectangle outside the image");
  }
  Image out(width, height);
  const std::size_t rowBytes = static_cast<std::size_t>(width) * 4;
  for (std::uint32_t row = 0; row < height; ++row) {
    std::memcpy(out.pixel(0, row), image.pixel(x, y + row), rowBytes);
  }
  return out;
}

ImageDiff compareImages(const Image& a, const Image& b, int tolerance) {
  if (a.width() != b.width() || a.height() != b.height()) {
    throw UsageError("compareImages: sizes differ");
  }
  ImageDiff diff;
  for (std::uint32_t y = 0; y < a.height(); ++y) {
    for (std::uint32_t x = 0; x < a.width(); ++x) {
      const std::uint8_t* p = a.pixel(x, y);
      const std::uint8_t* q = b.pixel(x, y);
      int worst = 0;
      for (int c = 0; c < 4; ++c) worst = std::max(worst, std::abs(int{p[c]} - int{q[c]}));
      diff.maxChannelDifference = std::max(diff.maxChannelDifference, worst);
      if (worst > tolerance) {
        if (diff.differingPixels == 0) {
          diff.firstX = x;
          diff.firstY = y;
        }
        ++diff.differingPixels;
      }
    }
  }
  return diff;
}

ImageQuality measureQuality(const Image& frame, const Image& truth, Rgba8 background) {
  if (frame.width() != truth.width() || frame.height() != truth.height()) {
    throw UsageError("measureQuality: sizes differ");
  }
  ImageQuality quality;
  const auto isBackground = [&](const std::uint8_t* p) {
    return p[0] == background[0] && p[1] == background[1] && p[2] == background[2];
  };
  double squaredError = 0.0;
  for (std::uint32_t y = 0; y < frame.height(); ++y) {
    for (std::uint32_t x = 0; x < frame.width(); ++x) {
      const std::uint8_t* p = frame.pixel(x, y);
      const std::uint8_t* q = truth.pixel(x, y);
      bool same = true;
      for (int c = 0; c < 3; ++c) {
        const double d = static_cast<double>(p[c]) - static_cast<double>(q[c]);
        squaredError += d * d;
        same = same && p[c] == q[c];
      }
      if (!isBackground(p) || !isBackground(q)) {
        ++quality.covered;
        quality.identical += same ? 1u : 0u;
      }
    }
  }
  const double samples = 3.0 * static_cast<double>(frame.width()) * frame.height();
  const double mse = samples > 0.0 ? squaredError / samples : 0.0;
  quality.psnr =
      mse > 0.0 ? 10.0 * std::log10(255.0 * 255.0 / mse) : std::numeric_limits<double>::infinity();
  return quality;
}

}  // namespace pointillist
