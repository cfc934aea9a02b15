#pragma once
// Screen regions bound to render processes (the `regions` scheduler): the box
// of interest is cut as a k-d tree with one leaf per render process, each cut
// placed so both sides hold work in proportion to their leaves, as measured on
// the last completed frame. The tree's shape and the axis of each cut are kept
// from frame to frame, so a leaf's region moves only as far as the work and
// the view move it, and its render process keeps most of the data it holds
// (Equalizer's 2D load equalizer, with splat counts instead of times).
#include <cstdint>
#include <vector>

#include "common/camera.hpp"
#include "display/core/work_density.hpp"

namespace pointillist::display {

class RegionTiling {
 public:
  // One rectangle per leaf, in leaf order, covering `area` exactly once. A
  // leaf gets an empty rectangle only when `area` has fewer pixels than
  // leaves. Sides stay at least `minSide` where the area allows it.
  std::vector<TileRect> split(const TileRect& area, std::uint32_t leaves,
                              const WorkDensity& density, std::uint32_t minSide);

 private:
  void splitNode(const TileRect& rect, std::uint32_t first, std::uint32_t count, std::uint32_t node,
                 const WorkDensity& density, std::uint32_t minSide, std::vector<TileRect>& out);

  std::uint32_t leaves_ = 0;
  // Per node, in preorder (fixed by the leaf count): 0 none yet, 1 cut
  // across x, 2 across y.
  std::vector<std::uint8_t> axis_;
};

}  // namespace pointillist::display
