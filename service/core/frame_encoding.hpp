#pragma once
// A composed frame (RGBA8, rows bottom-up as the display composes it) in the
// encoding a client asked for: raw RGBA rows top-down, PNG (RGB), or JPEG
// through libturbojpeg. Decoders are here too, for the clients and the tests.
#include <cstdint>
#include <span>
#include <vector>

#include "common/image.hpp"
#include "service_v1.pb.h"

namespace pointillist::service {

inline constexpr std::uint32_t kDefaultJpegQuality = 90;

// Throws Error naming the encoding when the encoder fails, UsageError for
// ENCODING_UNSPECIFIED or a quality outside 1-100.
std::vector<std::uint8_t> encodeFrame(const Image& frame, v1::Encoding encoding,
                                      std::uint32_t jpegQuality = kDefaultJpegQuality);

// Back to an RGBA8 image, rows bottom-up (alpha 255 for PNG-RGB and JPEG).
// Throws InputError for data that does not decode or does not match the size.
Image decodeFrame(std::span<const std::uint8_t> bytes, v1::Encoding encoding, std::uint32_t width,
                  std::uint32_t height);

}  // namespace pointillist::service
