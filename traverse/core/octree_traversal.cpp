#include "traverse/core/octree_traversal.hpp"

#include <algorithm>
#include <cmath>

#include "common/geometry.hpp"

namespace pointillist::traverse {
namespace {

glm::vec3 grownMin(const OctreeCell& cell, float sizeScale) {
  const float r = cell.maxSplatRadius * sizeScale;
  return {cell.boundsMin[0] - r, cell.boundsMin[1] - r, cell.boundsMin[2] - r};
}

glm::vec3 grownMax(const OctreeCell& cell, float sizeScale) {
  const float r = cell.maxSplatRadius * sizeScale;
  return {cell.boundsMax[0] + r, cell.boundsMax[1] + r, cell.boundsMax[2] + r};
}

// Sorts and merges adjacent ranges of the same top-level cell.
void normalizeRanges(std::vector<PacketRange>& ranges) {
  std::sort(ranges.begin(), ranges.end(), [](const PacketRange& a, const PacketRange& b) {
    return a.topLevel != b.topLevel ? a.topLevel < b.topLevel : a.offset < b.offset;
  });
  std::vector<PacketRange> merged;
  merged.reserve(ranges.size());
  for (const PacketRange& range : ranges) {
    if (!merged.empty() && merged.back().topLevel == range.topLevel &&
        merged.back().offset + merged.back().count == range.offset) {
      merged.back().count += range.count;
    } else {
      merged.push_back(range);
    }
  }
  ranges.swap(merged);
}

}  // namespace

float distanceToCell(const OctreeCell& cell, const glm::vec3& eye, float sizeScale) {
  const glm::vec3 low = grownMin(cell, sizeScale);
  const glm::vec3 high = grownMax(cell, sizeScale);
  const glm::vec3 nearest = glm::clamp(eye, low, high);
  return glm::length(nearest - eye);
}

bool cellBackfacing(const OctreeCell& cell, const glm::vec3& eye, float sizeScale) {
  const NormalCone cone = decodeNormalCone(cell);
  if (!cone.valid || cone.cosHalfAngle <= 0.0) return false;  // cone of 90 deg or more
  const glm::vec3 low = grownMin(cell, sizeScale);
  const glm::vec3 high = grownMax(cell, sizeScale);
  const glm::vec3 centre = 0.5f * (low + high);
  const float radius = 0.5f * glm::length(high - low);
  const glm::vec3 toCell = centre - eye;
  const float distance = glm::length(toCell);
  if (distance <= radius * 1.0001f) return false;  // eye inside: some splat may face it
  // Every splat normal n lies within the cone's half angle C of the axis;
  // every direction from the eye to a splat lies within V of toCell, with
  // sin V = radius / distance. The splat faces away when angle(n, direction)
  // < 90 deg, guaranteed when A + C + V + s < 90 deg, A being the angle from
  // the axis to toCell and s a safety margin. Tested with cosines and sines
  // instead of angles: X = C + V + s must stay below 90 deg (cos X > 0), and
  // then A < 90 deg - X exactly when cos A > sin X. This runs for every cell
  // the walk meets, so it takes no inverse trigonometric functions.
  constexpr double kSafety = 1e-3;  // radians, covers float rounding of bounds and normals
  static const double cosSafety = std::cos(kSafety);
  static const double sinSafety = std::sin(kSafety);
  const double cosC = std::clamp(cone.cosHalfAngle, 0.0, 1.0);
  const double sinC = std::sqrt(1.0 - cosC * cosC);
  const double sinV = std::clamp(static_cast<double>(radius / distance), 0.0, 1.0);
  const double cosV = std::sqrt(1.0 - sinV * sinV);
  const double cosCV = cosC * cosV - sinC * sinV;
  const double sinCV = sinC * cosV + cosC * sinV;
  const double cosX = cosCV * cosSafety - sinCV * sinSafety;
  const double sinX = sinCV * cosSafety + cosCV * sinSafety;
  if (cosX <= 0.0) return false;
  const glm::dvec3 axis(cone.axis[0], cone.axis[1], cone.axis[2]);
  const double cosA = std::clamp(glm::dot(axis, glm::normalize(glm::dvec3(toCell))), -1.0, 1.0);
  return cosA > sinX;
}

std::vector<CellPrefix> topLevelCellsInTile(std::span<const OctreeCell> cells,
                                            const PacketLayers& layers, const Camera& camera,
                                            const TileRect& rect,
                                            const TraversalSettings& settings) {
  std::vector<CellPrefix> found;
  if (cells.empty()) return found;
  const FrustumPlanes planes = tilePlanes(camera, rect, settings.marginPixels);
  const glm::vec3 eye = cameraEye(camera);
  const auto size = static_cast<std::uint32_t>(cells.size());
  std::uint32_t index = 0;
  while (index != kNoIndex && index < size) {
    const OctreeCell& cell = cells[index];
    const bool culled = boxOutside(planes, grownMin(cell, settings.sizeScale),
                                   grownMax(cell, settings.sizeScale)) ||
                        (settings.backfaceCull && cellBackfacing(cell, eye, settings.sizeScale));
    if (culled) {
      index = cell.nextSibling;
    } else if (cell.topLevel != kNoIndex) {
      if (cell.pointsCount + cell.splatsCount > 0) {
        const float distance = distanceToCell(cell, eye, settings.sizeScale);
        found.push_back({cell.topLevel, layers.prefixAt(cell.topLevel, camera, distance,
                                                        settings.lodPixels, settings.sizeScale)});
      }
      index = cell.nextSibling;
    } else {
      index = cell.isLeaf() ? cell.nextSibling : index + 1;
    }
  }
  // Top-level cells are met in depth-first order, which is table order, once each.
  return found;
}

TraversalResult traverseTile(std::span<const OctreeCell> cells, const Camera& camera,
                             const TileRect& rect, const TraversalSettings& settings) {
  TraversalResult result;
  if (cells.empty()) return result;
  const FrustumPlanes planes = tilePlanes(camera, rect, settings.marginPixels);
  const glm::vec3 eye = cameraEye(camera);
  const double focal = focalLengthPixels(camera);
  const auto size = static_cast<std::uint32_t>(cells.size());

  std::uint32_t index = 0;
  while (index != kNoIndex && index < size) {
    const OctreeCell& cell = cells[index];
    ++result.cellsVisited;
    if (boxOutside(planes, grownMin(cell, settings.sizeScale),
                   grownMax(cell, settings.sizeScale))) {
      ++result.cellsCulledFrustum;
      index = cell.nextSibling;
      continue;
    }
    if (settings.backfaceCull && cellBackfacing(cell, eye, settings.sizeScale)) {
      ++result.cellsCulledBackface;
      index = cell.nextSibling;
      continue;
    }
    if (cell.topLevel == kNoIndex) {
      // Above the top-level depth there is no data: examine the children.
      index = cell.isLeaf() ? cell.nextSibling : index + 1;
      continue;
    }
    const float distance = distanceToCell(cell, eye, settings.sizeScale);
    // projectedRadiusPixels(camera, r, distance), with the focal length taken once.
    const bool coarseEnough = distance > 0.0f && cell.maxSplatRadius * settings.sizeScale *
                                                         pixelsPerUnit(focal, distance) <=
                                                     settings.lodPixels;
    if (cell.isLeaf() && !(coarseEnough && cell.splatsCount > 0)) {
      if (cell.pointsCount > 0) {
        result.ranges.push_back({cell.topLevel, cell.pointsOffset, cell.pointsCount});
      }
      index = cell.nextSibling;
    } else if (coarseEnough && cell.splatsCount > 0) {
      result.ranges.push_back({cell.topLevel, cell.splatsOffset, cell.splatsCount});
      index = cell.nextSibling;
    } else {
      index = index + 1;  // the first child follows its parent in depth-first order
    }
  }

  normalizeRanges(result.ranges);
  for (const PacketRange& range : result.ranges) {
    result.splats += range.count;
    if (result.needs.empty() || result.needs.back().cell != range.topLevel) {
      result.needs.push_back({range.topLevel, 0});
    }
    result.needs.back().splats = std::max(result.needs.back().splats, range.offset + range.count);
  }
  return result;
}

}  // namespace pointillist::traverse
