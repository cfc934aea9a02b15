#pragma once
// What a render process needs of one top-level cell: the first `splats` splats
// of its packet. Packets are layered coarse-first (common/dataset.hpp), so a
// cell drawn coarsely needs, holds and receives only a prefix; traverse,
// data-send and render processes all count in prefixes.
#include <cstdint>

namespace pointillist {

struct CellPrefix {
  std::uint32_t cell = 0;    // top-level cell index
  std::uint32_t splats = 0;  // prefix length in splats
  bool operator==(const CellPrefix&) const = default;
};

}  // namespace pointillist
