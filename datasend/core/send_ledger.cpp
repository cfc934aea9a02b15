#include "datasend/core/send_ledger.hpp"

#include <string>

#include "common/errors.hpp"
#include "common/splat.hpp"

namespace pointillist::datasend {

std::vector<std::span<const SplatRange>> dataPacketGroups(std::span<const SplatRange> ranges,
                                                          std::uint64_t targetBytes) {
  std::vector<std::span<const SplatRange>> groups;
  std::size_t begin = 0;
  std::uint64_t bytes = 0;
  for (std::size_t i = 0; i < ranges.size(); ++i) {
    const std::uint64_t rangeBytes = std::uint64_t{ranges[i].count} * sizeof(Splat);
    if (i > begin && bytes + rangeBytes > targetBytes) {
      groups.push_back(ranges.subspan(begin, i - begin));
      begin = i;
      bytes = 0;
    }
    bytes += rangeBytes;
  }
  if (begin < ranges.size()) groups.push_back(ranges.subspan(begin));
  return groups;
}

SendLedger::SendLedger(PeerRanks peers, std::vector<std::uint32_t> owners, std::uint32_t selfIndex)
    : peers_(std::move(peers)),
      owners_(std::move(owners)),
      selfIndex_(selfIndex),
      sentTo_(peers_.renders.size()) {}

bool SendLedger::owns(std::uint32_t cell) const {
  return cell < owners_.size() && owners_[cell] == selfIndex_;
}

std::vector<SplatRange> SendLedger::rangesToSend(const v1::SendOrder& order) {
  auto& sent = sentTo_.at(peers_.indexOf(v1::ROLE_RENDER, order.render_rank()));
  if (order.top_level_splats_size() != order.top_level_cells_size()) {
    throw ProtocolError("rank " + std::to_string(order.requester_rank()) + " ordered " +
                        std::to_string(order.top_level_cells_size()) + " cells with " +
                        std::to_string(order.top_level_splats_size()) + " prefixes");
  }
  std::vector<SplatRange> ranges;
  for (int i = 0; i < order.top_level_cells_size(); ++i) {
    const std::uint32_t cell = order.top_level_cells(i);
    if (!owns(cell)) {
      throw ProtocolError("rank " + std::to_string(order.requester_rank()) +
                          " ordered top-level cell " + std::to_string(cell) +
                          ", which this data-send process does not own");
    }
    // Never the same splats to the same render twice while it holds them or
    // they are on their way: only what lies beyond the prefix sent before.
    std::uint32_t& done = sent[cell];
    const std::uint32_t wanted = order.top_level_splats(i);
    if (wanted <= done) {
      ++duplicatesSkipped_;
      continue;
    }
    if (done > 0) ++extensionsSent_;
    ranges.push_back({cell, done, wanted - done});
    done = wanted;
  }
  return ranges;
}

void SendLedger::applyReport(int sourceRank, const v1::RenderReport& report) {
  auto& sent = sentTo_.at(peers_.indexOf(v1::ROLE_RENDER, sourceRank));
  for (std::uint32_t cell : report.evicted_cells()) sent.erase(cell);
}

}  // namespace pointillist::datasend
