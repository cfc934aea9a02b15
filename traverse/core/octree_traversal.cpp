#include "traverse/core/octree_traversal.hpp"

#include <algorithm>
#include <cmath>

#include "common/errors.hpp"
#include "common/geometry.hpp"

namespace pointillist::traverse {
namespace {

// Sorts by (topLevel, offset) and merges adjacent ranges of the same top-level
// cell. The walk meets each top-level cell's subtree in one piece, in table
// order, so only the ranges within a cell need sorting (levels come before
// points in a packet, coarse before fine).
void normalizeRanges(std::vector<PacketRange>& ranges) {
  const auto byOffset = [](const PacketRange& a, const PacketRange& b) {
    return a.offset < b.offset;
  };
  bool cellsInOrder = true;
  for (auto group = ranges.begin(); group != ranges.end();) {
    const auto end = std::find_if(group, ranges.end(), [&](const PacketRange& range) {
      return range.topLevel != group->topLevel;
    });
    std::sort(group, end, byOffset);
    if (end != ranges.end() && end->topLevel < group->topLevel) cellsInOrder = false;
    group = end;
  }
  if (!cellsInOrder) {
    std::sort(ranges.begin(), ranges.end(), [](const PacketRange& a, const PacketRange& b) {
      return a.topLevel != b.topLevel ? a.topLevel < b.topLevel : a.offset < b.offset;
    });
  }
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

// The table's grown bounds must be those the settings ask for.
void checkScale(const CullingTable& table, const TraversalSettings& settings) {
  if (table.sizeScale() != settings.sizeScale) {
    throw UsageError("culling table made for size scale " + std::to_string(table.sizeScale()) +
                     ", walk asks for " + std::to_string(settings.sizeScale));
  }
}

}  // namespace

float distanceToCell(const OctreeCell& cell, const glm::vec3& eye, float sizeScale) {
  return distanceToCell(cellCulling(cell, sizeScale), eye);
}

bool cellBackfacing(const OctreeCell& cell, const glm::vec3& eye, float sizeScale) {
  return cellBackfacing(cellCulling(cell, sizeScale), eye);
}

std::vector<CellPrefix> topLevelCellsInTile(std::span<const OctreeCell> cells,
                                            const PacketLayers& layers, const Camera& camera,
                                            const TileRect& rect,
                                            const TraversalSettings& settings) {
  return topLevelCellsInTile(CullingTable(cells, settings.sizeScale), layers, camera, rect,
                             settings);
}

std::vector<CellPrefix> topLevelCellsInTile(const CullingTable& table, const PacketLayers& layers,
                                            const Camera& camera, const TileRect& rect,
                                            const TraversalSettings& settings) {
  checkScale(table, settings);
  std::vector<CellPrefix> found;
  const std::span<const OctreeCell> cells = table.cells();
  if (cells.empty()) return found;
  const FrustumPlanes planes = tilePlanes(camera, rect, settings.marginPixels);
  const glm::vec3 eye = cameraEye(camera);
  const auto size = static_cast<std::uint32_t>(cells.size());
  std::uint32_t index = 0;
  while (index != kNoIndex && index < size) {
    const OctreeCell& cell = cells[index];
    const CellCulling& culling = table[index];
    const bool culled = boxOutside(planes, culling.low, culling.high) ||
                        (settings.backfaceCull && cellBackfacing(culling, eye));
    if (culled) {
      index = cell.nextSibling;
    } else if (cell.topLevel != kNoIndex) {
      if (cell.pointsCount + cell.splatsCount > 0) {
        const float distance = distanceToCell(culling, eye);
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
  return traverseTile(CullingTable(cells, settings.sizeScale), camera, rect, settings);
}

TraversalResult traverseTile(const CullingTable& table, const Camera& camera, const TileRect& rect,
                             const TraversalSettings& settings) {
  checkScale(table, settings);
  TraversalResult result;
  const std::span<const OctreeCell> cells = table.cells();
  if (cells.empty()) return result;
  const FrustumPlanes planes = tilePlanes(camera, rect, settings.marginPixels);
  const glm::vec3 eye = cameraEye(camera);
  const double focal = focalLengthPixels(camera);
  const auto size = static_cast<std::uint32_t>(cells.size());

  std::uint32_t index = 0;
  while (index != kNoIndex && index < size) {
    const OctreeCell& cell = cells[index];
    const CellCulling& culling = table[index];
    ++result.cellsVisited;
    if (boxOutside(planes, culling.low, culling.high)) {
      ++result.cellsCulledFrustum;
      index = cell.nextSibling;
      continue;
    }
    if (settings.backfaceCull && cellBackfacing(culling, eye)) {
      ++result.cellsCulledBackface;
      index = cell.nextSibling;
      continue;
    }
    if (cell.topLevel == kNoIndex) {
      // Above the top-level depth there is no data: examine the children.
      index = cell.isLeaf() ? cell.nextSibling : index + 1;
      continue;
    }
    const float distance = distanceToCell(culling, eye);
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
