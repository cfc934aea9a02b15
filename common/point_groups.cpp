#include "common/point_groups.hpp"

#include <cstring>

namespace pointillist {

bool writePointGroups(std::span<const Splat> splats, std::size_t first, float* values) {
  using G = PointGroups;
  bool normals = false;
  for (std::size_t k = 0; k < splats.size(); ++k) {
    const Splat& s = splats[k];
    const std::size_t i = first + k;
    values[G::valueIndex(G::kX, i)] = s.position[0];
    values[G::valueIndex(G::kY, i)] = s.position[1];
    values[G::valueIndex(G::kZ, i)] = s.position[2];
    values[G::valueIndex(G::kRadius, i)] = s.radius;
    values[G::valueIndex(G::kNormalX, i)] = s.normal[0];
    values[G::valueIndex(G::kNormalY, i)] = s.normal[1];
    values[G::valueIndex(G::kNormalZ, i)] = s.normal[2];
    const std::uint32_t color = packColor(s.color[0], s.color[1], s.color[2], s.color[3]);
    std::memcpy(&values[G::valueIndex(G::kColor, i)], &color, sizeof color);
    normals = normals || shadesWithNormal(s);
  }
  return normals;
}

}  // namespace pointillist
