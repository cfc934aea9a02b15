// The data-send process's decision (seed 003 §4.4): never the same splats to
// the same render process twice while it holds them or they are on their way;
// packets are layered, so a longer prefix sends only what lies beyond.
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

// Orders prefixes {cell, splats}.
v1::SendOrder order(int render, std::vector<std::pair<std::uint32_t, std::uint32_t>> prefixes,
                    int requester = 1) {
  v1::SendOrder o;
  o.set_render_rank(render);
  o.set_requester_rank(requester);
  for (const auto& [cell, splats] : prefixes) {
    o.add_top_level_cells(cell);
    o.add_top_level_splats(splats);
  }
  return o;
}

using Ranges = std::vector<SplatRange>;

TEST(SendLedger, SendsEachSplatToARenderOnceUntilItIsEvicted) {
  SendLedger ledger(kPeers, kOwners, 1);
  EXPECT_EQ(ledger.rangesToSend(order(4, {{2, 100}, {3, 40}})), (Ranges{{2, 0, 100}, {3, 0, 40}}));
  // Ordered again (by the render itself, say): already there or on its way.
  EXPECT_TRUE(ledger.rangesToSend(order(4, {{3, 40}, {2, 60}}, 4)).empty());
  EXPECT_EQ(ledger.duplicatesSkipped(), 2u);
  // A longer prefix: only the splats beyond the one sent before.
  EXPECT_EQ(ledger.rangesToSend(order(4, {{2, 400}})), (Ranges{{2, 100, 300}}));
  EXPECT_EQ(ledger.extensionsSent(), 1u);
  // Another render is another matter.
  EXPECT_EQ(ledger.rangesToSend(order(5, {{3, 40}})), (Ranges{{3, 0, 40}}));
  // Evicted (or a dropped prefetch): it goes again from its start.
  v1::RenderReport report;
  report.add_evicted_cells(2);
  ledger.applyReport(4, report);
  EXPECT_EQ(ledger.rangesToSend(order(4, {{2, 100}, {3, 80}})), (Ranges{{2, 0, 100}, {3, 40, 40}}));
}

TEST(SendLedger, RefusesCellsItDoesNotOwnNamingTheRequester) {
  SendLedger ledger(kPeers, kOwners, 1);
  EXPECT_FALSE(ledger.owns(0));
  EXPECT_TRUE(ledger.owns(2));
  EXPECT_FALSE(ledger.owns(4));
  try {
    ledger.rangesToSend(order(4, {{0, 10}}, 1));
    FAIL() << "a cell of data-send 0 was accepted";
  } catch (const ProtocolError& error) {
    EXPECT_NE(std::string(error.what()).find("rank 1 ordered top-level cell 0"), std::string::npos)
        << error.what();
  }
  EXPECT_THROW(ledger.rangesToSend(order(3, {{2, 10}})), ProtocolError);  // not a render
  v1::SendOrder withoutPrefix = order(4, {{2, 10}});
  withoutPrefix.clear_top_level_splats();
  EXPECT_THROW(ledger.rangesToSend(withoutPrefix), ProtocolError);
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
    for (const SplatRange& range : group) {
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
