#pragma once
// The display's half of splitting heavy tiles by their data
// (docs/scheduling.md §9): the parts of one tile, drawn by several render
// processes from different cells, arrive as the cpu point kernel's words
// (v1::PIXEL_FORMAT_POINT_WORDS64) and compose by the minimum word per pixel,
// as the kernel composes its own threads' buffers. Nearest wins and equal
// depths fall to the smaller colour, whatever the order parts come in, so the
// composed tile equals the tile drawn whole, bit for bit.
#include <cstddef>
#include <cstdint>
#include <map>
#include <span>
#include <tuple>
#include <vector>

#include "common/camera.hpp"
#include "common/image.hpp"

namespace pointillist::display {

// RGBA8 as the kernel's words hold it: R in the low byte.
constexpr std::uint32_t packRgba(Rgba8 color) {
  return std::uint32_t{color[0]} | std::uint32_t{color[1]} << 8 | std::uint32_t{color[2]} << 16 |
         std::uint32_t{color[3]} << 24;
}

// The kernel's packed words to RGBA8 (their low half), `background` (RGBA8,
// R in the low byte) where nothing was drawn; `rgba` holds 4 bytes a word.
void pointWordsToRgba(std::span<const std::uint64_t> words, std::uint32_t background,
                      std::uint8_t* rgba);

class TilePartCompositor {
 public:
  // Merges one part's words (drawn.width x drawn.height little-endian uint64,
  // rows bottom-up; `drawn` in screen pixels inside the tile's `rect`, which
  // is all a part drew) into its tile's buffer, keyed by frame, tile and
  // attempt (a re-issued tile's parts never mix with the earlier attempt's).
  // ProtocolError when the bytes do not fit `drawn`, `drawn` lies outside
  // `rect`, or `rect` differs from the tile's earlier parts.
  void merge(std::uint64_t frame, std::uint32_t tile, std::uint32_t attempt, const TileRect& rect,
             const TileRect& drawn, std::span<const std::byte> words);
  // The same for a part that sends its whole tile.
  void merge(std::uint64_t frame, std::uint32_t tile, std::uint32_t attempt, const TileRect& rect,
             std::span<const std::byte> words) {
    merge(frame, tile, attempt, rect, rect, words);
  }
  // The composed tile as RGBA8 (rows bottom-up); forgets every attempt of
  // the tile. UsageError when no part of it was merged.
  std::vector<std::uint8_t> take(std::uint64_t frame, std::uint32_t tile, std::uint32_t attempt,
                                 std::uint32_t background);
  // Forgets what is left of a frame's tiles (parts of attempts that lost).
  void dropFrame(std::uint64_t frame);
  std::size_t tilesHeld() const { return tiles_.size(); }

 private:
  struct Composing {
    TileRect rect;
    std::vector<std::uint64_t> words;
  };
  std::map<std::tuple<std::uint64_t, std::uint32_t, std::uint32_t>, Composing> tiles_;
};

}  // namespace pointillist::display
