#include "preprocess/parallel.hpp"

#include <sys/mman.h>
#include <sys/resource.h>

#include <atomic>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <thread>
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

// A body that throws, on any thread: the caller gets the exception once all
// threads are joined, and no chunk is handed out after it.
TEST(ParallelFor, AnExceptionFromAnyThreadReachesTheCaller) {
  for (const std::size_t bad : {std::size_t{0}, std::size_t{3}, std::size_t{999}}) {
    std::atomic<std::size_t> calls{0};
    try {
      parallelFor(
          1000, 4,
          [&](std::size_t i) {
            ++calls;
            if (i == bad) throw std::runtime_error("item " + std::to_string(i));
            std::this_thread::sleep_for(std::chrono::microseconds(20));
          },
          1);
      ADD_FAILURE() << "no exception for item " << bad;
    } catch (const std::runtime_error& e) {
      EXPECT_EQ(std::string(e.what()), "item " + std::to_string(bad));
    }
    // The other threads stop taking items: at most one more each.
    if (bad == 3) {
      EXPECT_LT(calls.load(), 40u);
    }
  }
  // Several throw: one of theirs arrives, whole.
  EXPECT_THROW(parallelFor(
                   64, 4, [](std::size_t) { throw std::logic_error("every item"); }, 1),
               std::logic_error);
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
