#include "render/core/cell_cache.hpp"

#include <algorithm>

#include "common/errors.hpp"

namespace pointillist::render {

CellCache::CellCache(std::uint64_t capBytes, std::chrono::milliseconds timeout)
    : capBytes_(capBytes), timeout_(timeout) {
  if (capBytes_ == 0) throw UsageError("the render cache needs a cap above 0 bytes");
}

void CellCache::touch(std::uint32_t cell, Clock::time_point now) {
  auto found = entries_.find(cell);
  if (found == entries_.end()) return;
  found->second.lastUsed = now;
  recency_.splice(recency_.end(), recency_, found->second.position);
}

std::vector<std::uint32_t> CellCache::insert(std::uint32_t cell, std::uint64_t bytes,
                                             Clock::time_point now) {
  std::vector<std::uint32_t> evicted;
  const std::uint64_t current = bytesOf(cell);
  if (contains(cell)) touch(cell, now);
  if (contains(cell) && bytes <= current) return evicted;
  const std::uint64_t growth = bytes - current;
  for (auto it = recency_.begin(); it != recency_.end() && bytes_ + growth > capBytes_;) {
    const std::uint32_t victim = *it++;
    if (victim == cell || pinned(victim)) continue;
    evicted.push_back(victim);
    erase(victim);
  }
  if (bytes_ + growth > capBytes_) ++overCapInsertions_;
  if (contains(cell)) {
    entries_.at(cell).bytes = bytes;
  } else {
    recency_.push_back(cell);
    entries_[cell] = Entry{bytes, now, std::prev(recency_.end())};
  }
  bytes_ += growth;
  if (pinned(cell)) pinnedBytes_ += growth;
  peakBytes_ = std::max(peakBytes_, bytes_);
  return evicted;
}

bool CellCache::evict(std::uint32_t cell) {
  if (!contains(cell) || pinned(cell)) return false;
  erase(cell);
  return true;
}

std::uint64_t CellCache::bytesOf(std::uint32_t cell) const {
  const auto found = entries_.find(cell);
  return found == entries_.end() ? 0 : found->second.bytes;
}

std::vector<std::uint32_t> CellCache::expire(Clock::time_point now) {
  std::vector<std::uint32_t> evicted;
  for (auto it = recency_.begin(); it != recency_.end();) {
    const std::uint32_t cell = *it++;
    const Entry& entry = entries_.at(cell);
    if (now - entry.lastUsed <= timeout_) break;  // the rest were used more recently
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
  if (++pins_[cell] == 1) pinnedBytes_ += bytesOf(cell);
}

void CellCache::unpin(std::uint32_t cell) {
  auto found = pins_.find(cell);
  if (found == pins_.end()) return;
  if (--found->second == 0) {
    pins_.erase(found);
    pinnedBytes_ -= bytesOf(cell);
  }
}

bool CellCache::pinned(std::uint32_t cell) const {
  return pins_.contains(cell);
}

std::vector<std::uint32_t> CellCache::lruOrder() const {
  return {recency_.begin(), recency_.end()};
}

std::optional<CellCache::Clock::time_point> CellCache::oldestUse() const {
  if (recency_.empty()) return std::nullopt;
  return entries_.at(recency_.front()).lastUsed;
}

void CellCache::erase(std::uint32_t cell) {
  auto found = entries_.find(cell);
  bytes_ -= found->second.bytes;
  if (pinned(cell)) pinnedBytes_ -= found->second.bytes;
  recency_.erase(found->second.position);
  entries_.erase(found);
  ++evictions_;
}

}  // namespace pointillist::render
