#pragma once
// The CPU point kernel's layout of a cell (render/raster/cpu_point_renderer):
// groups of kPad splats, each group one field after another (kPad x's, kPad
// y's, ...), the last group padded with zeros, all in one block. A range of a
// cell is one stretch of memory: a tile draws thousands of short ranges of
// small cells, and one array per field started eight cold streams on eight
// pages for each.
//
// Render processes keep their cells in it; a data-send process also lays its
// packets out in it in shared memory, so render processes of its machine draw
// them in place (common/shared_packets.hpp).
#include <cstddef>
#include <cstdint>
#include <span>

#include "common/splat.hpp"

namespace pointillist {

struct PointGroups {
  static constexpr std::size_t kPad = 16;  // the widest vector's lanes
  // A field's place in its group, kPad 4-byte values each.
  static constexpr std::size_t kX = 0, kY = 1, kZ = 2, kRadius = 3;
  static constexpr std::size_t kNormalX = 4, kNormalY = 5, kNormalZ = 6, kColor = 7;
  static constexpr std::size_t kFields = 8;
  static constexpr std::size_t kGroupValues = kFields * kPad;
  static constexpr std::size_t kAlignment = 64;  // a block starts on a cache line
  // Where splat i's `field` lies among a block's values; the kPad - i % kPad
  // values from there are those of splats i, i + 1, ... of its group.
  static constexpr std::size_t valueIndex(std::size_t field, std::size_t i) {
    return (i / kPad) * kGroupValues + field * kPad + i % kPad;
  }
  // Bytes of a block holding `splats` (whole groups).
  static constexpr std::size_t blockBytes(std::size_t splats) {
    return (splats + kPad - 1) / kPad * kPad * kFields * 4;
  }
};

// RGBA8 in one word, R in the low byte.
inline std::uint32_t packColor(std::uint32_t r, std::uint32_t g, std::uint32_t b, std::uint32_t a) {
  return r | (g << 8) | (b << 16) | (a << 24);
}

// Whether a splat's normal is long enough to shade with (as the kernel decides).
inline bool shadesWithNormal(const Splat& splat) {
  const float lengthSquared = splat.normal[0] * splat.normal[0] +
                              splat.normal[1] * splat.normal[1] + splat.normal[2] * splat.normal[2];
  return lengthSquared > 0.25f;
}

// Writes `splats` as splats first, first + 1, ... of the block at `values`
// (which must have room for them); the padding is not touched. Returns
// whether any of them shades with its normal.
bool writePointGroups(std::span<const Splat> splats, std::size_t first, float* values);

}  // namespace pointillist
