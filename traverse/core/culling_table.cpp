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
  out.radius = 0.5f * glm::length(out.high - out.low);
  const NormalCone cone = decodeNormalCone(cell);
  if (cone.valid && cone.cosHalfAngle > 0.0) {  // a cone of 90 deg or more culls nothing
    out.coneAxis = glm::vec3(glm::normalize(glm::dvec3(cone.axis[0], cone.axis[1], cone.axis[2])));
    const double cosCone = std::min(cone.cosHalfAngle, 1.0);
    out.cosCone = static_cast<float>(cosCone);
    out.sinCone = static_cast<float>(std::sqrt(1.0 - cosCone * cosCone));
  }
  out.maxSplatRadius = cell.maxSplatRadius;
  out.nextSibling = cell.nextSibling;
  out.topLevel = cell.topLevel;
  out.flags = (cell.isLeaf() ? CellCulling::kLeaf : 0u) |
              (cell.pointsCount > 0 ? CellCulling::kHasPoints : 0u) |
              (cell.splatsCount > 0 ? CellCulling::kHasSplats : 0u) |
              std::uint32_t{cell.level} << CellCulling::kLevelShift;
  return out;
}

CullingTable::CullingTable(std::span<const OctreeCell> cells, float sizeScale)
    : cells_(cells), sizeScale_(sizeScale) {
  culling_.reserve(cells.size());
  for (const OctreeCell& cell : cells) culling_.push_back(cellCulling(cell, sizeScale));
  // Depth-first order: a cell's children follow it up to its next sibling.
  struct Open {
    std::size_t end;
    std::size_t index;
  };
  std::vector<Open> ancestors;
  for (std::size_t i = 0; i < cells.size(); ++i) {
    while (!ancestors.empty() && i >= ancestors.back().end) ancestors.pop_back();
    if (!ancestors.empty()) {
      const CellCulling& parent = culling_[ancestors.back().index];
      CellCulling& child = culling_[i];
      if (glm::all(glm::greaterThanEqual(child.low, parent.low)) &&
          glm::all(glm::lessThanEqual(child.high, parent.high)))
        child.flags |= CellCulling::kWithinParent;
    }
    if (!cells[i].isLeaf()) {
      ancestors.push_back(
          {cells[i].nextSibling == kNoIndex ? cells.size() : cells[i].nextSibling, i});
    }
  }
  children_.assign(cells.size(), {});
  for (std::size_t i = 0; i < cells.size(); ++i) {
    const OctreeCell& parent = cells[i];
    if (parent.isLeaf() || parent.topLevel == kNoIndex) continue;
    const std::size_t end = parent.nextSibling == kNoIndex ? cells.size() : parent.nextSibling;
    ChildrenSplats group;
    bool oneRange = true;
    bool first = true;
    for (std::size_t child = i + 1; child < end && oneRange;) {
      const OctreeCell& c = cells[child];
      const bool fits =
          c.splatsCount > 0 && c.topLevel == parent.topLevel &&
          (culling_[child].flags & CellCulling::kWithinParent) != 0 &&
          (first ? true : c.level == group.level && c.splatsOffset == group.offset + group.count);
      if (!fits) {
        oneRange = false;
        break;
      }
      if (first) {
        group.offset = c.splatsOffset;
        group.level = c.level;
        first = false;
      }
      group.count += c.splatsCount;
      group.maxSplatRadius = std::max(group.maxSplatRadius, c.maxSplatRadius);
      // The next child: this one's next sibling (its subtree is skipped).
      child = c.nextSibling == kNoIndex ? end : c.nextSibling;
    }
    if (oneRange && !first) {
      children_[i] = group;
      culling_[i].flags |= CellCulling::kChildrenInOneRange;
    }
  }
}

bool cellBackfacing(const CellCulling& cell, const glm::vec3& eye) {
  return cellFacing(cell, eye) == Facing::Away;
}

Facing cellFacing(const CellCulling& cell, const glm::vec3& eye) {
  if (cell.cosCone <= 0.0f) return Facing::Mixed;
  const glm::vec3 toCell = cell.centre() - eye;
  const float squared = glm::dot(toCell, toCell);
  const float radius = cell.radius;
  if (squared <= radius * radius * 1.0002f) return Facing::Mixed;  // eye inside
  // Every splat normal n lies within the cone's half angle C of the axis;
  // every direction from the eye to a splat lies within V of toCell, with
  // sin V = radius / distance. The splat faces away when angle(n, direction)
  // < 90 deg, guaranteed when A + C + V + s < 90 deg, A being the angle from
  // the axis to toCell and s a safety margin. Tested with cosines and sines
  // instead of angles: X = C + V + s must stay below 90 deg (cos X > 0), and
  // then A < 90 deg - X exactly when cos A > sin X. Every splat faces the eye
  // when the angle from the axis to -toCell passes the same test. Every term
  // is taken times the distance D (sin V D = radius, cos A D = axis . toCell),
  // which leaves one square root and no division.
  // In float: s covers its rounding (a relative 1e-7 moves an angle by at
  // most 5e-4 radians, where its cosine is near 1) as well as that of the
  // bounds and normals.
  constexpr float kCosSafety = 0.999998f;       // cos(2e-3 radians)
  constexpr float kSinSafety = 0.00199999867f;  // sin(2e-3 radians)
  const float cosC = cell.cosCone;
  const float sinC = cell.sinCone;
  const float cosVD = std::sqrt(squared - radius * radius);
  const float cosCVD = cosC * cosVD - sinC * radius;
  const float sinCVD = sinC * cosVD + cosC * radius;
  const float cosXD = cosCVD * kCosSafety - sinCVD * kSinSafety;
  const float sinXD = sinCVD * kCosSafety + cosCVD * kSinSafety;
  if (cosXD <= 0.0f) return Facing::Mixed;
  const float cosAD = glm::dot(cell.coneAxis, toCell);
  if (cosAD > sinXD) return Facing::Away;
  if (-cosAD > sinXD) return Facing::Toward;
  return Facing::Mixed;
}

float distanceToCell(const CellCulling& cell, const glm::vec3& eye) {
  const glm::vec3 nearest = glm::clamp(eye, cell.low, cell.high);
  return glm::length(nearest - eye);
}

}  // namespace pointillist::traverse
