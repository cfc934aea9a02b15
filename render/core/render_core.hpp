#pragma once
// Every decision of a render process (seed 003 §4.4-4.5), without MPI or GL:
// the queue of render packets, the cache of top-level cells (LRU with time-out
// and a memory cap) holding ranges of each cell's packet
// (common/cell_ranges.hpp), which ranges to ask data-send for and when to ask
// again, the measured rates T_s and T_n, and the reports to traverse and
// data-send.
//
// The core is told what arrived and `now`; it answers with what to send (an
// Outbox) and which cells' data the caller must drop. The MPI render process
// and the simulator both drive this class; neither decides anything itself.
#include <chrono>
#include <cstdint>
#include <deque>
#include <map>
#include <optional>
#include <span>
#include <string>
#include <unordered_map>
#include <vector>

#include "common/cell_ranges.hpp"
#include "common/clock.hpp"
#include "common/messages.hpp"
#include "common/octree_cell.hpp"
#include "common/peer_ranks.hpp"
#include "common/statistical_node.hpp"
#include "render/core/cell_cache.hpp"
#include "render/core/rate_estimates.hpp"

namespace pointillist::render {

struct RenderCoreConfig {
  std::uint64_t cacheCapBytes = 1ull << 30;
  std::chrono::milliseconds cacheTimeout{30'000};
  // Test hook: after this many packets the process stops drawing (a stalled
  // render process); it still takes messages and reports.
  std::optional<std::uint64_t> stallAfterPackets;
};

// How often the cache is checked for expired cells and late data re-asked.
inline constexpr std::chrono::milliseconds kRenderMaintenancePeriod{250};
// Data asked for longer ago than this is asked for again.
inline constexpr std::chrono::milliseconds kRerequestAfter{1000};
// T_n is sampled from payloads of at least this many bytes, T_s from packets of
// at least this many splats: smaller ones measure overheads, not rates.
inline constexpr std::uint64_t kMinTransferSampleBytes = 4096;
inline constexpr std::uint64_t kMinDrawSampleSplats = 1000;

// What the caller must do besides sending: drop the data of these cells.
struct RenderEffects {
  Outbox messages;
  std::vector<std::uint32_t> released;
};

// What to do with a part of a cell's packet that arrived.
enum class DataVerdict {
  Store,      // write the part's splats into the cell (any held already are the same)
  Duplicate,  // already held: ignore it
  Dropped,    // prefetched data with no room beside the packet waited for
};

// A packet whose data is all cached, handed to the caller to draw.
struct ReadyPacket {
  v1::RenderPacket packet;
  TimePoint arrived;
  TimePoint dataComplete;
};

// A DataPacket's header against its payload (`payloadBytes`): sizes, record
// size and counts that fit a packet, and for parts in a shared segment (no
// payload) places inside it. Throws ProtocolError naming the cell and
// `sourceRank`. The checksum and the segment itself are the caller's.
void checkDataPacketHeader(const v1::DataPacketHeader& header, std::size_t payloadBytes,
                           int sourceRank);

class RenderCore {
 public:
  RenderCore(const RenderCoreConfig& config, PeerRanks peers, int selfRank,
             std::span<const TopLevelCell> topLevel, std::vector<std::uint32_t> owners,
             std::span<const StatisticalPacketEntry> statistical = {});

  // A render packet from traverse `sourceRank`. Needed ranges neither held nor
  // asked for are asked for (the traverse ordered them already; asking too
  // covers a cell evicted after the traverse last heard from us). Throws
  // ProtocolError when a need lies beyond its packet, needs are not sorted and
  // disjoint, or a drawn range lies outside its cell's needs.
  void receivePacket(int sourceRank, v1::RenderPacket packet, TimePoint now,
                     RenderEffects& effects);

  // Splats [first, first + count) of `cell`'s packet arrived (checksum already
  // checked). Throws ProtocolError when they lie outside the dataset's packet.
  DataVerdict receiveData(std::uint32_t cell, std::uint32_t first, std::uint32_t count,
                          double transferSeconds, TimePoint now, RenderEffects& effects);

  // Between messages: maintenance (expired cells, late data asked again),
  // pins the head packet's cells, and hands out the first packet whose data
  // is all here. When there is none, a pending report goes out.
  std::optional<ReadyPacket> nextPacket(TimePoint now, RenderEffects& effects);

  // The caller drew `packet`: `splats` in `seconds`. Returns the tile image's
  // header (the caller adds the pixels); the report goes out.
  v1::TileImageHeader packetDrawn(const ReadyPacket& packet, std::uint64_t splats, double seconds,
                                  TimePoint now, RenderEffects& effects);

  // When nextPacket() next has maintenance to do (a simulated process sleeps
  // until then); nullopt when nothing is cached or asked for.
  std::optional<TimePoint> nextMaintenance() const;

  int selfRank() const { return selfRank_; }
  // For the summary line and tests.
  const CellCache& cache() const { return cache_; }
  std::size_t queuedPackets() const { return queue_.size(); }
  std::uint64_t workloadSplats() const { return workload_; }
  std::uint64_t packetsDone() const { return packetsDone_; }
  std::uint64_t splatsDone() const { return splatsDone_; }
  std::uint64_t hits() const { return hits_; }
  std::uint64_t misses() const { return misses_; }
  std::uint64_t dataBytesReceived() const { return dataBytesReceived_; }
  std::uint64_t droppedPrefetches() const { return droppedPrefetches_; }
  double busySeconds() const { return busySeconds_; }
  double secondsPerSplat() const { return secondsPerSplat_; }
  double secondsPerByte() const { return secondsPerByte_; }
  bool stalled() const;
  bool pinned(std::uint32_t cell) const { return cache_.pinned(cell); }
  bool requested(std::uint32_t cell) const { return requestedAt_.contains(cell); }
  // The splats of `cell` held (0 when not cached).
  std::uint64_t heldSplats(std::uint32_t cell) const;
  // One past the last splat of `cell` held: the room its copy takes.
  std::uint32_t heldExtent(std::uint32_t cell) const;
  bool holds(std::uint32_t cell, std::uint32_t first, std::uint32_t count) const;
  // The length of `cell`'s whole packet in splats (0 for an unknown cell).
  std::uint32_t packetSplats(std::uint32_t cell) const {
    return cell < cellSplats_.size() ? cellSplats_[cell] : 0;
  }
  std::string summary() const;

 private:
  struct QueuedPacket {
    v1::RenderPacket packet;
    TimePoint arrived;
    std::optional<TimePoint> dataComplete;
    std::uint64_t sequence = 0;
    std::uint32_t missing = 0;  // its cells not holding all it needs of them
  };
  // A queued packet's needs of a cell it lacks (need_* entries [first, end)
  // of its packet), so data that arrives updates only the packets waiting for
  // that cell (a packet may name thousands).
  struct Need {
    std::uint64_t sequence = 0;
    int first = 0, end = 0;
  };
  // Per data-send index: the ranges to ask it for.
  using Requests = std::unordered_map<std::uint32_t, std::vector<CellRange>>;
  struct Request {
    TimePoint at;
    std::uint64_t frame = 0;
    SpanSet spans;  // asked for and not yet held
  };

  void pinHeadPacket(TimePoint now, RenderEffects& effects);
  // Counts and lists what a queued packet lacks (it must not be listed yet).
  void countMissing(QueuedPacket& queued);
  // Whether `cell`'s held splats cover need_* entries [first, end) of `packet`.
  bool holdsNeeds(std::uint32_t cell, const v1::RenderPacket& packet, int first, int end) const;
  // More of `cell` is held: the packets waiting for no more than that lack one
  // cell less; one that now has all its data is complete.
  void heldGrew(std::uint32_t cell, TimePoint now);
  QueuedPacket& queuedPacket(std::uint64_t sequence);
  // Asks for what of need_* entries [first, end) of `packet` (all of one
  // cell) is neither held nor already asked for.
  void askUnlessPending(const v1::RenderPacket& packet, int first, int end, TimePoint now,
                        Requests& requests);
  void ask(std::uint32_t cell, std::uint32_t begin, std::uint32_t end, std::uint64_t frame,
           TimePoint now, Requests& requests);
  void sendRequests(Requests& requests, std::uint64_t frame, RenderEffects& effects);
  void rerequestLateCells(TimePoint now, RenderEffects& effects);
  void evict(std::uint32_t cell, RenderEffects& effects);
  void sendReport(RenderEffects& effects);

  RenderCoreConfig config_;
  PeerRanks peers_;
  int selfRank_;
  std::vector<std::uint32_t> cellSplats_;  // whole packet per cell (packet id)
  // Packets from this id on are statistical: their ranges count nodes.
  std::uint32_t nodeRangesFrom_ = 0;
  std::vector<std::uint32_t> owners_;
  CellCache cache_;
  std::deque<QueuedPacket> queue_;
  std::uint64_t packetsQueued_ = 0;
  std::uint64_t pinnedSequence_ = 0;
  std::vector<std::uint32_t> pinnedCells_;
  std::vector<SpanSet> held_;  // by cell (packet id)
  // cell -> the queued packets that lack it. Evictions are rare: one makes the
  // next nextPacket() count every queued packet again (recountMissing_).
  std::unordered_map<std::uint32_t, std::vector<Need>> waiting_;
  bool recountMissing_ = false;
  // cell -> what was asked for, when and for which frame
  std::unordered_map<std::uint32_t, Request> requestedAt_;
  std::vector<CellRange> loaded_;  // stored since the last report
  std::vector<std::uint32_t> evicted_;
  std::vector<std::uint64_t> lastPacketFrom_;  // per traverse
  std::optional<TimePoint> lastMaintenance_;
  bool reportDirty_ = true;  // the first idle moment announces the process
  std::uint64_t reportSequence_ = 0;
  std::uint64_t orderSequence_ = 0;
  std::uint64_t workload_ = 0;
  std::uint64_t packetsDone_ = 0;
  std::uint64_t splatsDone_ = 0;
  std::uint64_t hits_ = 0;
  std::uint64_t misses_ = 0;
  std::uint64_t dataBytesReceived_ = 0;
  std::uint64_t droppedPrefetches_ = 0;
  std::uint64_t extensions_ = 0;  // parts stored beside others of their cell
  double busySeconds_ = 0.0;
  double secondsPerSplat_ = 0.0;
  double secondsPerByte_ = 0.0;
  RecentSamples transferSamples_{32};  // T_n: their lower quartile
};

}  // namespace pointillist::render
