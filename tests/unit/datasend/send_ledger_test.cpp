// The data-send process's decision (seed 003 §4.4): never the same cell to the
// same render process twice while it is there or on its way.
#include "datasend/core/send_ledger.hpp"

#include <gtest/gtest.h>

#include "common/errors.hpp"

namespace pointillist::datasend {
namespace {

// Layout 1,1,2,2: display 0, traverse 1, data-sends 2-3, renders 4-5.
const PeerRanks kPeers = PeerRanks::contiguous(JobLayout{1, 1, 2, 2});
// This is data-send index 1 (rank 3): it owns cells 2 and 3.
const std::vector<std::uint32_t> kOwners{0, 0, 1, 1};

v1::SendOrder order(int render, std::vector<std::uint32_t> cells, int requester = 1) {
  v1::SendOrder o;
  o.set_render_rank(render);
  o.set_requester_rank(requester);
  for (std::uint32_t cell : cells) o.add_top_level_cells(cell);
  return o;
}

TEST(SendLedger, SendsACellToARenderOnceUntilItIsEvicted) {
  SendLedger ledger(kPeers, kOwners, 1);
  EXPECT_EQ(ledger.cellsToSend(order(4, {2, 3})), (std::vector<std::uint32_t>{2, 3}));
  // Ordered again (by the render itself, say): already there or on its way.
  EXPECT_TRUE(ledger.cellsToSend(order(4, {3, 2}, 4)).empty());
  EXPECT_EQ(ledger.duplicatesSkipped(), 2u);
  // Another render is another matter.
  EXPECT_EQ(ledger.cellsToSend(order(5, {3})), (std::vector<std::uint32_t>{3}));
  // Evicted (or a dropped prefetch): it may go again.
  v1::RenderReport report;
  report.add_evicted_cells(3);
  ledger.applyReport(4, report);
  EXPECT_EQ(ledger.cellsToSend(order(4, {2, 3})), (std::vector<std::uint32_t>{3}));
}

TEST(SendLedger, RefusesCellsItDoesNotOwnNamingTheRequester) {
  SendLedger ledger(kPeers, kOwners, 1);
  EXPECT_FALSE(ledger.owns(0));
  EXPECT_TRUE(ledger.owns(2));
  EXPECT_FALSE(ledger.owns(4));
  try {
    ledger.cellsToSend(order(4, {0}, 1));
    FAIL() << "a cell of data-send 0 was accepted";
  } catch (const ProtocolError& error) {
    EXPECT_NE(std::string(error.what()).find("rank 1 ordered top-level cell 0"), std::string::npos)
        << error.what();
  }
  EXPECT_THROW(ledger.cellsToSend(order(3, {2})), ProtocolError);  // not a render
  v1::RenderReport report;
  EXPECT_THROW(ledger.applyReport(1, report), ProtocolError);
}

}  // namespace
}  // namespace pointillist::datasend
