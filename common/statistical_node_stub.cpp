// TEMPORARY STUB -- drop on merge. The real encode/decode of
// common/statistical_node.hpp is the lead's common/statistical_node.cpp; this
// file only lets the stat-render branch link (the splat renderer calls
// decodeStatisticalPacket) until that lands. Every function throws.
#include <span>
#include <string>

#include "common/errors.hpp"
#include "common/statistical_node.hpp"

namespace pointillist {

StatisticalPacketView decodeStatisticalPacket(std::span<const std::byte>, const ClassTables&,
                                              const std::string& where) {
  throw InputError(where + ": decodeStatisticalPacket is a stub on this branch");
}

StatisticalPacketView decodeStatisticalPacket(std::span<const Splat>, const ClassTables&,
                                              const std::string& where) {
  throw InputError(where + ": decodeStatisticalPacket is a stub on this branch");
}

}  // namespace pointillist
