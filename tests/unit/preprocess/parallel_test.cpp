#include "preprocess/parallel.hpp"

#include <sys/mman.h>
#include <sys/resource.h>

#include <cstddef>
#include <cstdint>
#include <vector>

#include <gtest/gtest.h>

#include "common/splat.hpp"
#include "common/uninitialized_allocator.hpp"

namespace pointillist::preprocess {
namespace {

long minorFaults() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return usage.ru_minflt;
}

TEST(PopulatePages, FreshMemoryIsMappedAheadAndReadsZero) {
  constexpr std::size_t kBytes = std::size_t{64} << 20;
  void* mapped = mmap(nullptr, kBytes, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
  ASSERT_NE(mapped, MAP_FAILED);
  auto* bytes = static_cast<unsigned char*>(mapped);
  // Not page-aligned at either end: whole pages inside are mapped, and the
  // bytes around them stay as they are.
  populatePages(bytes + 100, kBytes - 200, 2);
  const long before = minorFaults();
  std::uint64_t sum = 0;
  for (std::size_t at = 4096; at + 4096 <= kBytes; at += 4096) {
    sum += bytes[at];
    bytes[at] = 1;
  }
  const long faults = minorFaults() - before;
#ifdef MADV_POPULATE_WRITE
  // 16,382 pages touched; a kernel that knows the advice maps them all ahead.
  if (madvise(bytes, 4096, MADV_POPULATE_WRITE) == 0) {
    EXPECT_LT(faults, 64);
  }
#endif
  EXPECT_EQ(sum, 0u);
  munmap(mapped, kBytes);
}

TEST(PopulatePages, AVectorFilledAfterwardsHoldsWhatWasWritten) {
  std::vector<Splat> splats;
  splats.reserve(100'000);
  populatePages(splats.data(), splats.capacity() * sizeof(Splat), 0);
  for (std::size_t i = 0; i < 100'000; ++i) {
    Splat s{};
    s.position[0] = static_cast<float>(i);
    splats.push_back(s);
  }
  for (std::size_t i = 0; i < splats.size(); i += 997)
    EXPECT_EQ(splats[i].position[0], static_cast<float>(i));
  populatePages(nullptr, 0, 0);  // nothing to do
}

}  // namespace
}  // namespace pointillist::preprocess
