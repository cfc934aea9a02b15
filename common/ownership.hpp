#pragma once
// Which data-send process owns which top-level cell. Every role computes the
// same answer from the top-level table, so no message is needed to agree.
#include <cstdint>
#include <span>
#include <vector>

#include "common/octree_cell.hpp"

namespace pointillist {

// Splits the table (depth-first, so spatially coherent) into `owners`
// contiguous runs of about equal bytes. Returns the owner of every cell.
std::vector<std::uint32_t> assignOwners(std::span<const TopLevelCell> topLevel,
                                        std::uint32_t owners);

// The owner of every packet id below `packetCount` (common/dataset.hpp): a
// top-level cell's statistical packet (id topLevel.size() + t) goes with it.
std::vector<std::uint32_t> assignPacketOwners(std::span<const TopLevelCell> topLevel,
                                              std::uint32_t owners, std::uint32_t packetCount);

}  // namespace pointillist
