#pragma once
// The first `splats` splats of a top-level cell's packet. Packets are layered
// coarse-first (common/dataset.hpp), so what a walk draws of a cell ends
// inside such a prefix (TraversalResult::needs), a statistical cut needs one
// whole, and a view is estimated to need one when ordering ahead. What
// travels and is held is counted in ranges (common/cell_ranges.hpp).
#include <cstdint>

namespace pointillist {

struct CellPrefix {
  std::uint32_t cell = 0;    // top-level cell index
  std::uint32_t splats = 0;  // prefix length in splats
  bool operator==(const CellPrefix&) const = default;
};

}  // namespace pointillist
