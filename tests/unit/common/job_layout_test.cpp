// Who is in a job: role counts (D,T,S,R) and the ranks of every role.
#include "common/job_layout.hpp"

#include <gtest/gtest.h>

#include "common/errors.hpp"
#include "common/peer_ranks.hpp"

namespace pointillist {
namespace {

TEST(PeerRanks, NumbersALayoutContiguouslyAndFindsEachRole) {
  const PeerRanks peers = PeerRanks::contiguous(JobLayout{1, 2, 1, 3});
  EXPECT_EQ(peers.display, 0);
  EXPECT_EQ(peers.traverses, (std::vector<int>{1, 2}));
  EXPECT_EQ(peers.datasends, (std::vector<int>{3}));
  EXPECT_EQ(peers.renders, (std::vector<int>{4, 5, 6}));
  EXPECT_EQ(peers.indexOf(v1::ROLE_RENDER, 6), 2u);
  EXPECT_EQ(peers.layout().toString(), "1,2,1,3");
  try {
    (void)peers.indexOf(v1::ROLE_RENDER, 2);
    FAIL() << "a traverse rank was taken for a render";
  } catch (const ProtocolError& error) {
    EXPECT_STREQ(error.what(), "rank 2 is not a render process");
  }
}

TEST(JobLayout, ParsesAndPrints) {
  const auto layout = JobLayout::parse("1,2,3,40");
  EXPECT_EQ(layout.traverse, 2u);
  EXPECT_EQ(layout.datasend, 3u);
  EXPECT_EQ(layout.render, 40u);
  EXPECT_EQ(layout.total(), 46u);
  EXPECT_EQ(layout.toString(), "1,2,3,40");
}

TEST(JobLayout, RefusesMalformedOrImpossibleLayouts) {
  for (const char* bad : {"", "1,2,1", "1,2,1,4,5", "a,2,1,4", "1,,1,4", "2,2,1,4", "1,0,1,4",
                          "1,2,1,0", "1,2,1,-4", "1,2,1,4x"}) {
    EXPECT_THROW((void)JobLayout::parse(bad), UsageError) << bad;
  }
  try {
    (void)JobLayout::parse("1,2,1");
  } catch (const UsageError& error) {
    EXPECT_NE(std::string(error.what()).find("'1,2,1'"), std::string::npos);
  }
}

}  // namespace
}  // namespace pointillist
