#include "common/ownership.hpp"

#include "common/errors.hpp"

namespace pointillist {

std::vector<std::uint32_t> assignOwners(std::span<const TopLevelCell> topLevel,
                                        std::uint32_t owners) {
  if (owners == 0) throw UsageError("at least one data-send process is needed");
  std::uint64_t total = 0;
  for (const TopLevelCell& cell : topLevel) total += cell.byteSize;
  std::vector<std::uint32_t> owner(topLevel.size(), 0);
  std::uint64_t before = 0;
  for (std::size_t i = 0; i < topLevel.size(); ++i) {
    // The owner whose share contains this cell's middle byte.
    const std::uint64_t middle = before + topLevel[i].byteSize / 2;
    const std::uint64_t share = total == 0 ? 0 : (middle * owners) / total;  // in [0, owners)
    owner[i] = static_cast<std::uint32_t>(std::min<std::uint64_t>(share, owners - 1));
    before += topLevel[i].byteSize;
  }
  return owner;
}

std::vector<std::uint32_t> assignPacketOwners(std::span<const TopLevelCell> topLevel,
                                              std::uint32_t owners, std::uint32_t packetCount) {
  std::vector<std::uint32_t> out = assignOwners(topLevel, owners);
  for (std::size_t id = out.size(); id < packetCount; ++id)
    out.push_back(out[id % topLevel.size()]);
  return out;
}

}  // namespace pointillist
