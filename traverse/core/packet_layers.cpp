#include "traverse/core/packet_layers.hpp"

#include <algorithm>
#include <map>
#include <string>

#include "common/errors.hpp"

namespace pointillist::traverse {

PacketLayers::PacketLayers(std::span<const OctreeCell> cells,
                           std::span<const TopLevelCell> topLevel,
                           const StatisticalTrees* statistical) {
  totals_.reserve(topLevel.size());
  pointPackets_ = static_cast<std::uint32_t>(topLevel.size());
  for (const TopLevelCell& t : topLevel) {
    totals_.push_back(static_cast<std::uint32_t>(packetRecords(t)));
    sectionsBegin_.push_back(t.levelSplatCount);
    sectionsEnd_.push_back(static_cast<std::uint32_t>(pointsStart(t)));
  }
  // level -> (end, radius) per top-level cell, filled in one pass over the cells.
  std::vector<std::map<std::uint8_t, PacketLayer, std::greater<>>> perCell(topLevel.size());
  for (const OctreeCell& cell : cells) {
    if (cell.topLevel == kNoIndex || cell.splatsCount == 0) continue;
    if (cell.topLevel >= topLevel.size() || std::uint64_t{cell.splatsOffset} + cell.splatsCount >
                                                topLevel[cell.topLevel].levelSplatCount) {
      throw InputError("octree cell of top-level cell " + std::to_string(cell.topLevel) +
                       " has level-splats outside its packet's level-splats");
    }
    PacketLayer& layer = perCell[cell.topLevel][cell.level];
    layer.end = std::max(layer.end, cell.splatsOffset + cell.splatsCount);
    layer.radius = std::max(layer.radius, cell.maxSplatRadius);
  }
  first_.reserve(topLevel.size() + 1);
  for (std::size_t k = 0; k < topLevel.size(); ++k) {
    first_.push_back(static_cast<std::uint32_t>(layers_.size()));
    for (const auto& [level, layer] : perCell[k]) layers_.push_back(layer);
    layers_.push_back({totals_[k], 0.0f});  // the points: full detail
  }
  if (statistical != nullptr) {
    if (statistical->firstPacketId() != topLevel.size() ||
        statistical->cellCount() != topLevel.size())
      throw InputError("the statistical hierarchies do not match the top-level table");
    for (std::uint32_t t = 0; t < statistical->cellCount(); ++t) {
      const auto ends = statistical->levelEnds(t);
      first_.push_back(static_cast<std::uint32_t>(layers_.size()));
      for (const std::uint32_t end : ends) layers_.push_back({end, 0.0f});
      totals_.push_back(ends.empty() ? 0 : ends.back());
      sectionsBegin_.push_back(0);
      sectionsEnd_.push_back(0);
    }
  }
  first_.push_back(static_cast<std::uint32_t>(layers_.size()));
}

std::span<const PacketLayer> PacketLayers::layers(std::uint32_t cell) const {
  const std::uint32_t begin = first_.at(cell);
  return std::span<const PacketLayer>(layers_).subspan(begin, first_.at(cell + 1) - begin);
}

std::uint32_t PacketLayers::prefixAt(std::uint32_t cell, const Camera& camera, float distance,
                                     float lodPixels, float sizeScale, bool instanced) const {
  std::uint32_t prefix = totalSplats(cell);
  if (distance > 0.0f) {
    for (const PacketLayer& layer : layers(cell)) {
      if (projectedRadiusPixels(camera, layer.radius * sizeScale, distance) <= lodPixels) {
        prefix = layer.end;
        break;
      }
    }
  }
  // Full detail of an instanced frame: the sections, not the points after them.
  const bool sections = sectionsEnd_.at(cell) > sectionsBegin_[cell];
  return instanced && sections && prefix > sectionsEnd_[cell] ? sectionsEnd_[cell] : prefix;
}

}  // namespace pointillist::traverse
