// Which data-send process owns which top-level cell.
#include "common/ownership.hpp"

#include <gtest/gtest.h>

#include <numeric>

#include "common/errors.hpp"

namespace pointillist {
namespace {

TEST(Ownership, ContiguousRunsOfAboutEqualBytes) {
  std::vector<TopLevelCell> cells(100);
  for (std::size_t i = 0; i < cells.size(); ++i) cells[i].byteSize = 1000 + (i % 7) * 300;
  for (std::uint32_t owners : {1u, 2u, 3u, 7u}) {
    const auto owner = assignOwners(cells, owners);
    std::vector<std::uint64_t> bytes(owners, 0);
    for (std::size_t i = 0; i < cells.size(); ++i) {
      ASSERT_LT(owner[i], owners);
      if (i > 0) {
        ASSERT_GE(owner[i], owner[i - 1]) << "contiguous runs";
      }
      bytes[owner[i]] += cells[i].byteSize;
    }
    const double mean =
        static_cast<double>(std::accumulate(bytes.begin(), bytes.end(), 0ull)) / owners;
    for (auto b : bytes) EXPECT_NEAR(static_cast<double>(b), mean, 2000.0);
  }
  EXPECT_THROW((void)assignOwners(cells, 0), UsageError);
}

}  // namespace
}  // namespace pointillist
