#include "display/core/tile_parts.hpp"

#include <algorithm>
#include <cstring>
#include <string>

#include "common/errors.hpp"

namespace pointillist::display {

void pointWordsToRgba(std::span<const std::uint64_t> words, std::uint32_t background,
                      std::uint8_t* rgba) {
  for (std::size_t i = 0; i < words.size(); ++i) {
    const std::uint32_t color =
        words[i] == ~std::uint64_t{0} ? background : static_cast<std::uint32_t>(words[i]);
    rgba[4 * i + 0] = static_cast<std::uint8_t>(color);
    rgba[4 * i + 1] = static_cast<std::uint8_t>(color >> 8);
    rgba[4 * i + 2] = static_cast<std::uint8_t>(color >> 16);
    rgba[4 * i + 3] = static_cast<std::uint8_t>(color >> 24);
  }
}

void TilePartCompositor::merge(std::uint64_t frame, std::uint32_t tile, std::uint32_t attempt,
                               const TileRect& rect, std::span<const std::byte> words) {
  const std::size_t pixels = static_cast<std::size_t>(rect.width()) * rect.height();
  if (words.size() != pixels * sizeof(std::uint64_t)) {
    throw ProtocolError("part of tile " + std::to_string(tile) + " of frame " +
                        std::to_string(frame) + " has " + std::to_string(words.size()) +
                        " bytes of words for " + std::to_string(pixels) + " pixels");
  }
  auto [found, fresh] = tiles_.try_emplace({frame, tile, attempt});
  Composing& composing = found->second;
  if (fresh) {
    composing.rect = rect;
    composing.words.assign(pixels, ~std::uint64_t{0});
  } else if (composing.rect.x() != rect.x() || composing.rect.y() != rect.y() ||
             composing.rect.width() != rect.width() || composing.rect.height() != rect.height()) {
    throw ProtocolError("parts of tile " + std::to_string(tile) + " of frame " +
                        std::to_string(frame) + " disagree on its rectangle");
  }
  // The payload need not be aligned for uint64: copy a block at a time.
  constexpr std::size_t kBlock = 256;
  std::uint64_t block[kBlock];
  for (std::size_t at = 0; at < pixels; at += kBlock) {
    const std::size_t count = std::min(kBlock, pixels - at);
    std::memcpy(block, words.data() + at * sizeof(std::uint64_t), count * sizeof(std::uint64_t));
    std::uint64_t* into = composing.words.data() + at;
    for (std::size_t i = 0; i < count; ++i) into[i] = std::min(into[i], block[i]);
  }
}

std::vector<std::uint8_t> TilePartCompositor::take(std::uint64_t frame, std::uint32_t tile,
                                                   std::uint32_t attempt,
                                                   std::uint32_t background) {
  const auto found = tiles_.find({frame, tile, attempt});
  if (found == tiles_.end()) {
    throw UsageError("no part of tile " + std::to_string(tile) + " of frame " +
                     std::to_string(frame) + " was composed");
  }
  std::vector<std::uint8_t> rgba(found->second.words.size() * 4);
  pointWordsToRgba(found->second.words, background, rgba.data());
  tiles_.erase(tiles_.lower_bound({frame, tile, 0}),
               tiles_.upper_bound({frame, tile, ~std::uint32_t{0}}));
  return rgba;
}

void TilePartCompositor::dropFrame(std::uint64_t frame) {
  tiles_.erase(tiles_.lower_bound({frame, 0, 0}), tiles_.lower_bound({frame + 1, 0, 0}));
}

}  // namespace pointillist::display
