#include "common/image_compression.hpp"

#include <memory>

#include <zstd.h>

#include "common/errors.hpp"

namespace pointillist {

namespace {

struct CompressContextFree {
  void operator()(ZSTD_CCtx* context) const { ZSTD_freeCCtx(context); }
};
struct DecompressContextFree {
  void operator()(ZSTD_DCtx* context) const { ZSTD_freeDCtx(context); }
};

// One context a thread: making one costs more than compressing a small tile.
ZSTD_CCtx* compressContext() {
  thread_local std::unique_ptr<ZSTD_CCtx, CompressContextFree> context(ZSTD_createCCtx());
  if (!context) throw Error("zstd could not make a compression context");
  return context.get();
}

ZSTD_DCtx* decompressContext() {
  thread_local std::unique_ptr<ZSTD_DCtx, DecompressContextFree> context(ZSTD_createDCtx());
  if (!context) throw Error("zstd could not make a decompression context");
  return context.get();
}

}  // namespace

ImageCompression parseImageCompression(const std::string& text) {
  if (text == "auto") return ImageCompression::Auto;
  if (text == "zstd") return ImageCompression::Zstd;
  if (text == "off") return ImageCompression::Off;
  throw UsageError("--image-compression must be auto, zstd or off, not '" + text + "'");
}

const char* imageCompressionName(ImageCompression compression) {
  switch (compression) {
    case ImageCompression::Auto:
      return "auto";
    case ImageCompression::Zstd:
      return "zstd";
    case ImageCompression::Off:
      return "off";
  }
  return "?";
}

bool compressesImages(ImageCompression compression, bool displayOnThisMachine) {
  return compression == ImageCompression::Zstd ||
         (compression == ImageCompression::Auto && !displayOnThisMachine);
}

std::vector<std::byte> compressImageBytes(std::span<const std::byte> bytes, int level) {
  if (bytes.size() < kMinCompressedPayload) return {};
  std::vector<std::byte> frame(ZSTD_compressBound(bytes.size()));
  const std::size_t size = ZSTD_compressCCtx(compressContext(), frame.data(), frame.size(),
                                             bytes.data(), bytes.size(), level);
  if (ZSTD_isError(size) != 0)
    throw Error(std::string("zstd could not compress a tile image: ") + ZSTD_getErrorName(size));
  if (size >= bytes.size()) return {};
  frame.resize(size);
  return frame;
}

std::vector<std::byte> decompressImageBytes(std::span<const std::byte> frame,
                                            std::size_t expectedBytes, const std::string& what) {
  // The frame must say its size, and say this one, before anything is allocated:
  // a corrupt header must not ask for gigabytes.
  const unsigned long long declared = ZSTD_getFrameContentSize(frame.data(), frame.size());
  if (declared == ZSTD_CONTENTSIZE_ERROR)
    throw ProtocolError(what + " is not a zstd frame (" + std::to_string(frame.size()) + " bytes)");
  if (declared == ZSTD_CONTENTSIZE_UNKNOWN || declared != expectedBytes)
    throw ProtocolError(what + " is a zstd frame of " +
                        (declared == ZSTD_CONTENTSIZE_UNKNOWN
                             ? std::string("unknown size")
                             : std::to_string(declared) + " bytes") +
                        ", its header says " + std::to_string(expectedBytes));
  const std::size_t frameBytes = ZSTD_findFrameCompressedSize(frame.data(), frame.size());
  if (ZSTD_isError(frameBytes) != 0 || frameBytes != frame.size())
    throw ProtocolError(what + " has " + std::to_string(frame.size()) +
                        " bytes that are not exactly one zstd frame");
  std::vector<std::byte> bytes(expectedBytes);
  const std::size_t size = ZSTD_decompressDCtx(decompressContext(), bytes.data(), bytes.size(),
                                               frame.data(), frame.size());
  if (ZSTD_isError(size) != 0 || size != expectedBytes)
    throw ProtocolError(what + " does not decompress: " +
                        (ZSTD_isError(size) != 0 ? std::string(ZSTD_getErrorName(size))
                                                 : std::to_string(size) + " bytes"));
  return bytes;
}

}  // namespace pointillist
