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
                               const TileRect& rect, const TileRect& drawn,
                               std::span<const std::byte> words) {
  const std::string which =
      "part of tile " + std::to_string(tile) + " of frame " + std::to_string(frame);
  const bool empty = drawn.width() == 0 || drawn.height() == 0;
  if (!rectWithin(drawn, rect)) {
    throw ProtocolError(which + " drew " + std::to_string(drawn.width()) + "x" +
                        std::to_string(drawn.height()) + " at (" + std::to_string(drawn.x()) + "," +
                        std::to_string(drawn.y()) + "), outside its tile " +
                        std::to_string(rect.width()) + "x" + std::to_string(rect.height()) +
                        " at (" + std::to_string(rect.x()) + "," + std::to_string(rect.y()) + ")");
  }
  const std::size_t drawnPixels =
      empty ? 0 : static_cast<std::size_t>(drawn.width()) * drawn.height();
  if (words.size() != drawnPixels * sizeof(std::uint64_t)) {
    throw ProtocolError(which + " has " + std::to_string(words.size()) + " bytes of words for " +
                        std::to_string(drawnPixels) + " pixels");
  }
  const std::size_t pixels = static_cast<std::size_t>(rect.width()) * rect.height();
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
  if (empty) return;
  // The payload need not be aligned for uint64: copy a block at a time.
  constexpr std::size_t kBlock = 256;
  std::uint64_t block[kBlock];
  const std::size_t width = drawn.width();
  for (std::size_t row = 0; row < drawn.height(); ++row) {
    const std::byte* from = words.data() + row * width * sizeof(std::uint64_t);
    std::uint64_t* into = composing.words.data() +
                          (drawn.y() - rect.y() + row) * std::size_t{rect.width()} +
                          (drawn.x() - rect.x());
    for (std::size_t at = 0; at < width; at += kBlock) {
      const std::size_t count = std::min(kBlock, width - at);
      std::memcpy(block, from + at * sizeof(std::uint64_t), count * sizeof(std::uint64_t));
      for (std::size_t i = 0; i < count; ++i) into[at + i] = std::min(into[at + i], block[i]);
    }
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
