#pragma once
// The one record every stage shares: an input point (level 0) or a level-splat.
#include <cstdint>
#include <type_traits>

namespace pointillist {

struct Splat {
  float position[3];
  float normal[3];        // unit length; (0,0,0) when unknown
  float radius;           // world-space disk radius
  std::uint8_t color[4];  // RGBA8
};

// A normal is known when any component is non-zero.
inline bool hasNormal(const Splat& splat) {
  return splat.normal[0] != 0.0f || splat.normal[1] != 0.0f || splat.normal[2] != 0.0f;
}

static_assert(sizeof(Splat) == 32, "Splat is a 32-byte wire and file record");
static_assert(std::is_trivially_copyable_v<Splat>);
static_assert(std::is_standard_layout_v<Splat>);

}  // namespace pointillist
