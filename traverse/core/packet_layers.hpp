#pragma once
// The layers of every top-level packet (dataset format 4, common/dataset.hpp):
// where each level's level-splats end, coarse first, and how large their
// splats are. Traverse processes ask for the ranges a tile draws, and
// estimate, layer by layer, the prefix a view will need for ordering ahead
// (prefixAt). A statistical packet is needed as a prefix (a cut needs every
// node above it).
#include <cstdint>
#include <span>
#include <vector>

#include "common/camera.hpp"
#include "common/octree_cell.hpp"
#include "common/statistical_cut.hpp"

namespace pointillist::traverse {

struct PacketLayer {
  std::uint32_t end = 0;  // prefix length in splats that holds this layer
  // Largest maxSplatRadius of the layer's cells; 0 for the points (the last
  // layer), which are drawn whatever their size.
  float radius = 0.0f;
};

class PacketLayers {
 public:
  // Throws InputError when a cell's data lies outside its packet. With
  // `statistical`, the statistical packets follow as ids topLevel.size() + t,
  // layered by depth of their hierarchy (a cut needs every node above it).
  PacketLayers(std::span<const OctreeCell> cells, std::span<const TopLevelCell> topLevel,
               const StatisticalTrees* statistical = nullptr);

  std::size_t cellCount() const { return totals_.size(); }
  std::uint32_t totalSplats(std::uint32_t cell) const { return totals_.at(cell); }
  // Coarse first; the last layer (the points) ends at totalSplats(cell).
  std::span<const PacketLayer> layers(std::uint32_t cell) const;
  // Statistical packets (ids from the point packets' count on) are needed
  // from their start; point packets as the ranges drawn.
  bool neededAsPrefix(std::uint32_t cell) const { return cell >= pointPackets_; }
  // The prefix a view probably needs from `cell` when its nearest point is
  // `distance` from the eye: through the first layer whose splats project to
  // at most `lodPixels` there (an estimate for ordering ahead: a tile's own
  // walk gives the exact need). With `instanced` (--mode instanced), full
  // detail ends after the cell's instanced sections, which stand for its
  // points, where it has any.
  std::uint32_t prefixAt(std::uint32_t cell, const Camera& camera, float distance, float lodPixels,
                         float sizeScale, bool instanced = false) const;

 private:
  std::vector<std::uint32_t> totals_;
  std::uint32_t pointPackets_ = 0;
  std::vector<std::uint32_t> sectionsBegin_;  // per cell: its levelSplatCount
  std::vector<std::uint32_t> sectionsEnd_;    // and where its points start
  std::vector<std::uint32_t> first_;          // per cell, index of its first layer; plus one entry
  std::vector<PacketLayer> layers_;
};

}  // namespace pointillist::traverse
