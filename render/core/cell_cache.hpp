#pragma once
// The render process's cache of top-level cells (seed 003 §4.5): least
// recently used cells go first when the memory cap is reached, and cells unused
// for longer than the time-out are dropped. Cells needed by queued render
// packets are pinned and never evicted. A cell grows as ranges of its packet
// arrive; it counts the room up to the last splat held (a copy's size, holes
// included). The cache only keeps the books; the caller owns the data (GL
// buffers, kernel arrays) and is told what to drop.
#include <chrono>
#include <cstdint>
#include <optional>
#include <vector>

namespace pointillist::render {

class CellCache {
 public:
  using Clock = std::chrono::steady_clock;

  CellCache(std::uint64_t capBytes, std::chrono::milliseconds timeout);

  bool contains(std::uint32_t cell) const { return cell < slots_.size() && slots_[cell].cached; }
  // Marks a cell used now (moves it to the most recent end).
  void touch(std::uint32_t cell, Clock::time_point now);
  // Makes the cell hold `bytes` (adds it, or grows a cached one; never
  // shrinks) and marks it used, first evicting least recently used unpinned
  // other cells until the growth fits under the cap. Returns the evicted cells.
  // When pinned cells and this one alone exceed the cap it still grows
  // (counted in overCapInsertions).
  std::vector<std::uint32_t> insert(std::uint32_t cell, std::uint64_t bytes, Clock::time_point now);
  // Drops an unpinned cell now (counted as an eviction); false when it is
  // pinned or not cached.
  bool evict(std::uint32_t cell);
  std::uint64_t bytesOf(std::uint32_t cell) const;  // 0 when not cached
  // True when `bytes` more fit under the cap once every unpinned cell is evicted.
  bool canFit(std::uint64_t bytes) const;
  // Evicts unpinned cells unused for longer than the time-out.
  std::vector<std::uint32_t> expire(Clock::time_point now);
  // Pins count per cell; a pin may be taken before the cell arrives.
  void pin(std::uint32_t cell);
  void unpin(std::uint32_t cell);
  bool pinned(std::uint32_t cell) const;

  std::uint64_t bytes() const { return bytes_; }
  std::uint64_t peakBytes() const { return peakBytes_; }
  std::uint64_t capBytes() const { return capBytes_; }
  std::size_t size() const { return size_; }
  std::uint64_t evictions() const { return evictions_; }
  std::uint64_t overCapInsertions() const { return overCapInsertions_; }
  // Least recently used first.
  std::vector<std::uint32_t> lruOrder() const;
  // When the least recently used cell was last used; nullopt when empty.
  std::optional<Clock::time_point> oldestUse() const;

 private:
  static constexpr std::uint32_t kNone = 0xFFFFFFFFu;
  // Cells are dense top-level ids (packet ids): a slot per id, not a hash
  // map, and the recency list threaded through the slots. A frame looks up,
  // pins and touches every cell of every packet.
  struct Slot {
    std::uint64_t bytes = 0;
    Clock::time_point lastUsed{};
    std::uint32_t older = kNone, newer = kNone;  // recency list neighbours
    std::uint32_t pins = 0;                      // taken before the cell arrives too
    bool cached = false;
  };
  Slot& slot(std::uint32_t cell);  // grows the slots to hold `cell`
  void linkNewest(std::uint32_t cell);
  void unlink(std::uint32_t cell);
  void erase(std::uint32_t cell);

  std::uint64_t capBytes_;
  std::chrono::milliseconds timeout_;
  std::vector<Slot> slots_;
  std::uint32_t oldest_ = kNone, newest_ = kNone;
  std::size_t size_ = 0;
  std::uint64_t bytes_ = 0;
  std::uint64_t pinnedBytes_ = 0;  // of the cached cells that are pinned
  std::uint64_t peakBytes_ = 0;
  std::uint64_t evictions_ = 0;
  std::uint64_t overCapInsertions_ = 0;
};

}  // namespace pointillist::render
