#pragma once
// Every decision of a data-send process (seed 003 §4.4), without MPI: which
// splats of the ordered top-level cells go out. Orders ask for ranges of
// packets (common/cell_ranges.hpp); a render process gets each splat of a
// cell once while it holds the cell: an order sends only what of its ranges
// did not go to that render before. The render's reports of evictions (and of data
// it dropped) make the whole cell sendable again.
// The MPI data-send process and the simulator both drive this class.
#include <cstdint>
#include <span>
#include <unordered_map>
#include <vector>

#include "common/cell_ranges.hpp"
#include "common/peer_ranks.hpp"
#include "pointillist.pb.h"

namespace pointillist::datasend {

// Ranges of one order travel together in data packets of about this many
// bytes: a top-level cell of a few KiB must not cost a message of its own
// (measured: a message per 8 KiB cell held data-send at 5 frames/s), while a
// render can already store the first parts of a large order.
inline constexpr std::uint64_t kDataPacketTargetBytes = 1ull << 20;

// Splits `ranges` (in order) into consecutive groups of at most `targetBytes`
// of splats each; a range larger than that is a group of its own.
std::vector<std::span<const CellRange>> dataPacketGroups(
    std::span<const CellRange> ranges, std::uint64_t targetBytes = kDataPacketTargetBytes);

class SendLedger {
 public:
  // `owners` gives the data-send index owning every top-level cell.
  SendLedger(PeerRanks peers, std::vector<std::uint32_t> owners, std::uint32_t selfIndex);

  // Of the ordered ranges, those not sent to that render before, in order.
  // Throws ProtocolError for a cell this process does not own, a render rank
  // that is not one, or malformed range fields.
  std::vector<CellRange> rangesToSend(const v1::SendOrder& order);
  // A render's report: evicted cells are sent again from their start.
  void applyReport(int sourceRank, const v1::RenderReport& report);

  std::uint32_t selfIndex() const { return selfIndex_; }
  bool owns(std::uint32_t cell) const;
  // Ordered ranges that were already sent whole.
  std::uint64_t duplicatesSkipped() const { return duplicatesSkipped_; }
  // Ranges sent of cells that render had been sent some of before.
  std::uint64_t extensionsSent() const { return extensionsSent_; }

 private:
  PeerRanks peers_;
  std::vector<std::uint32_t> owners_;
  std::uint32_t selfIndex_;
  // Per render: cell -> splats sent so far.
  std::vector<std::unordered_map<std::uint32_t, SpanSet>> sentTo_;
  std::uint64_t duplicatesSkipped_ = 0;
  std::uint64_t extensionsSent_ = 0;
};

}  // namespace pointillist::datasend
