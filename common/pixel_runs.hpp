#pragma once
// Tile images as runs (v1::TileImageHeader.runs_bytes): the pixels of the
// drawn box, row after row as one sequence, told as runs. Each run is a
// little-endian uint32 of pixels skipped (empty: the background, or the
// point kernel's empty word), a uint32 of pixels that follow, then those
// pixels. The runs cover the box exactly. A scanned surface seen from afar
// leaves about half of a part's box empty (the city at 4K: 52 % lit, a run
// every 200 lit pixels), so runs carry about half the bytes.
#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

namespace pointillist {

// Where a box lies in a tile's pixels (rows bottom-up, `tileWidth` a row).
struct PixelBox {
  std::uint32_t x = 0, y = 0, width = 0, height = 0;
  bool operator==(const PixelBox&) const = default;
};

// The box's pixels of `tile` (pixelBytes each), row after row: a tile image
// that carries its box as it is.
std::vector<std::byte> pixelsInBox(std::span<const std::byte> tile, std::size_t pixelBytes,
                                   std::uint32_t tileWidth, const PixelBox& box);

// The box's pixels of `tile` (pixelBytes each: 4 or 8) as runs, skipping
// the pixels whose bytes equal `empty` (pixelBytes long). A run ends at its
// row's end.
std::vector<std::byte> encodePixelRuns(std::span<const std::byte> tile, std::size_t pixelBytes,
                                       std::uint32_t tileWidth, const PixelBox& box,
                                       std::span<const std::byte> empty);

// The box's pixels back, `empty` where runs skipped. Throws ProtocolError
// when the runs do not cover exactly `pixels` pixels in exactly these bytes.
std::vector<std::byte> decodePixelRuns(std::span<const std::byte> runs, std::size_t pixelBytes,
                                       std::size_t pixels, std::span<const std::byte> empty);

}  // namespace pointillist
