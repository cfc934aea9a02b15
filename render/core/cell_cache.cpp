#include "render/core/cell_cache.hpp"

#include <algorithm>
#include <string>

#include "common/errors.hpp"

namespace pointillist::render {

namespace {
// Far beyond any dataset's top-level cells (a slot is 32 bytes): an id past
// it is a caller's bug, not a cell.
constexpr std::uint32_t kMaxCells = 1u << 24;
}  // namespace

CellCache::CellCache(std::uint64_t capBytes, std::chrono::milliseconds timeout)
    : capBytes_(capBytes), timeout_(timeout) {
  if (capBytes_ == 0) throw UsageError("the render cache needs a cap above 0 bytes");
}

CellCache::Slot& CellCache::slot(std::uint32_t cell) {
  if (cell >= slots_.size()) {
    if (cell >= kMaxCells) {
      throw UsageError("render cache: cell id " + std::to_string(cell) + " is beyond " +
                       std::to_string(kMaxCells) + " cells");
    }
    slots_.resize(std::max<std::size_t>(std::size_t{cell} + 1, slots_.size() * 2));
  }
  return slots_[cell];
}

void CellCache::linkNewest(std::uint32_t cell) {
  Slot& s = slots_[cell];
  s.older = newest_;
  s.newer = kNone;
  if (newest_ != kNone) slots_[newest_].newer = cell;
  newest_ = cell;
  if (oldest_ == kNone) oldest_ = cell;
}

void CellCache::unlink(std::uint32_t cell) {
  Slot& s = slots_[cell];
  if (s.older != kNone) slots_[s.older].newer = s.newer;
  if (s.newer != kNone) slots_[s.newer].older = s.older;
  if (oldest_ == cell) oldest_ = s.newer;
  if (newest_ == cell) newest_ = s.older;
  s.older = s.newer = kNone;
}

void CellCache::touch(std::uint32_t cell, Clock::time_point now) {
  if (!contains(cell)) return;
  slots_[cell].lastUsed = now;
  if (newest_ == cell) return;
  unlink(cell);
  linkNewest(cell);
}

std::vector<std::uint32_t> CellCache::insert(std::uint32_t cell, std::uint64_t bytes,
                                             Clock::time_point now) {
  Slot& s = slot(cell);  // refuses an absurd id before anything is evicted
  std::vector<std::uint32_t> evicted;
  const std::uint64_t current = bytesOf(cell);
  if (contains(cell)) touch(cell, now);
  if (contains(cell) && bytes <= current) return evicted;
  const std::uint64_t growth = bytes - current;
  for (std::uint32_t at = oldest_; at != kNone && bytes_ + growth > capBytes_;) {
    const std::uint32_t victim = at;
    at = slots_[at].newer;
    if (victim == cell || pinned(victim)) continue;
    evicted.push_back(victim);
    erase(victim);
  }
  if (bytes_ + growth > capBytes_) ++overCapInsertions_;
  if (!s.cached) {
    s.cached = true;
    s.lastUsed = now;
    ++size_;
    linkNewest(cell);
  }
  s.bytes = bytes;
  bytes_ += growth;
  if (s.pins > 0) pinnedBytes_ += growth;
  peakBytes_ = std::max(peakBytes_, bytes_);
  return evicted;
}

bool CellCache::evict(std::uint32_t cell) {
  if (!contains(cell) || pinned(cell)) return false;
  erase(cell);
  return true;
}

std::uint64_t CellCache::bytesOf(std::uint32_t cell) const {
  return contains(cell) ? slots_[cell].bytes : 0;
}

std::vector<std::uint32_t> CellCache::expire(Clock::time_point now) {
  std::vector<std::uint32_t> evicted;
  for (std::uint32_t at = oldest_; at != kNone;) {
    const std::uint32_t cell = at;
    at = slots_[at].newer;
    if (now - slots_[cell].lastUsed <= timeout_) break;  // the rest were used more recently
    if (pinned(cell)) continue;
    evicted.push_back(cell);
    erase(cell);
  }
  return evicted;
}

bool CellCache::canFit(std::uint64_t bytes) const {
  return pinnedBytes_ + bytes <= capBytes_;
}

void CellCache::pin(std::uint32_t cell) {
  Slot& s = slot(cell);
  if (++s.pins == 1) pinnedBytes_ += bytesOf(cell);
}

void CellCache::unpin(std::uint32_t cell) {
  if (cell >= slots_.size() || slots_[cell].pins == 0) return;
  if (--slots_[cell].pins == 0) pinnedBytes_ -= bytesOf(cell);
}

bool CellCache::pinned(std::uint32_t cell) const {
  return cell < slots_.size() && slots_[cell].pins > 0;
}

std::vector<std::uint32_t> CellCache::lruOrder() const {
  std::vector<std::uint32_t> order;
  order.reserve(size_);
  for (std::uint32_t at = oldest_; at != kNone; at = slots_[at].newer) order.push_back(at);
  return order;
}

std::optional<CellCache::Clock::time_point> CellCache::oldestUse() const {
  if (oldest_ == kNone) return std::nullopt;
  return slots_[oldest_].lastUsed;
}

void CellCache::erase(std::uint32_t cell) {
  Slot& s = slots_[cell];
  bytes_ -= s.bytes;
  if (s.pins > 0) pinnedBytes_ -= s.bytes;
  unlink(cell);
  s.bytes = 0;
  s.cached = false;
  --size_;
  ++evictions_;
}

}  // namespace pointillist::render
