#include "datasend/core/send_ledger.hpp"

#include <string>

#include "common/errors.hpp"

namespace pointillist::datasend {

SendLedger::SendLedger(PeerRanks peers, std::vector<std::uint32_t> owners, std::uint32_t selfIndex)
    : peers_(std::move(peers)),
      owners_(std::move(owners)),
      selfIndex_(selfIndex),
      sentTo_(peers_.renders.size()) {}

bool SendLedger::owns(std::uint32_t cell) const {
  return cell < owners_.size() && owners_[cell] == selfIndex_;
}

std::vector<std::uint32_t> SendLedger::cellsToSend(const v1::SendOrder& order) {
  auto& sent = sentTo_.at(peers_.indexOf(v1::ROLE_RENDER, order.render_rank()));
  std::vector<std::uint32_t> cells;
  for (std::uint32_t cell : order.top_level_cells()) {
    if (!owns(cell)) {
      throw ProtocolError("rank " + std::to_string(order.requester_rank()) +
                          " ordered top-level cell " + std::to_string(cell) +
                          ", which this data-send process does not own");
    }
    // Never the same cell to the same render twice while it is there or on its way.
    if (!sent.insert(cell).second) {
      ++duplicatesSkipped_;
      continue;
    }
    cells.push_back(cell);
  }
  return cells;
}

void SendLedger::applyReport(int sourceRank, const v1::RenderReport& report) {
  auto& sent = sentTo_.at(peers_.indexOf(v1::ROLE_RENDER, sourceRank));
  for (std::uint32_t cell : report.evicted_cells()) sent.erase(cell);
}

}  // namespace pointillist::datasend
