#include "service/core/frame_encoding.hpp"

#include <turbojpeg.h>

#include <cstring>
#include <memory>
#include <string>

#include "common/errors.hpp"

namespace pointillist::service {
namespace {

struct TurboJpegHandle {
  explicit TurboJpegHandle(bool compress)
      : handle(compress ? tjInitCompress() : tjInitDecompress()) {
    if (handle == nullptr) throw Error(std::string("libturbojpeg: ") + tjGetErrorStr2(nullptr));
  }
  ~TurboJpegHandle() { tjDestroy(handle); }
  TurboJpegHandle(const TurboJpegHandle&) = delete;
  TurboJpegHandle& operator=(const TurboJpegHandle&) = delete;
  tjhandle handle;
};

std::vector<std::uint8_t> rawTopDown(const Image& frame) {
  std::vector<std::uint8_t> out(frame.byteSize());
  const std::size_t row = static_cast<std::size_t>(frame.width()) * 4;
  for (std::uint32_t y = 0; y < frame.height(); ++y) {
    std::memcpy(out.data() + static_cast<std::size_t>(frame.height() - 1 - y) * row,
                frame.pixel(0, y), row);
  }
  return out;
}

std::vector<std::uint8_t> encodeJpeg(const Image& frame, std::uint32_t quality) {
  thread_local TurboJpegHandle compressor(true);
  unsigned char* buffer = nullptr;
  unsigned long size = 0;
  // The frame's rows are bottom-up; libturbojpeg reads them so when told.
  const int failed =
      tjCompress2(compressor.handle, frame.bytes().data(), static_cast<int>(frame.width()), 0,
                  static_cast<int>(frame.height()), TJPF_RGBA, &buffer, &size, TJSAMP_420,
                  static_cast<int>(quality), TJFLAG_BOTTOMUP);
  std::unique_ptr<unsigned char, decltype(&tjFree)> owned(buffer, &tjFree);
  if (failed != 0) {
    throw Error(std::string("JPEG encoding failed: ") + tjGetErrorStr2(compressor.handle));
  }
  return {buffer, buffer + size};
}

Image decodeJpeg(std::span<const std::uint8_t> bytes, std::uint32_t width, std::uint32_t height) {
  thread_local TurboJpegHandle decompressor(false);
  int jpegWidth = 0, jpegHeight = 0, subsampling = 0, colourspace = 0;
  // libturbojpeg takes a non-const pointer but does not write through it.
  auto* data = const_cast<unsigned char*>(bytes.data());
  if (tjDecompressHeader3(decompressor.handle, data, bytes.size(), &jpegWidth, &jpegHeight,
                          &subsampling, &colourspace) != 0) {
    throw InputError(std::string("JPEG data does not decode: ") +
                     tjGetErrorStr2(decompressor.handle));
  }
  if (static_cast<std::uint32_t>(jpegWidth) != width ||
      static_cast<std::uint32_t>(jpegHeight) != height) {
    throw InputError("JPEG is " + std::to_string(jpegWidth) + "x" + std::to_string(jpegHeight) +
                     ", expected " + std::to_string(width) + "x" + std::to_string(height));
  }
  Image image(width, height);
  if (tjDecompress2(decompressor.handle, data, bytes.size(), image.bytes().data(), jpegWidth, 0,
                    jpegHeight, TJPF_RGBA, TJFLAG_BOTTOMUP) != 0) {
    throw InputError(std::string("JPEG data does not decode: ") +
                     tjGetErrorStr2(decompressor.handle));
  }
  return image;
}

}  // namespace

std::vector<std::uint8_t> encodeFrame(const Image& frame, v1::Encoding encoding,
                                      std::uint32_t jpegQuality) {
  switch (encoding) {
    case v1::ENCODING_RAW_RGBA:
      return rawTopDown(frame);
    case v1::ENCODING_PNG:
      if (frame.empty()) throw UsageError("no pixels to encode");
      return encodePng(frame, true, PngSpeed::Fast);
    case v1::ENCODING_JPEG:
      if (jpegQuality < 1 || jpegQuality > 100) {
        throw UsageError("JPEG quality " + std::to_string(jpegQuality) + " not in [1, 100]");
      }
      return encodeJpeg(frame, jpegQuality);
    default:
      throw UsageError("no encoding chosen for the frame");
  }
}

Image decodeFrame(std::span<const std::uint8_t> bytes, v1::Encoding encoding, std::uint32_t width,
                  std::uint32_t height) {
  switch (encoding) {
    case v1::ENCODING_RAW_RGBA: {
      if (bytes.size() != static_cast<std::size_t>(width) * height * 4) {
        throw InputError("raw frame has " + std::to_string(bytes.size()) + " bytes, expected " +
                         std::to_string(static_cast<std::size_t>(width) * height * 4));
      }
      Image image(width, height);
      const std::size_t row = static_cast<std::size_t>(width) * 4;
      for (std::uint32_t y = 0; y < height; ++y) {
        std::memcpy(image.pixel(0, y),
                    bytes.data() + static_cast<std::size_t>(height - 1 - y) * row, row);
      }
      return image;
    }
    case v1::ENCODING_PNG: {
      Image image = decodePng(bytes, "frame PNG");
      if (image.width() != width || image.height() != height) {
        throw InputError("frame PNG is " + std::to_string(image.width()) + "x" +
                         std::to_string(image.height()) + ", expected " + std::to_string(width) +
                         "x" + std::to_string(height));
      }
      return image;
    }
    case v1::ENCODING_JPEG:
      return decodeJpeg(bytes, width, height);
    default:
      throw InputError("frame has no encoding");
  }
}

}  // namespace pointillist::service
