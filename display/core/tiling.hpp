#pragma once
// Mini frusta from the box of interest (seed 003 §4.2): the screen rectangle
// the data covers is split into tiles, each worth one render packet.
#include <cstdint>
#include <optional>
#include <vector>

#include "common/camera.hpp"

namespace pointillist::display {

// The pixel rectangle covered by the projection of the box (grown by
// `marginWorld`), clipped to the frame. Empty (nullopt) when the box is
// entirely off screen. When the box reaches behind the eye, the full frame.
std::optional<TileRect> boxOfInterest(const Camera& camera, const glm::vec3& boxMin,
                                      const glm::vec3& boxMax, float marginWorld);

// Splits `area` into about `targetTiles` near-square tiles no smaller than
// minTileSize pixels on a side (unless the area itself is smaller). Tiles cover
// every pixel of the area exactly once; row-major from the bottom-left.
std::vector<TileRect> splitIntoTiles(const TileRect& area, std::uint32_t targetTiles,
                                     std::uint32_t minTileSize);

}  // namespace pointillist::display
