#pragma once
// Ranges of splats of top-level cells' packets: what a tile needs, what a
// render process holds or has on order, what a data-send process has sent.
// Traverse, data-send and render processes all count in them. A tile draws
// the cells it does not cull, and those lie scattered through a packet's
// layers (a layer holds every cell of its depth beneath the top-level cell),
// so a prefix through the drawn ones carried half again their bytes of
// culled cells (docs/scheduling.md §19).
#include <algorithm>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

namespace pointillist {

// Splats [first, first + count) of top-level cell `cell`'s packet.
struct CellRange {
  std::uint32_t cell = 0;
  std::uint32_t first = 0;
  std::uint32_t count = 0;
  std::uint64_t end() const { return std::uint64_t{first} + count; }
  bool operator==(const CellRange&) const = default;
};

// Splats [begin, end) of one packet.
struct SplatSpan {
  std::uint32_t begin = 0;
  std::uint32_t end = 0;
  bool operator==(const SplatSpan&) const = default;
};

// The splats of one packet held (or sent, or on order): disjoint spans in
// ascending order, never touching (adjacent spans are one).
class SpanSet {
 public:
  SpanSet() = default;
  SpanSet(std::uint32_t begin, std::uint32_t end) { add(begin, end); }

  bool empty() const { return spans_.empty(); }
  std::span<const SplatSpan> spans() const { return spans_; }
  std::uint64_t splats() const;  // splats held
  // One past the last splat held (0 when empty): the room a copy needs.
  std::uint32_t extent() const { return spans_.empty() ? 0 : spans_.back().end; }
  bool covers(std::uint32_t begin, std::uint32_t end) const;
  // Adds [begin, end); returns how many of its splats were not held before.
  std::uint64_t add(std::uint32_t begin, std::uint32_t end);
  void add(const SpanSet& other);
  // Drops [begin, end).
  void remove(std::uint32_t begin, std::uint32_t end);
  // How many of [begin, end) are not held.
  std::uint64_t uncovered(std::uint32_t begin, std::uint32_t end) const;
  // Calls gap(b, e) for each stretch of [begin, end) not held, ascending.
  template <class Gap>
  void forEachGap(std::uint32_t begin, std::uint32_t end, Gap&& gap) const;
  void clear() { spans_.clear(); }
  bool operator==(const SpanSet&) const = default;

 private:
  std::vector<SplatSpan> spans_;
};

// Sorts `ranges` by cell and first splat and joins those that overlap, touch
// or lie at most `gapSplats` apart (a gap of a few splats costs fewer bytes
// than the range it saves costs to name, hold and look up). Empty ranges go.
void normalizeCellRanges(std::vector<CellRange>& ranges, std::uint32_t gapSplats = 0);

// Splats the ranges hold in all.
std::uint64_t rangeSplats(std::span<const CellRange> ranges);

// Ranges sorted by cell, one block of them per cell: calls
// block(cell, ranges of that cell) in order.
template <class Block>
void forEachCellBlock(std::span<const CellRange> ranges, Block&& block) {
  for (std::size_t at = 0; at < ranges.size();) {
    std::size_t end = at + 1;
    while (end < ranges.size() && ranges[end].cell == ranges[at].cell) ++end;
    block(ranges[at].cell, ranges.subspan(at, end - at));
    at = end;
  }
}

// Reads parallel repeated fields (cells, firsts, counts) of a message into
// ranges; ProtocolError naming `what` when their lengths differ, a count is
// 0 or a range passes 2^32 splats.
template <class Cells, class Firsts, class Counts>
std::vector<CellRange> rangesFromFields(const Cells& cells, const Firsts& firsts,
                                        const Counts& counts, const std::string& what);
void throwBadRangeFields(const std::string& what, std::size_t cells, std::size_t firsts,
                         std::size_t counts, std::size_t bad);

template <class Cells, class Firsts, class Counts>
std::vector<CellRange> rangesFromFields(const Cells& cells, const Firsts& firsts,
                                        const Counts& counts, const std::string& what) {
  const auto size = static_cast<std::size_t>(cells.size());
  if (static_cast<std::size_t>(firsts.size()) != size ||
      static_cast<std::size_t>(counts.size()) != size) {
    throwBadRangeFields(what, size, static_cast<std::size_t>(firsts.size()),
                        static_cast<std::size_t>(counts.size()), size);
  }
  std::vector<CellRange> ranges;
  ranges.reserve(size);
  for (std::size_t i = 0; i < size; ++i) {
    const CellRange range{cells[static_cast<int>(i)], firsts[static_cast<int>(i)],
                          counts[static_cast<int>(i)]};
    if (range.count == 0 || range.end() > 0xFFFFFFFFull) {
      throwBadRangeFields(what, size, size, size, i);
    }
    ranges.push_back(range);
  }
  return ranges;
}

// Writes ranges into parallel repeated fields of a message.
template <class Cells, class Firsts, class Counts>
void addRangeFields(std::span<const CellRange> ranges, Cells& cells, Firsts& firsts,
                    Counts& counts) {
  const auto size = static_cast<int>(ranges.size());
  cells.Reserve(cells.size() + size);
  firsts.Reserve(firsts.size() + size);
  counts.Reserve(counts.size() + size);
  for (const CellRange& range : ranges) {
    cells.Add(range.cell);
    firsts.Add(range.first);
    counts.Add(range.count);
  }
}

template <class Gap>
void SpanSet::forEachGap(std::uint32_t begin, std::uint32_t end, Gap&& gap) const {
  std::uint32_t at = begin;
  // The first span ending after `begin`.
  auto span =
      std::upper_bound(spans_.begin(), spans_.end(), begin,
                       [](std::uint32_t value, const SplatSpan& s) { return value < s.end; });
  for (; span != spans_.end() && span->begin < end && at < end; ++span) {
    if (span->begin > at) gap(at, span->begin);
    at = std::max(at, span->end);
  }
  if (at < end) gap(at, end);
}

}  // namespace pointillist
