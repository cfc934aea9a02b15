// How many processes share a machine's cores (common/core_share.hpp): what the
// traverse weighs a render process's queue by.
#include "common/core_share.hpp"

#include <gtest/gtest.h>

namespace pointillist {
namespace {

ProcessPlacement process(int rank, v1::Role role, std::string host,
                         std::vector<std::uint32_t> cpus) {
  return {rank, role, std::move(host), std::move(cpus)};
}

TEST(CoreShare, ProcessesOfOneMachineShareTheUnionOfTheirProcessors) {
  // The development job 1,2,1,4 on two cores, unbound: 2 / 8 each.
  std::vector<ProcessPlacement> job{
      process(0, v1::ROLE_DISPLAY, "dev", {0, 1}), process(1, v1::ROLE_TRAVERSE, "dev", {0, 1}),
      process(2, v1::ROLE_TRAVERSE, "dev", {0, 1}), process(3, v1::ROLE_DATASEND, "dev", {0, 1})};
  for (int rank = 7; rank >= 4; --rank)
    job.push_back(process(rank, v1::ROLE_RENDER, "dev", {0, 1}));
  EXPECT_EQ(renderCoreShares(job), (std::vector<float>{0.25f, 0.25f, 0.25f, 0.25f}));
}

TEST(CoreShare, ProcessesBoundToCoresOfTheirOwnHaveAWholeOne) {
  // A cluster: node a holds the display and a traverse, node b two renders
  // bound to cores 0 and 1, node c one render on a 4-core node and a
  // data-send, node d a render that named no processor.
  const std::vector<ProcessPlacement> job{process(0, v1::ROLE_DISPLAY, "a", {0}),
                                          process(1, v1::ROLE_TRAVERSE, "a", {1}),
                                          process(2, v1::ROLE_RENDER, "b", {0}),
                                          process(3, v1::ROLE_RENDER, "b", {1}),
                                          process(4, v1::ROLE_RENDER, "c", {0, 1, 2, 3}),
                                          process(5, v1::ROLE_DATASEND, "c", {0, 1, 2, 3}),
                                          process(6, v1::ROLE_RENDER, "d", {})};
  EXPECT_EQ(renderCoreShares(job), (std::vector<float>{1.0f, 1.0f, 1.0f, 1.0f}));
}

TEST(CoreShare, ThreeProcessesBoundToTwoCoresShareThem) {
  const std::vector<ProcessPlacement> job{process(0, v1::ROLE_DISPLAY, "n", {0}),
                                          process(1, v1::ROLE_RENDER, "n", {1}),
                                          process(2, v1::ROLE_RENDER, "n", {1})};
  const auto shares = renderCoreShares(job);
  ASSERT_EQ(shares.size(), 2u);
  EXPECT_FLOAT_EQ(shares[0], 2.0f / 3.0f);
  EXPECT_FLOAT_EQ(shares[1], 2.0f / 3.0f);
}

TEST(CoreShare, ThisProcessMayRunOnSomeProcessor) {
  EXPECT_FALSE(allowedCpus().empty());
}

}  // namespace
}  // namespace pointillist
