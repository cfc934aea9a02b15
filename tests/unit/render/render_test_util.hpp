#pragma once
// Scenes shared by the render tests.
#include <cmath>
#include <cstdint>
#include <random>
#include <vector>

#include "common/splat.hpp"

namespace pointillist::render::testing {

inline Splat makeSplat(float x, float y, float z, float radius, std::uint8_t r, std::uint8_t g,
                       std::uint8_t b, float nx = 0, float ny = 0, float nz = 0) {
  Splat s{};
  s.position[0] = x;
  s.position[1] = y;
  s.position[2] = z;
  s.normal[0] = nx;
  s.normal[1] = ny;
  s.normal[2] = nz;
  s.radius = radius;
  s.color[0] = r;
  s.color[1] = g;
  s.color[2] = b;
  s.color[3] = 255;
  return s;
}

// A sphere surface with outward normals plus a random cloud inside the unit
// box; radii vary so point sizes from 1 to ~10 pixels appear.
inline std::vector<Splat> mixedScene(std::size_t count, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f), r01(0.0f, 1.0f);
  std::vector<Splat> splats;
  splats.reserve(count);
  for (std::size_t i = 0; i < count; ++i) {
    float x = u(rng), y = u(rng), z = u(rng);
    float nx = 0, ny = 0, nz = 0;
    if (i % 2 == 0) {
      const float len = std::sqrt(x * x + y * y + z * z) + 1e-6f;
      nx = x / len;
      ny = y / len;
      nz = z / len;
      x = 0.8f * nx;
      y = 0.8f * ny;
      z = 0.8f * nz;
    }
    const float radius = 0.004f + 0.03f * r01(rng) * r01(rng);
    splats.push_back(makeSplat(x, y, z, radius, static_cast<std::uint8_t>(rng()),
                               static_cast<std::uint8_t>(rng()), static_cast<std::uint8_t>(rng()),
                               nx, ny, nz));
  }
  return splats;
}

}  // namespace pointillist::render::testing
