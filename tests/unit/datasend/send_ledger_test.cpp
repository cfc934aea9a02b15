// The data-send process's decision (seed 003 §4.4): never the same splats to
// the same render process twice while it holds them or they are on their way;
// orders name ranges of packets, and of an order only what went there before
// is left out.
#include "datasend/core/send_ledger.hpp"

#include <gtest/gtest.h>

#include "common/errors.hpp"
#include "common/splat.hpp"

namespace pointillist::datasend {
namespace {

// Layout 1,1,2,2: display 0, traverse 1, data-sends 2-3, renders 4-5.
const PeerRanks kPeers = PeerRanks::contiguous(JobLayout{1, 1, 2, 2});
// This is data-send index 1 (rank 3): it owns cells 2 and 3.
const std::vector<std::uint32_t> kOwners{0, 0, 1, 1};

using Ranges = std::vector<CellRange>;

v1::SendOrder order(int render, const Ranges& ranges, int requester = 1) {
  v1::SendOrder o;
  o.set_render_rank(render);
  o.set_requester_rank(requester);
  addRangeFields(ranges, *o.mutable_range_top_level(), *o.mutable_range_first(),
                 *o.mutable_range_count());
  return o;
}

TEST(SendLedger, SendsEachSplatToARenderOnceUntilItIsEvicted) {
  SendLedger ledger(kPeers, kOwners, 1);
  EXPECT_EQ(ledger.rangesToSend(order(4, {{2, 0, 100}, {3, 0, 40}})),
            (Ranges{{2, 0, 100}, {3, 0, 40}}));
  // Ordered again (by the render itself, say): already there or on its way.
  EXPECT_TRUE(ledger.rangesToSend(order(4, {{3, 0, 40}, {2, 10, 60}}, 4)).empty());
  EXPECT_EQ(ledger.duplicatesSkipped(), 2u);
  // Ranges reaching beyond and around what went before: only what did not.
  EXPECT_EQ(ledger.rangesToSend(order(4, {{2, 50, 350}})), (Ranges{{2, 100, 300}}));
  EXPECT_EQ(ledger.rangesToSend(order(4, {{3, 1000, 50}, {3, 20, 2000}})),
            (Ranges{{3, 1000, 50}, {3, 40, 960}, {3, 1050, 970}}));
  EXPECT_EQ(ledger.extensionsSent(), 4u);
  // Another render is another matter.
  EXPECT_EQ(ledger.rangesToSend(order(5, {{3, 0, 40}})), (Ranges{{3, 0, 40}}));
  // Evicted (or a dropped prefetch): the whole cell may go again.
  v1::RenderReport report;
  report.add_evicted_cells(2);
  ledger.applyReport(4, report);
  EXPECT_EQ(ledger.rangesToSend(order(4, {{2, 0, 100}, {3, 0, 2080}})),
            (Ranges{{2, 0, 100}, {3, 2020, 60}}));
}

TEST(SendLedger, RefusesCellsItDoesNotOwnNamingTheRequester) {
  SendLedger ledger(kPeers, kOwners, 1);
  EXPECT_FALSE(ledger.owns(0));
  EXPECT_TRUE(ledger.owns(2));
  EXPECT_FALSE(ledger.owns(4));
  try {
    ledger.rangesToSend(order(4, {{0, 0, 10}}, 1));
    FAIL() << "a cell of data-send 0 was accepted";
  } catch (const ProtocolError& error) {
    EXPECT_NE(std::string(error.what()).find("rank 1 ordered top-level cell 0"), std::string::npos)
        << error.what();
  }
  EXPECT_THROW(ledger.rangesToSend(order(3, {{2, 0, 10}})), ProtocolError);  // not a render
  v1::SendOrder withoutCounts = order(4, {{2, 0, 10}});
  withoutCounts.clear_range_count();
  EXPECT_THROW(ledger.rangesToSend(withoutCounts), ProtocolError);
  EXPECT_THROW(ledger.rangesToSend(order(4, {{2, 5, 0}})), ProtocolError);  // empty
  EXPECT_THROW(ledger.rangesToSend(order(4, {{2, 0xFFFFFFF0u, 100}})), ProtocolError);
  v1::RenderReport report;
  EXPECT_THROW(ledger.applyReport(1, report), ProtocolError);
}

// An order's ranges go in few data packets: consecutive groups, in order,
// every range once, each group under the target unless one range alone is
// larger.
TEST(SendLedger, RangesGoInDataPacketsOfAboutTheTargetSize) {
  const std::uint64_t target = 100 * sizeof(Splat);
  const Ranges ranges{{1, 0, 30}, {2, 0, 30}, {3, 0, 40}, {4, 10, 250}, {5, 0, 60}, {6, 0, 50}};
  const auto groups = dataPacketGroups(ranges, target);
  ASSERT_EQ(groups.size(), 4u);
  EXPECT_EQ(groups[0].size(), 3u);  // 30 + 30 + 40 splats: exactly the target
  EXPECT_EQ(groups[1].size(), 1u);  // 250 splats, alone
  EXPECT_EQ(groups[2].size(), 1u);  // 60 + 50 would pass the target
  EXPECT_EQ(groups[3].size(), 1u);
  Ranges joined;
  for (const auto group : groups) {
    std::uint64_t bytes = 0;
    for (const CellRange& range : group) {
      joined.push_back(range);
      bytes += std::uint64_t{range.count} * sizeof(Splat);
    }
    EXPECT_TRUE(bytes <= target || group.size() == 1);
  }
  EXPECT_EQ(joined, ranges);
  EXPECT_TRUE(dataPacketGroups({}, target).empty());
  EXPECT_EQ(dataPacketGroups(ranges).size(), 1u);  // the default target holds them all
}

}  // namespace
}  // namespace pointillist::datasend
