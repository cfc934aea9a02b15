#include "common/cell_ranges.hpp"

#include <algorithm>

#include "common/errors.hpp"

namespace pointillist {

std::uint64_t SpanSet::splats() const {
  std::uint64_t total = 0;
  for (const SplatSpan& span : spans_) total += span.end - span.begin;
  return total;
}

bool SpanSet::covers(std::uint32_t begin, std::uint32_t end) const {
  if (begin >= end) return true;
  const auto span =
      std::upper_bound(spans_.begin(), spans_.end(), begin,
                       [](std::uint32_t value, const SplatSpan& s) { return value < s.end; });
  return span != spans_.end() && span->begin <= begin && span->end >= end;
}

std::uint64_t SpanSet::uncovered(std::uint32_t begin, std::uint32_t end) const {
  std::uint64_t missing = 0;
  forEachGap(begin, end, [&](std::uint32_t b, std::uint32_t e) { missing += e - b; });
  return missing;
}

std::uint64_t SpanSet::add(std::uint32_t begin, std::uint32_t end) {
  if (begin >= end) return 0;
  const std::uint64_t added = uncovered(begin, end);
  if (added == 0) return 0;
  // Spans that overlap or touch [begin, end) join it: those from the first
  // that ends at or after `begin` to the last that starts at or before `end`.
  auto first =
      std::lower_bound(spans_.begin(), spans_.end(), begin,
                       [](const SplatSpan& s, std::uint32_t value) { return s.end < value; });
  auto last = first;
  while (last != spans_.end() && last->begin <= end) ++last;
  if (first == last) {
    spans_.insert(first, SplatSpan{begin, end});
    return added;
  }
  first->begin = std::min(first->begin, begin);
  first->end = std::max((last - 1)->end, end);
  spans_.erase(first + 1, last);
  return added;
}

void SpanSet::add(const SpanSet& other) {
  for (const SplatSpan& span : other.spans_) add(span.begin, span.end);
}

void SpanSet::remove(std::uint32_t begin, std::uint32_t end) {
  if (begin >= end) return;
  // The spans that overlap [begin, end): from the first ending after `begin`
  // to the last starting before `end`.
  auto first =
      std::upper_bound(spans_.begin(), spans_.end(), begin,
                       [](std::uint32_t value, const SplatSpan& s) { return value < s.end; });
  auto last = first;
  while (last != spans_.end() && last->begin < end) ++last;
  if (first == last) return;
  std::vector<SplatSpan> kept;
  if (first->begin < begin) kept.push_back({first->begin, begin});
  if ((last - 1)->end > end) kept.push_back({end, (last - 1)->end});
  const auto at = spans_.erase(first, last);
  spans_.insert(at, kept.begin(), kept.end());
}

void normalizeCellRanges(std::vector<CellRange>& ranges, std::uint32_t gapSplats) {
  std::erase_if(ranges, [](const CellRange& r) { return r.count == 0; });
  const auto before = [](const CellRange& a, const CellRange& b) {
    return a.cell != b.cell ? a.cell < b.cell : a.first < b.first;
  };
  // Most callers hand them in order already (a walk's ranges).
  if (!std::is_sorted(ranges.begin(), ranges.end(), before)) {
    std::sort(ranges.begin(), ranges.end(), before);
  }
  std::size_t out = 0;
  for (std::size_t i = 0; i < ranges.size(); ++i) {
    if (out > 0 && ranges[out - 1].cell == ranges[i].cell &&
        ranges[i].first <= ranges[out - 1].end() + gapSplats) {
      CellRange& joined = ranges[out - 1];
      joined.count =
          static_cast<std::uint32_t>(std::max(joined.end(), ranges[i].end()) - joined.first);
      continue;
    }
    ranges[out++] = ranges[i];
  }
  ranges.resize(out);
}

std::uint64_t rangeSplats(std::span<const CellRange> ranges) {
  std::uint64_t total = 0;
  for (const CellRange& range : ranges) total += range.count;
  return total;
}

void throwBadRangeFields(const std::string& what, std::size_t cells, std::size_t firsts,
                         std::size_t counts, std::size_t bad) {
  if (cells != firsts || cells != counts) {
    throw ProtocolError(what + " gives " + std::to_string(cells) + " cells, " +
                        std::to_string(firsts) + " first splats and " + std::to_string(counts) +
                        " counts for its ranges");
  }
  throw ProtocolError(what + ": range " + std::to_string(bad) +
                      " is empty or reaches past 2^32 splats");
}

}  // namespace pointillist
