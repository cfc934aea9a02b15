#include "common/pixel_runs.hpp"

#include <cstring>
#include <string>

#include "common/errors.hpp"

namespace pointillist {

namespace {

void appendWord(std::vector<std::byte>& out, std::uint32_t value) {
  std::byte bytes[4];
  for (int i = 0; i < 4; ++i) bytes[i] = static_cast<std::byte>(value >> (8 * i));
  out.insert(out.end(), bytes, bytes + 4);
}

void checkBox(std::span<const std::byte> tile, std::size_t pixelBytes, std::uint32_t tileWidth,
              const PixelBox& box, const char* what) {
  if (std::uint64_t{box.x} + box.width > tileWidth ||
      (std::uint64_t{box.y} + box.height) * tileWidth * pixelBytes > tile.size())
    throw UsageError(std::string(what) + ": the box does not fit the tile");
}

std::uint32_t readWord(const std::byte* at) {
  std::uint32_t value = 0;
  for (int i = 0; i < 4; ++i)
    value |= std::uint32_t{std::to_integer<std::uint8_t>(at[i])} << (8 * i);
  return value;
}

// One pixel a Word (4 or 8 bytes): a compare a pixel, not a memcmp call.
template <typename Word>
std::vector<std::byte> encodeRuns(std::span<const std::byte> tile, std::uint32_t tileWidth,
                                  const PixelBox& box, Word empty) {
  std::vector<std::byte> out;
  std::uint32_t skipped = 0;  // empty pixels before the next run
  for (std::uint32_t r = 0; r < box.height; ++r) {
    const std::byte* row =
        tile.data() + (std::size_t{box.y + r} * tileWidth + box.x) * sizeof(Word);
    std::uint32_t x = 0;
    while (x < box.width) {
      Word pixel;
      std::memcpy(&pixel, row + std::size_t{x} * sizeof(Word), sizeof(Word));
      if (pixel == empty) {
        ++skipped;
        ++x;
        continue;
      }
      // A run: to the next empty pixel or the row's end (a run never spans
      // rows, so the next row's first pixels start a new one).
      std::uint32_t end = x + 1;
      for (; end < box.width; ++end) {
        std::memcpy(&pixel, row + std::size_t{end} * sizeof(Word), sizeof(Word));
        if (pixel == empty) break;
      }
      appendWord(out, skipped);
      appendWord(out, end - x);
      out.insert(out.end(), row + std::size_t{x} * sizeof(Word),
                 row + std::size_t{end} * sizeof(Word));
      skipped = 0;
      x = end;
    }
  }
  if (skipped > 0) {  // the box's empty end, as a run of none
    appendWord(out, skipped);
    appendWord(out, 0);
  }
  return out;
}

}  // namespace

std::vector<std::byte> pixelsInBox(std::span<const std::byte> tile, std::size_t pixelBytes,
                                   std::uint32_t tileWidth, const PixelBox& box) {
  checkBox(tile, pixelBytes, tileWidth, box, "pixelsInBox");
  const std::size_t rowBytes = std::size_t{box.width} * pixelBytes;
  std::vector<std::byte> bytes(rowBytes * box.height);
  for (std::uint32_t r = 0; r < box.height; ++r)
    std::memcpy(bytes.data() + r * rowBytes,
                tile.data() + (std::size_t{box.y + r} * tileWidth + box.x) * pixelBytes, rowBytes);
  return bytes;
}

std::vector<std::byte> encodePixelRuns(std::span<const std::byte> tile, std::size_t pixelBytes,
                                       std::uint32_t tileWidth, const PixelBox& box,
                                       std::span<const std::byte> empty) {
  if (empty.size() != pixelBytes || (pixelBytes != 4 && pixelBytes != 8))
    throw UsageError("encodePixelRuns: pixels of 4 or 8 bytes, and one empty pixel");
  checkBox(tile, pixelBytes, tileWidth, box, "encodePixelRuns");
  if (pixelBytes == 4) {
    std::uint32_t word;
    std::memcpy(&word, empty.data(), 4);
    return encodeRuns<std::uint32_t>(tile, tileWidth, box, word);
  }
  std::uint64_t word;
  std::memcpy(&word, empty.data(), 8);
  return encodeRuns<std::uint64_t>(tile, tileWidth, box, word);
}

std::vector<std::byte> decodePixelRuns(std::span<const std::byte> runs, std::size_t pixelBytes,
                                       std::size_t pixels, std::span<const std::byte> empty) {
  if (empty.size() != pixelBytes || pixelBytes == 0)
    throw UsageError("decodePixelRuns: the empty pixel must be one pixel's bytes");
  std::vector<std::byte> out(pixels * pixelBytes);
  for (std::size_t i = 0; i < pixels; ++i)
    std::memcpy(out.data() + i * pixelBytes, empty.data(), pixelBytes);
  std::size_t at = 0, pixel = 0;
  while (at < runs.size()) {
    if (runs.size() - at < 8)
      throw ProtocolError("tile image runs end inside a run's counts at byte " +
                          std::to_string(at));
    const std::uint64_t skip = readWord(runs.data() + at);
    const std::uint64_t count = readWord(runs.data() + at + 4);
    at += 8;
    if (skip + count > pixels - pixel)
      throw ProtocolError("tile image runs go past the box's " + std::to_string(pixels) +
                          " pixels");
    pixel += skip;
    if (count * pixelBytes > runs.size() - at)
      throw ProtocolError("tile image run of " + std::to_string(count) +
                          " pixels is cut short at byte " + std::to_string(runs.size()));
    std::memcpy(out.data() + pixel * pixelBytes, runs.data() + at, count * pixelBytes);
    at += count * pixelBytes;
    pixel += count;
  }
  if (pixel != pixels)
    throw ProtocolError("tile image runs cover " + std::to_string(pixel) + " of the box's " +
                        std::to_string(pixels) + " pixels");
  return out;
}

}  // namespace pointillist
