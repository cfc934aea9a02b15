// The render cache of top-level cells: LRU under a memory cap, time-out, pins.
#include <gtest/gtest.h>

#include <algorithm>
#include <map>
#include <random>

#include "common/errors.hpp"
#include "render/core/cell_cache.hpp"

namespace pointillist::render {
namespace {

using namespace std::chrono_literals;
using Clock = CellCache::Clock;

TEST(CellCache, EvictsLeastRecentlyUsedToStayUnderTheCap) {
  CellCache cache(300, 60s);
  const auto t = Clock::now();
  EXPECT_TRUE(cache.insert(1, 100, t).empty());
  EXPECT_TRUE(cache.insert(2, 100, t + 1ms).empty());
  EXPECT_TRUE(cache.insert(3, 100, t + 2ms).empty());
  cache.touch(1, t + 3ms);  // 2 is now the least recently used
  const auto evicted = cache.insert(4, 100, t + 4ms);
  ASSERT_EQ(evicted.size(), 1u);
  EXPECT_EQ(evicted[0], 2u);
  EXPECT_EQ(cache.bytes(), 300u);
  EXPECT_EQ(cache.lruOrder(), (std::vector<std::uint32_t>{3, 1, 4}));
  // A large cell evicts as many as needed.
  const auto many = cache.insert(5, 250, t + 5ms);
  EXPECT_EQ(many, (std::vector<std::uint32_t>{3, 1, 4}));
  EXPECT_EQ(cache.bytes(), 250u);
  EXPECT_EQ(cache.evictions(), 4u);
}

// Cells are slots by id: sparse ids work, a pin may come before the cell, and
// an id no dataset could have is refused rather than allocated for.
TEST(CellCache, SparseIdsAndEarlyPinsKeepTheBooksAndAbsurdIdsAreRefused) {
  CellCache cache(1000, 60s);
  const auto t = Clock::now();
  cache.pin(70000);  // before it arrives
  EXPECT_TRUE(cache.pinned(70000));
  EXPECT_FALSE(cache.contains(70000));
  EXPECT_TRUE(cache.insert(5, 300, t).empty());
  EXPECT_TRUE(cache.insert(70000, 400, t + 1ms).empty());
  EXPECT_FALSE(cache.canFit(601));  // the pinned 400 stays
  EXPECT_TRUE(cache.canFit(600));
  EXPECT_EQ(cache.insert(9, 500, t + 2ms), (std::vector<std::uint32_t>{5}));
  EXPECT_EQ(cache.lruOrder(), (std::vector<std::uint32_t>{70000, 9}));
  cache.unpin(70000);
  cache.unpin(12345);  // never pinned: nothing happens
  EXPECT_TRUE(cache.canFit(1000));
  EXPECT_EQ(cache.size(), 2u);
  EXPECT_EQ(cache.bytes(), 900u);
  EXPECT_THROW(cache.insert(0xFFFFFFF0u, 1, t), UsageError);
  EXPECT_THROW(cache.pin(0xFFFFFFF0u), UsageError);
  EXPECT_FALSE(cache.contains(0xFFFFFFF0u));
}

TEST(CellCache, PinnedCellsAreNeverEvicted) {
  CellCache cache(200, 1ms);
  const auto t = Clock::now();
  cache.pin(1);
  cache.insert(1, 100, t);
  cache.insert(2, 100, t);
  const auto evicted = cache.insert(3, 100, t);
  EXPECT_EQ(evicted, (std::vector<std::uint32_t>{2}));
  EXPECT_TRUE(cache.contains(1));
  // Time-out skips pinned cells too.
  EXPECT_EQ(cache.expire(t + 1s), (std::vector<std::uint32_t>{3}));
  EXPECT_TRUE(cache.contains(1));
  cache.unpin(1);
  EXPECT_EQ(cache.expire(t + 2s), (std::vector<std::uint32_t>{1}));
  EXPECT_EQ(cache.size(), 0u);
}

TEST(CellCache, GoesOverTheCapOnlyWhenEverythingIsPinned) {
  CellCache cache(100, 60s);
  const auto t = Clock::now();
  cache.pin(1);
  cache.pin(2);
  cache.insert(1, 80, t);
  cache.insert(2, 80, t);
  EXPECT_EQ(cache.overCapInsertions(), 1u);
  EXPECT_EQ(cache.peakBytes(), 160u);
}

TEST(CellCache, ExpiresCellsUnusedLongerThanTheTimeout) {
  CellCache cache(1000, 100ms);
  const auto t = Clock::now();
  cache.insert(1, 10, t);
  cache.insert(2, 10, t + 50ms);
  cache.touch(1, t + 120ms);
  EXPECT_TRUE(cache.expire(t + 140ms).empty());
  EXPECT_EQ(cache.expire(t + 160ms), (std::vector<std::uint32_t>{2}));
  EXPECT_EQ(cache.expire(t + 230ms), (std::vector<std::uint32_t>{1}));
}

// After every operation: the books add up, and the cap holds unless pinned
// cells (and the cell just inserted or grown) alone exceed it.
TEST(CellCache, RandomWorkloadKeepsItsInvariants) {
  CellCache cache(5000, 50ms);
  std::mt19937 random(11);
  auto t = Clock::now();
  std::map<std::uint32_t, int> pins;
  std::map<std::uint32_t, std::uint64_t> sizes;  // what the cache should hold
  std::size_t overCapSteps = 0;
  for (int step = 0; step < 20'000; ++step) {
    t += std::chrono::microseconds(random() % 200);
    const std::uint32_t cell = random() % 64;
    const std::uint64_t before = cache.bytes();
    bool inserted = false;
    switch (random() % 5) {
      case 0:
      case 1: {
        const std::uint64_t bytes = 100 + random() % 900;
        // A new cell, or a longer prefix of a cached one; a shorter one only touches it.
        inserted = !cache.contains(cell) || cache.bytesOf(cell) < bytes;
        for (auto victim : cache.insert(cell, bytes, t)) {
          ASSERT_FALSE(cache.pinned(victim));
          ASSERT_FALSE(cache.contains(victim));
          ASSERT_NE(victim, cell);
          sizes.erase(victim);
        }
        sizes[cell] = std::max(sizes[cell], bytes);
        ASSERT_EQ(cache.bytesOf(cell), sizes[cell]);
        break;
      }
      case 2:
        cache.touch(cell, t);
        break;
      case 3:
        if (pins[cell] < 2 && pins.size() < 3) {
          cache.pin(cell);
          ++pins[cell];
        } else if (pins.contains(cell)) {
          cache.unpin(cell);
          if (--pins[cell] == 0) pins.erase(cell);
        }
        break;
      default:
        for (auto victim : cache.expire(t)) {
          ASSERT_FALSE(cache.pinned(victim));
          sizes.erase(victim);
        }
    }
    std::uint64_t held = 0;
    std::uint64_t evictable = 0;  // unpinned, and not the cell just inserted
    std::uint64_t pinnedHeld = 0;
    for (const auto& [id, bytes] : sizes) {
      ASSERT_TRUE(cache.contains(id)) << "cell " << id;
      held += bytes;
      if (cache.pinned(id)) pinnedHeld += bytes;
      if (!cache.pinned(id) && !(inserted && id == cell)) evictable += bytes;
    }
    // canFit keeps its pinned bytes as pins, growths and evictions come.
    const std::uint64_t probe = random() % 6000;
    ASSERT_EQ(cache.canFit(probe), pinnedHeld + probe <= cache.capBytes()) << "step " << step;
    ASSERT_EQ(cache.bytes(), held);
    ASSERT_EQ(cache.size(), sizes.size());
    ASSERT_EQ(cache.lruOrder().size(), cache.size());
    ASSERT_LE(cache.bytes(), cache.peakBytes());
    if (inserted) {
      if (cache.bytes() > cache.capBytes()) {
        ++overCapSteps;
        ASSERT_EQ(evictable, 0u) << "over the cap with evictable cells left, step " << step;
      }
    } else {
      ASSERT_LE(cache.bytes(), before)
          << "only an insert that grows a cell adds bytes, step " << step;
    }
  }
  EXPECT_GT(cache.evictions(), 0u);
  EXPECT_EQ(cache.overCapInsertions(), overCapSteps);
}

}  // namespace
}  // namespace pointillist::render
