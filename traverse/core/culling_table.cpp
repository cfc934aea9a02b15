#include "traverse/core/culling_table.hpp"

#include <algorithm>
#include <cmath>

#include "common/geometry.hpp"

namespace pointillist::traverse {

CellCulling cellCulling(const OctreeCell& cell, float sizeScale) {
  CellCulling out;
  const float r = cell.maxSplatRadius * sizeScale;
  out.low = {cell.boundsMin[0] - r, cell.boundsMin[1] - r, cell.boundsMin[2] - r};
  out.high = {cell.boundsMax[0] + r, cell.boundsMax[1] + r, cell.boundsMax[2] + r};
  out.centre = 0.5f * (out.low + out.high);
  out.radius = 0.5f * glm::length(out.high - out.low);
  const NormalCone cone = decodeNormalCone(cell);
  if (cone.valid && cone.cosHalfAngle > 0.0) {  // a cone of 90 deg or more culls nothing
    out.coneAxis = {cone.axis[0], cone.axis[1], cone.axis[2]};
    out.cosCone = std::min(cone.cosHalfAngle, 1.0);
    out.sinCone = std::sqrt(1.0 - out.cosCone * out.cosCone);
  }
  return out;
}

CullingTable::CullingTable(std::span<const OctreeCell> cells, float sizeScale)
    : cells_(cells), sizeScale_(sizeScale) {
  culling_.reserve(cells.size());
  for (const OctreeCell& cell : cells) culling_.push_back(cellCulling(cell, sizeScale));
  // Depth-first order: a cell's children follow it up to its next sibling.
  withinParent_.assign(cells.size(), 0);
  struct Open {
    std::size_t end;
    std::size_t index;
  };
  std::vector<Open> ancestors;
  for (std::size_t i = 0; i < cells.size(); ++i) {
    while (!ancestors.empty() && i >= ancestors.back().end) ancestors.pop_back();
    if (!ancestors.empty()) {
      const CellCulling& parent = culling_[ancestors.back().index];
      const CellCulling& child = culling_[i];
      withinParent_[i] = glm::all(glm::greaterThanEqual(child.low, parent.low)) &&
                         glm::all(glm::lessThanEqual(child.high, parent.high));
    }
    if (!cells[i].isLeaf()) {
      ancestors.push_back(
          {cells[i].nextSibling == kNoIndex ? cells.size() : cells[i].nextSibling, i});
    }
  }
}

bool cellBackfacing(const CellCulling& cell, const glm::vec3& eye) {
  return cellFacing(cell, eye) == Facing::Away;
}

Facing cellFacing(const CellCulling& cell, const glm::vec3& eye) {
  if (cell.cosCone <= 0.0) return Facing::Mixed;
  const glm::vec3 toCell = cell.centre - eye;
  const float distance = glm::length(toCell);
  if (distance <= cell.radius * 1.0001f) return Facing::Mixed;  // eye inside
  // Every splat normal n lies within the cone's half angle C of the axis;
  // every direction from the eye to a splat lies within V of toCell, with
  // sin V = radius / distance. The splat faces away when angle(n, direction)
  // < 90 deg, guaranteed when A + C + V + s < 90 deg, A being the angle from
  // the axis to toCell and s a safety margin. Tested with cosines and sines
  // instead of angles: X = C + V + s must stay below 90 deg (cos X > 0), and
  // then A < 90 deg - X exactly when cos A > sin X. Every splat faces the eye
  // when the angle from the axis to -toCell passes the same test.
  constexpr double kSafety = 1e-3;  // radians, covers float rounding of bounds and normals
  static const double cosSafety = std::cos(kSafety);
  static const double sinSafety = std::sin(kSafety);
  const double cosC = cell.cosCone;
  const double sinC = cell.sinCone;
  const double sinV = std::clamp(static_cast<double>(cell.radius / distance), 0.0, 1.0);
  const double cosV = std::sqrt(1.0 - sinV * sinV);
  const double cosCV = cosC * cosV - sinC * sinV;
  const double sinCV = sinC * cosV + cosC * sinV;
  const double cosX = cosCV * cosSafety - sinCV * sinSafety;
  const double sinX = sinCV * cosSafety + cosCV * sinSafety;
  if (cosX <= 0.0) return Facing::Mixed;
  const double cosA =
      std::clamp(glm::dot(cell.coneAxis, glm::normalize(glm::dvec3(toCell))), -1.0, 1.0);
  if (cosA > sinX) return Facing::Away;
  if (-cosA > sinX) return Facing::Toward;
  return Facing::Mixed;
}

float distanceToCell(const CellCulling& cell, const glm::vec3& eye) {
  const glm::vec3 nearest = glm::clamp(eye, cell.low, cell.high);
  return glm::length(nearest - eye);
}

}  // namespace pointillist::traverse
