#pragma once
// Every decision of a data-send process (seed 003 §4.4), without MPI: which
// ordered top-level cells go out. A cell goes to a render process only when
// that process neither holds it nor has it on the way; the render's reports
// of evictions (and of prefetched data it dropped) make it sendable again.
// The MPI data-send process and the simulator both drive this class.
#include <cstdint>
#include <unordered_set>
#include <vector>

#include "common/peer_ranks.hpp"
#include "pointillist.pb.h"

namespace pointillist::datasend {

class SendLedger {
 public:
  // `owners` gives the data-send index owning every top-level cell.
  SendLedger(PeerRanks peers, std::vector<std::uint32_t> owners, std::uint32_t selfIndex);

  // Of the ordered cells, those to send now, in order. Throws ProtocolError
  // for a cell this process does not own or a render rank that is not one.
  std::vector<std::uint32_t> cellsToSend(const v1::SendOrder& order);
  // A render's report: evicted cells may be sent to it again.
  void applyReport(int sourceRank, const v1::RenderReport& report);

  std::uint32_t selfIndex() const { return selfIndex_; }
  bool owns(std::uint32_t cell) const;
  std::uint64_t duplicatesSkipped() const { return duplicatesSkipped_; }

 private:
  PeerRanks peers_;
  std::vector<std::uint32_t> owners_;
  std::uint32_t selfIndex_;
  std::vector<std::unordered_set<std::uint32_t>> sentTo_;  // per render
  std::uint64_t duplicatesSkipped_ = 0;
};

}  // namespace pointillist::datasend
