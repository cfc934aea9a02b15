#include "datasend/core/send_ledger.hpp"

#include <string>

#include "common/errors.hpp"
#include "common/splat.hpp"

namespace pointillist::datasend {

std::vector<std::span<const CellRange>> dataPacketGroups(std::span<const CellRange> ranges,
                                                         std::uint64_t targetBytes) {
  std::vector<std::span<const CellRange>> groups;
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

std::vector<CellRange> SendLedger::rangesToSend(const v1::SendOrder& order) {
  auto& sent = sentTo_.at(peers_.indexOf(v1::ROLE_RENDER, order.render_rank()));
  const std::vector<CellRange> wanted =
      rangesFromFields(order.range_top_level(), order.range_first(), order.range_count(),
                       "send order " + std::to_string(order.order_id()) + " from rank " +
                           std::to_string(order.requester_rank()));
  std::vector<CellRange> ranges;
  for (const CellRange& range : wanted) {
    if (!owns(range.cell)) {
      throw ProtocolError("rank " + std::to_string(order.requester_rank()) +
                          " ordered top-level cell " + std::to_string(range.cell) +
                          ", which this data-send process does not own");
    }
    // Never the same splats to the same render twice while it holds them or
    // they are on their way: only what of the range did not go there before.
    SpanSet& done = sent[range.cell];
    const bool some = !done.empty();
    const auto end = static_cast<std::uint32_t>(range.end());
    const std::size_t before = ranges.size();
    done.forEachGap(range.first, end, [&](std::uint32_t begin, std::uint32_t stop) {
      ranges.push_back({range.cell, begin, stop - begin});
    });
    if (ranges.size() == before) {
      ++duplicatesSkipped_;
      continue;
    }
    if (some) extensionsSent_ += ranges.size() - before;
    done.add(range.first, end);
  }
  return ranges;
}

void SendLedger::applyReport(int sourceRank, const v1::RenderReport& report) {
  auto& sent = sentTo_.at(peers_.indexOf(v1::ROLE_RENDER, sourceRank));
  for (std::uint32_t cell : report.evicted_cells()) sent.erase(cell);
}

}  // namespace pointillist::datasend
