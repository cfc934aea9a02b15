#include "traverse/core/octree_traversal.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <optional>
#include <utility>

#include "common/errors.hpp"
#include "common/geometry.hpp"
#include "common/instanced_section.hpp"
#include "common/view_options.hpp"

namespace pointillist::traverse {
namespace {

// Ranges as the walk finds them, put in packet order one top-level cell at a
// time. A packet holds its level-splats by level from the highest down, each
// level's cells in depth-first order, then instanced sections, then the
// points in depth-first order (common/octree_cell.hpp); the walk meets cells
// depth-first, so ranges kept apart by kind and joined in that order come out
// sorted. Sorting the walk's order instead took a quarter of the walk.
class PacketOrderRanges {
 public:
  static constexpr std::size_t kSections = 256, kPoints = 257;
  static std::size_t levelSplats(std::uint8_t level) { return 255u - level; }

  explicit PacketOrderRanges(std::vector<PacketRange>& out) : out_(out) {}
  void add(const PacketRange& range, std::size_t kind) {
    if (range.topLevel != topLevel_) flush();
    topLevel_ = range.topLevel;
    kinds_[kind].push_back(range);
    low_ = std::min(low_, kind);
    high_ = std::max(high_, kind);
  }
  // Call once the walk is done.
  void flush() {
    for (std::size_t kind = low_; kind <= high_ && low_ <= high_; ++kind) {
      out_.insert(out_.end(), kinds_[kind].begin(), kinds_[kind].end());
      kinds_[kind].clear();
    }
    low_ = kinds_.size();
    high_ = 0;
  }

 private:
  std::vector<PacketRange>& out_;
  std::array<std::vector<PacketRange>, kPoints + 1> kinds_;
  std::uint32_t topLevel_ = kNoIndex;
  std::size_t low_ = kPoints + 1, high_ = 0;
};

// Sorts by (topLevel, offset) and merges adjacent ranges of the same top-level
// cell. The walk meets each top-level cell's subtree in one piece, in table
// order, so only the ranges within a cell need sorting, and PacketOrderRanges
// has already sorted them.
void normalizeRanges(std::vector<PacketRange>& ranges) {
  const auto byOffset = [](const PacketRange& a, const PacketRange& b) {
    return a.offset < b.offset;
  };
  bool cellsInOrder = true;
  for (auto group = ranges.begin(); group != ranges.end();) {
    const auto end = std::find_if(group, ranges.end(), [&](const PacketRange& range) {
      return range.topLevel != group->topLevel;
    });
    if (!std::is_sorted(group, end, byOffset)) std::sort(group, end, byOffset);
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
    if (!merged.empty() && merged.back().topLevel == range.topLevel && !range.section &&
        !merged.back().section && merged.back().offset + merged.back().count == range.offset) {
      merged.back().count += range.count;
    } else {
      merged.push_back(range);
    }
  }
  ranges.swap(merged);
}

// Level of detail as traverseTile decides it (the focal length taken once).
bool coarseEnough(float maxSplatRadius, float distance, double focal,
                  const TraversalSettings& settings) {
  return distance > 0.0f &&
         maxSplatRadius * settings.sizeScale * pixelsPerUnit(focal, distance) <= settings.lodPixels;
}

// The children's level-splats, when the walk would draw every child of the
// cell at `index` from them: the cell lies inside every plane of the tile and,
// with back-face culling, all its splats face the eye (so no child is culled,
// the children lying within it), and its children's largest splat is coarse
// enough at the cell's distance, which no child is nearer than. nullptr
// otherwise, or when the walk must test each cell (inheritCulling off, or
// instanced sections to look for).
const ChildrenSplats* childrenAllDrawnCoarse(const CullingTable& table, std::uint32_t index,
                                             bool insideAll, bool facingEye, float distance,
                                             double focal, const TraversalSettings& settings) {
  if ((table[index].flags & CellCulling::kChildrenInOneRange) == 0 || !insideAll ||
      !settings.inheritCulling || settings.instanced || (settings.backfaceCull && !facingEye))
    return nullptr;
  const ChildrenSplats& children = table.childrenSplats(index);
  return coarseEnough(children.maxSplatRadius, distance, focal, settings) ? &children : nullptr;
}

// Whether traverseTile, over the whole frame, would draw any point of the
// subtree at `root`: its walk with back-face culling and level of detail but
// no frustum (which differs between tiles).
bool subtreeDrawsPoints(const CullingTable& table, std::uint32_t root, const glm::vec3& eye,
                        double focal, const TraversalSettings& settings) {
  const std::span<const OctreeCell> cells = table.cells();
  const std::uint32_t end = cells[root].nextSibling == kNoIndex
                                ? static_cast<std::uint32_t>(cells.size())
                                : cells[root].nextSibling;
  for (std::uint32_t index = root; index < end;) {
    const OctreeCell& cell = cells[index];
    const CellCulling& culling = table[index];
    if (settings.backfaceCull && cellBackfacing(culling, eye)) {
      index = cell.nextSibling == kNoIndex ? end : cell.nextSibling;
      continue;
    }
    const bool coarse =
        coarseEnough(cell.maxSplatRadius, distanceToCell(culling, eye), focal, settings);
    if (cell.isLeaf() && !(coarse && cell.splatsCount > 0) && cell.pointsCount > 0) return true;
    if (cell.isLeaf() || (coarse && cell.splatsCount > 0))
      index = cell.nextSibling == kNoIndex ? end : cell.nextSibling;
    else
      ++index;
  }
  return false;
}

// The boxes of the walk's top-level cells, for needBoxes: the bounds of
// each one's drawn cells joined in world space as the walk meets them, and
// projected once per need (projecting every drawn cell took half the walk).
class BoxesByTopLevel {
 public:
  BoxesByTopLevel(const Camera& camera, const TraversalSettings& settings)
      : projector_(camera, settings.marginPixels) {}
  void add(std::uint32_t topLevel, const CellCulling& culling) {
    if (!bounds_.empty() && bounds_.back().topLevel == topLevel) {
      Bounds& b = bounds_.back();
      b.low = glm::min(b.low, culling.low);
      b.high = glm::max(b.high, culling.high);
    } else {
      bounds_.push_back({topLevel, culling.low, culling.high});
    }
  }
  // Parallel to `needs` (ascending cells).
  std::vector<ScreenBox> forNeeds(std::span<const CellPrefix> needs) {
    const auto byCell = [](const Bounds& a, const Bounds& b) { return a.topLevel < b.topLevel; };
    if (!std::is_sorted(bounds_.begin(), bounds_.end(), byCell))
      std::stable_sort(bounds_.begin(), bounds_.end(), byCell);
    std::vector<ScreenBox> out(needs.size());
    std::size_t at = 0;
    for (std::size_t i = 0; i < needs.size(); ++i) {
      while (at < bounds_.size() && bounds_[at].topLevel < needs[i].cell) ++at;
      for (; at < bounds_.size() && bounds_[at].topLevel == needs[i].cell; ++at)
        out[i].add(projector_.project(bounds_[at].low, bounds_[at].high));
    }
    return out;
  }

 private:
  struct Bounds {
    std::uint32_t topLevel;
    glm::vec3 low, high;
  };
  ScreenBoxProjector projector_;
  std::vector<Bounds> bounds_;
};

// The table's grown bounds must be those the settings ask for.
void checkScale(const CullingTable& table, const TraversalSettings& settings) {
  if (table.sizeScale() != settings.sizeScale) {
    throw UsageError("culling table made for size scale " + std::to_string(table.sizeScale()) +
                     ", walk asks for " + std::to_string(settings.sizeScale));
  }
}

}  // namespace

void ScreenBox::add(const ScreenBox& other) {
  if (other.empty()) return;
  if (empty()) {
    *this = other;
    return;
  }
  x0 = std::min(x0, other.x0);
  y0 = std::min(y0, other.y0);
  x1 = std::max(x1, other.x1);
  y1 = std::max(y1, other.y1);
}

TileRect clipScreenBox(const ScreenBox& box, const TileRect& rect) {
  if (box.empty()) return makeTileRect(rect.x(), rect.y(), 0, 0);
  const auto clip = [](float v, std::uint32_t low, std::uint32_t size) {
    const double high = static_cast<double>(low) + size;
    return static_cast<std::uint32_t>(
        std::clamp(static_cast<double>(v), static_cast<double>(low), high));
  };
  const std::uint32_t x0 = clip(std::floor(box.x0), rect.x(), rect.width());
  const std::uint32_t x1 = clip(std::ceil(box.x1), rect.x(), rect.width());
  const std::uint32_t y0 = clip(std::floor(box.y0), rect.y(), rect.height());
  const std::uint32_t y1 = clip(std::ceil(box.y1), rect.y(), rect.height());
  if (x1 <= x0 || y1 <= y0) return makeTileRect(rect.x(), rect.y(), 0, 0);
  return makeTileRect(x0, y0, x1 - x0, y1 - y0);
}

ScreenBoxProjector::ScreenBoxProjector(const Camera& camera, float marginPixels)
    : viewProjection_(viewProjectionMatrix(camera)),
      width_(static_cast<float>(camera.image_width())),
      height_(static_cast<float>(camera.image_height())),
      // A pixel more than the walk's margin: float rounding of the corners.
      margin_(marginPixels + 1.0f) {}

ScreenBox ScreenBoxProjector::project(const glm::vec3& low, const glm::vec3& high) const {
  constexpr float kEverywhere = 1e30f;
  ScreenBox box{kEverywhere, kEverywhere, -kEverywhere, -kEverywhere};
  for (int corner = 0; corner < 8; ++corner) {
    const glm::vec4 clip =
        viewProjection_ * glm::vec4((corner & 1) ? high.x : low.x, (corner & 2) ? high.y : low.y,
                                    (corner & 4) ? high.z : low.z, 1.0f);
    // At or behind the eye the projection wraps: the box is the whole frame.
    if (!(clip.w > 1e-6f)) return {-kEverywhere, -kEverywhere, kEverywhere, kEverywhere};
    const float x = (clip.x / clip.w + 1.0f) * 0.5f * width_;
    const float y = (clip.y / clip.w + 1.0f) * 0.5f * height_;
    box.x0 = std::min(box.x0, x);
    box.x1 = std::max(box.x1, x);
    box.y0 = std::min(box.y0, y);
    box.y1 = std::max(box.y1, y);
  }
  box.x0 -= margin_;
  box.y0 -= margin_;
  box.x1 += margin_;
  box.y1 += margin_;
  return box;
}

InstancedCells::InstancedCells(std::span<const OctreeCell> cells,
                               std::span<const TopLevelCell> topLevel,
                               std::span<const std::byte> sectionsFile,
                               const std::string& datasetName) {
  const std::string where = datasetName + "/" + kInstancedSectionsName + ": ";
  if (sectionsFile.size() != cells.size() * sizeof(InstancedCellSection))
    throw InputError(where + std::to_string(sectionsFile.size()) + " bytes for " +
                     std::to_string(cells.size()) + " cells");
  cells_.resize(cells.size());
  std::memcpy(cells_.data(), sectionsFile.data(), sectionsFile.size());
  for (std::size_t i = 0; i < cells.size(); ++i) {
    const Cell& c = cells_[i];
    if (c.records == 0) continue;
    const std::uint32_t k = cells[i].topLevel;
    if (k >= topLevel.size() || !(c.offset >= topLevel[k].levelSplatCount &&
                                  std::uint64_t{c.offset} + c.records <= pointsStart(topLevel[k])))
      throw InputError(where + "cell " + std::to_string(i) +
                       "'s section lies outside its packet's instanced sections");
  }
}

std::shared_ptr<const InstancedCells> InstancedCells::load(const Dataset& dataset) {
  const std::string name = dataset.path().string();
  if (dataset.manifest().file(kInstancedSectionsKey) == nullptr)
    throw UsageError("--mode instanced: dataset " + name +
                     " has no instanced sections; build it with pointillist-preprocess "
                     "--instanced");
  const std::vector<std::byte> bytes = dataset.readFile(kInstancedSectionsKey);
  return std::make_shared<const InstancedCells>(dataset.cells(), dataset.topLevelCells(), bytes,
                                                name);
}

TraversalSettings traversalSettings(const ViewOptions& view) {
  TraversalSettings settings;
  settings.lodPixels = view.lodPixels;
  settings.sizeScale = view.sizeScale;
  settings.backfaceCull = !view.noBackfaceCull;
  return settings;
}

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
  // A statistical frame orders nothing ahead yet: its cut is cheap to send.
  if (settings.statistical) return found;
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
        found.push_back(
            {cell.topLevel, layers.prefixAt(cell.topLevel, camera, distance, settings.lodPixels,
                                            settings.sizeScale, settings.instanced != nullptr)});
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

StatisticalCutMemo::StatisticalCutMemo(std::shared_ptr<const StatisticalTrees> trees)
    : trees_(std::move(trees)) {}

std::shared_ptr<const StatisticalCut> StatisticalCutMemo::cutFor(
    const Camera& camera, const StatisticalCutSettings& settings) {
  const std::string key = camera.SerializeAsString();
  const auto same = [&](const Entry& e) {
    return e.camera == key && e.settings.lodPixels == settings.lodPixels &&
           e.settings.backfaceCull == settings.backfaceCull &&
           e.settings.marginPixels == settings.marginPixels;
  };
  {
    std::lock_guard lock(mutex_);
    for (const Entry& e : recent_)
      if (same(e)) return e.cut;
  }
  auto cut = std::make_shared<const StatisticalCut>(cutStatistical(*trees_, camera, settings));
  std::lock_guard lock(mutex_);
  // A few frames: tiles of consecutive frames may interleave.
  if (recent_.size() >= 4) recent_.erase(recent_.begin());
  recent_.push_back({key, settings, cut});
  return cut;
}

namespace {

TraversalResult traverseStatistical(const Camera& camera, const TileRect& rect,
                                    const TraversalSettings& settings) {
  const StatisticalCutSettings cutSettings{settings.lodPixels, settings.backfaceCull,
                                           settings.marginPixels};
  const auto cut = settings.statistical->cutFor(camera, cutSettings);
  const StatisticalTile tile =
      statisticalTile(settings.statistical->trees(), *cut, camera, rect, cutSettings);
  TraversalResult result;
  result.ranges.reserve(tile.ranges.size());
  for (const StatisticalTile::Range& r : tile.ranges)
    result.ranges.push_back({r.packet, r.first, r.count, false});
  result.needs = tile.needs;
  result.splats = tile.points;
  result.sections = tile.nodes;
  result.cellsVisited = cut->visited;
  result.cellsCulledFrustum = cut->culledFrustum;
  result.cellsCulledBackface = cut->culledBackface;
  return result;
}

}  // namespace

TraversalResult traverseTile(const CullingTable& table, const Camera& camera, const TileRect& rect,
                             const TraversalSettings& settings) {
  checkScale(table, settings);
  if (settings.statistical) return traverseStatistical(camera, rect, settings);
  TraversalResult result;
  const std::span<const OctreeCell> cells = table.cells();
  if (cells.empty()) return result;
  const FrustumPlanes planes = tilePlanes(camera, rect, settings.marginPixels);
  const glm::vec3 eye = cameraEye(camera);
  const double focal = focalLengthPixels(camera);
  const auto size = static_cast<std::uint32_t>(cells.size());
  const int allPlanes = (1 << planes.size()) - 1;

  // What the cells being descended into are known to satisfy, innermost last.
  struct Known {
    std::uint32_t end;  // first index after the subtree
    int insidePlanes;   // boxInsidePlanes bits of the cell's bounds
    bool facingEye;     // cellFacing was Toward
  };
  std::vector<Known> known;
  PacketOrderRanges found(result.ranges);
  std::optional<BoxesByTopLevel> boxes;
  if (settings.screenBoxes) boxes.emplace(camera, settings);
  std::uint32_t index = 0;
  while (index != kNoIndex && index < size) {
    // Only this record is read until the cell is drawn (culling_table.hpp).
    // Where the walk goes next, the first child or the next sibling, is
    // fetched meanwhile, the cell too (its ranges are read if it is drawn):
    // the sibling is a jump no hardware prefetcher foresees.
    const CellCulling& culling = table[index];
    if (culling.nextSibling < size) {
      __builtin_prefetch(&table[culling.nextSibling]);
      __builtin_prefetch(&cells[culling.nextSibling]);
    }
    if (index + 1 < size) __builtin_prefetch(&cells[index + 1]);
    ++result.cellsVisited;
    while (!known.empty() && index >= known.back().end) known.pop_back();
    const bool inherit = settings.inheritCulling && !known.empty();
    const int inside = boxInsidePlanes(planes, culling.low, culling.high,
                                       inherit && (culling.flags & CellCulling::kWithinParent) != 0
                                           ? known.back().insidePlanes
                                           : 0);
    if (inside < 0) {
      ++result.cellsCulledFrustum;
      index = culling.nextSibling;
      continue;
    }
    bool facingEye = inherit && known.back().facingEye;
    if (settings.backfaceCull && !facingEye) {
      const Facing facing = cellFacing(culling, eye);
      if (facing == Facing::Away) {
        ++result.cellsCulledBackface;
        index = culling.nextSibling;
        continue;
      }
      facingEye = facing == Facing::Toward;
    }
    const auto descend = [&] {
      known.push_back(
          {culling.nextSibling == kNoIndex ? size : culling.nextSibling, inside, facingEye});
      ++index;  // the first child follows its parent in depth-first order
    };
    if (culling.topLevel == kNoIndex) {
      // Above the top-level depth there is no data: examine the children.
      if (culling.isLeaf()) {
        index = culling.nextSibling;
      } else {
        descend();
      }
      continue;
    }
    const float distance = distanceToCell(culling, eye);
    if (settings.instanced) {
      const InstancedCells::Cell& section = (*settings.instanced)[index];
      if (section.records > 0 && subtreeDrawsPoints(table, index, eye, focal, settings)) {
        found.add({culling.topLevel, section.offset, section.records, true},
                  PacketOrderRanges::kSections);
        if (boxes) boxes->add(culling.topLevel, culling);
        result.splats +=
            cells[index].pointsCount;  // what the section generates, with its remainder
        ++result.sections;
        index = culling.nextSibling;
        continue;
      }
    }
    const bool coarse = coarseEnough(culling.maxSplatRadius, distance, focal, settings);
    if (culling.isLeaf() && !(coarse && culling.hasSplats())) {
      if (culling.hasPoints()) {
        const OctreeCell& cell = cells[index];
        found.add({culling.topLevel, cell.pointsOffset, cell.pointsCount},
                  PacketOrderRanges::kPoints);
        if (boxes) boxes->add(culling.topLevel, culling);
      }
      index = culling.nextSibling;
    } else if (coarse && culling.hasSplats()) {
      const OctreeCell& cell = cells[index];
      found.add({culling.topLevel, cell.splatsOffset, cell.splatsCount},
                PacketOrderRanges::levelSplats(culling.level()));
      if (boxes) boxes->add(culling.topLevel, culling);
      index = culling.nextSibling;
    } else if (const ChildrenSplats* children = childrenAllDrawnCoarse(
                   table, index, inside == allPlanes, facingEye, distance, focal, settings)) {
      // Every child would be visited only to be drawn from its level-splats.
      found.add({culling.topLevel, children->offset, children->count},
                PacketOrderRanges::levelSplats(children->level));
      if (boxes) boxes->add(culling.topLevel, culling);
      index = culling.nextSibling;
    } else {
      descend();
    }
  }

  found.flush();
  normalizeRanges(result.ranges);
  for (const PacketRange& range : result.ranges) {
    if (!range.section) result.splats += range.count;
    if (result.needs.empty() || result.needs.back().cell != range.topLevel) {
      result.needs.push_back({range.topLevel, 0});
    }
    result.needs.back().splats = std::max(result.needs.back().splats, range.offset + range.count);
  }
  if (boxes) result.needBoxes = boxes->forNeeds(result.needs);
  return result;
}

}  // namespace pointillist::traverse
