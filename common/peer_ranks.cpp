#include "common/peer_ranks.hpp"

#include <algorithm>
#include <string>

#include "common/errors.hpp"

namespace pointillist {

PeerRanks PeerRanks::contiguous(const JobLayout& layout) {
  PeerRanks peers;
  int next = 1;
  const auto take = [&next](std::uint32_t count) {
    std::vector<int> ranks(count);
    for (int& rank : ranks) rank = next++;
    return ranks;
  };
  peers.traverses = take(layout.traverse);
  peers.datasends = take(layout.datasend);
  peers.renders = take(layout.render);
  return peers;
}

const std::vector<int>& PeerRanks::of(v1::Role role) const {
  switch (role) {
    case v1::ROLE_TRAVERSE:
      return traverses;
    case v1::ROLE_DATASEND:
      return datasends;
    case v1::ROLE_RENDER:
      return renders;
    default:
      throw ProtocolError("peer ranks are kept for the worker roles only");
  }
}

std::size_t PeerRanks::indexOf(v1::Role role, int rank) const {
  const std::vector<int>& ranks = of(role);
  const auto found = std::find(ranks.begin(), ranks.end(), rank);
  if (found == ranks.end()) {
    const char* name = role == v1::ROLE_TRAVERSE   ? "traverse"
                       : role == v1::ROLE_DATASEND ? "data-send"
                                                   : "render";
    throw ProtocolError("rank " + std::to_string(rank) + " is not a " + name + " process");
  }
  return static_cast<std::size_t>(found - ranks.begin());
}

JobLayout PeerRanks::layout() const {
  return JobLayout{1, static_cast<std::uint32_t>(traverses.size()),
                   static_cast<std::uint32_t>(datasends.size()),
                   static_cast<std::uint32_t>(renders.size())};
}

}  // namespace pointillist
