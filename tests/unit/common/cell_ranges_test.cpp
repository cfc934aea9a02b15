// Ranges of packets (common/cell_ranges.hpp): a span set stays disjoint,
// sorted and without touching spans whatever is added or removed, and agrees
// with a plain set of splats on every question asked of it.
#include "common/cell_ranges.hpp"

#include <gtest/gtest.h>

#include <random>
#include <set>

#include "common/errors.hpp"
#include "pointillist.pb.h"

namespace pointillist {
namespace {

void expectWellFormed(const SpanSet& set) {
  const auto spans = set.spans();
  for (std::size_t i = 0; i < spans.size(); ++i) {
    ASSERT_LT(spans[i].begin, spans[i].end) << "span " << i << " is empty";
    if (i > 0) {
      ASSERT_LT(spans[i - 1].end, spans[i].begin) << "spans " << i << " touch";
    }
  }
}

TEST(SpanSet, AgreesWithASetOfSplatsThroughAddsAndRemoves) {
  std::mt19937 rng(11);
  const auto next = [&](std::uint32_t n) { return static_cast<std::uint32_t>(rng() % n); };
  for (int trial = 0; trial < 50; ++trial) {
    SpanSet set;
    std::set<std::uint32_t> model;
    const std::uint32_t size = 50 + next(400);
    for (int step = 0; step < 200; ++step) {
      const std::uint32_t begin = next(size);
      const std::uint32_t end = begin + next(40);
      if (next(3) == 0) {
        set.remove(begin, end);
        for (std::uint32_t i = begin; i < end; ++i) model.erase(i);
      } else {
        std::uint64_t fresh = 0;
        for (std::uint32_t i = begin; i < end; ++i) fresh += model.insert(i).second;
        ASSERT_EQ(set.add(begin, end), fresh);
      }
      expectWellFormed(set);
      ASSERT_EQ(set.splats(), model.size());
      ASSERT_EQ(set.extent(), model.empty() ? 0u : *model.rbegin() + 1);
      // Every question about a random stretch.
      const std::uint32_t b = next(size + 40);
      const std::uint32_t e = b + next(60);
      std::uint64_t absent = 0;
      for (std::uint32_t i = b; i < e; ++i) absent += !model.contains(i);
      ASSERT_EQ(set.uncovered(b, e), absent);
      ASSERT_EQ(set.covers(b, e), absent == 0);
      std::uint64_t gaps = 0;
      std::uint32_t last = b;
      set.forEachGap(b, e, [&](std::uint32_t gb, std::uint32_t ge) {
        ASSERT_LT(gb, ge);
        ASSERT_GE(gb, last);
        for (std::uint32_t i = gb; i < ge; ++i) ASSERT_FALSE(model.contains(i)) << i;
        if (gb > b) {
          ASSERT_TRUE(model.contains(gb - 1)) << "a gap that does not start after data";
        }
        if (ge < e) {
          ASSERT_TRUE(model.contains(ge)) << "a gap that stops short";
        }
        gaps += ge - gb;
        last = ge;
      });
      ASSERT_EQ(gaps, absent);
    }
  }
}

TEST(SpanSet, AddsJoinTouchingSpansAndRemovesSplitThem) {
  SpanSet set(10, 20);
  set.add(30, 40);
  set.add(20, 30);  // touches both: one span
  ASSERT_EQ(set.spans().size(), 1u);
  EXPECT_EQ(set.spans()[0], (SplatSpan{10, 40}));
  set.remove(15, 25);
  ASSERT_EQ(set.spans().size(), 2u);
  EXPECT_EQ(set.spans()[0], (SplatSpan{10, 15}));
  EXPECT_EQ(set.spans()[1], (SplatSpan{25, 40}));
  EXPECT_EQ(set.add(5, 50), 45u - 20u);
  EXPECT_EQ(set, SpanSet(5, 50));
  EXPECT_EQ(set.add(7, 7), 0u);
  set.remove(0, 100);
  EXPECT_TRUE(set.empty());
}

TEST(CellRanges, NormalizingSortsJoinsAcrossSmallGapsAndDropsEmptyRanges) {
  std::vector<CellRange> ranges{{2, 50, 10}, {1, 0, 5}, {2, 0, 10}, {2, 12, 3},
                                {2, 55, 20}, {1, 9, 1}, {3, 4, 0}};
  normalizeCellRanges(ranges);
  EXPECT_EQ(ranges,
            (std::vector<CellRange>{{1, 0, 5}, {1, 9, 1}, {2, 0, 10}, {2, 12, 3}, {2, 50, 25}}));
  normalizeCellRanges(ranges, 4);
  EXPECT_EQ(ranges, (std::vector<CellRange>{{1, 0, 10}, {2, 0, 15}, {2, 50, 25}}));
  EXPECT_EQ(rangeSplats(ranges), 50u);
  std::vector<std::pair<std::uint32_t, std::size_t>> blocks;
  forEachCellBlock(std::span<const CellRange>(ranges),
                   [&](std::uint32_t cell, std::span<const CellRange> block) {
                     blocks.emplace_back(cell, block.size());
                   });
  EXPECT_EQ(blocks, (std::vector<std::pair<std::uint32_t, std::size_t>>{{1, 1}, {2, 2}}));
}

TEST(CellRanges, FieldsRoundTripAndMalformedOnesAreRefused) {
  const std::vector<CellRange> ranges{{4, 0, 8}, {4, 100, 1}, {9, 7, 3}};
  v1::SendOrder order;
  addRangeFields(ranges, *order.mutable_range_top_level(), *order.mutable_range_first(),
                 *order.mutable_range_count());
  EXPECT_EQ(
      rangesFromFields(order.range_top_level(), order.range_first(), order.range_count(), "order"),
      ranges);
  v1::SendOrder shorter = order;
  shorter.mutable_range_first()->RemoveLast();
  EXPECT_THROW(rangesFromFields(shorter.range_top_level(), shorter.range_first(),
                                shorter.range_count(), "order"),
               ProtocolError);
  v1::SendOrder empty = order;
  empty.set_range_count(1, 0);
  EXPECT_THROW(
      rangesFromFields(empty.range_top_level(), empty.range_first(), empty.range_count(), "order"),
      ProtocolError);
  v1::SendOrder past = order;
  past.set_range_first(2, 0xFFFFFFFEu);
  try {
    rangesFromFields(past.range_top_level(), past.range_first(), past.range_count(), "order 7");
    FAIL() << "a range past 2^32 splats was taken";
  } catch (const ProtocolError& error) {
    EXPECT_NE(std::string(error.what()).find("order 7: range 2"), std::string::npos)
        << error.what();
  }
}

}  // namespace
}  // namespace pointillist
