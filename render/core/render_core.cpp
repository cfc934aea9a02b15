#include "render/core/render_core.hpp"

#include <algorithm>
#include <cstdio>
#include <limits>
#include <stdexcept>
#include <string>

#include "common/point_groups.hpp"
#include "common/splat.hpp"

namespace pointillist::render {

RenderCore::RenderCore(const RenderCoreConfig& config, PeerRanks peers, int selfRank,
                       std::span<const TopLevelCell> topLevel, std::vector<std::uint32_t> owners,
                       std::span<const StatisticalPacketEntry> statistical)
    : config_(config),
      peers_(std::move(peers)),
      selfRank_(selfRank),
      owners_(std::move(owners)),
      cache_(config.cacheCapBytes, config.cacheTimeout),
      lastPacketFrom_(peers_.traverses.size(), 0) {
  cellSplats_.reserve(topLevel.size());
  for (const TopLevelCell& cell : topLevel) {
    cellSplats_.push_back(static_cast<std::uint32_t>(packetRecords(cell)));
  }
  nodeRangesFrom_ = static_cast<std::uint32_t>(cellSplats_.size());
  for (const StatisticalPacketEntry& entry : statistical) cellSplats_.push_back(entry.records);
  held_.resize(cellSplats_.size());
  if (owners_.size() != cellSplats_.size()) {
    throw UsageError("render core: " + std::to_string(owners_.size()) + " owners for " +
                     std::to_string(cellSplats_.size()) + " top-level cells");
  }
}

bool RenderCore::stalled() const {
  return config_.stallAfterPackets && packetsDone_ >= *config_.stallAfterPackets;
}

std::uint64_t RenderCore::heldSplats(std::uint32_t cell) const {
  return cell < held_.size() ? held_[cell].splats() : 0;
}

std::uint32_t RenderCore::heldExtent(std::uint32_t cell) const {
  return cell < held_.size() ? held_[cell].extent() : 0;
}

bool RenderCore::holds(std::uint32_t cell, std::uint32_t first, std::uint32_t count) const {
  return count == 0 || (cell < held_.size() && held_[cell].covers(first, first + count));
}

namespace {

// Calls block(cell, first, end) for each run of need_* entries [first, end)
// of one cell (the needs are sorted by cell).
template <class Block>
void forEachNeedCell(const v1::RenderPacket& packet, Block&& block) {
  const int needs = packet.need_top_level_size();
  for (int at = 0; at < needs;) {
    int end = at + 1;
    while (end < needs && packet.need_top_level(end) == packet.need_top_level(at)) ++end;
    block(packet.need_top_level(at), at, end);
    at = end;
  }
}

}  // namespace

bool RenderCore::holdsNeeds(std::uint32_t cell, const v1::RenderPacket& packet, int first,
                            int end) const {
  const SpanSet& held = held_[cell];  // the packet's cells were checked against the table
  for (int i = first; i < end; ++i) {
    if (!held.covers(packet.need_first(i), packet.need_first(i) + packet.need_count(i)))
      return false;
  }
  return true;
}

RenderCore::QueuedPacket& RenderCore::queuedPacket(std::uint64_t sequence) {
  // The queue stays in arrival order: packets leave it, none is inserted.
  const auto found = std::lower_bound(
      queue_.begin(), queue_.end(), sequence,
      [](const QueuedPacket& queued, std::uint64_t wanted) { return queued.sequence < wanted; });
  if (found == queue_.end() || found->sequence != sequence) {
    throw std::logic_error("render core: packet " + std::to_string(sequence) +
                           " waits for data but is not queued");
  }
  return *found;
}

void RenderCore::countMissing(QueuedPacket& queued) {
  queued.missing = 0;
  forEachNeedCell(queued.packet, [&](std::uint32_t cell, int first, int end) {
    if (holdsNeeds(cell, queued.packet, first, end)) return;
    ++queued.missing;
    waiting_[cell].push_back({queued.sequence, first, end});
  });
}

void RenderCore::heldGrew(std::uint32_t cell, TimePoint now) {
  const auto found = waiting_.find(cell);
  if (found == waiting_.end()) return;
  std::erase_if(found->second, [&](const Need& need) {
    QueuedPacket& queued = queuedPacket(need.sequence);
    if (!holdsNeeds(cell, queued.packet, need.first, need.end)) return false;
    if (--queued.missing == 0 && !queued.dataComplete) queued.dataComplete = now;
    return true;
  });
  if (found->second.empty()) waiting_.erase(found);
}

void RenderCore::ask(std::uint32_t cell, std::uint32_t begin, std::uint32_t end,
                     std::uint64_t frame, TimePoint now, Requests& requests) {
  requests[owners_[cell]].push_back({cell, begin, end - begin});
  Request& request = requestedAt_[cell];
  request.at = now;
  request.frame = frame;
  request.spans.add(begin, end);
}

void RenderCore::askUnlessPending(const v1::RenderPacket& packet, int first, int end, TimePoint now,
                                  Requests& requests) {
  static const SpanSet kNone;
  const std::uint32_t cell = packet.need_top_level(first);
  const SpanSet& have = held_[cell];
  // What is asked for already is not asked again here (late data is, by
  // rerequestLateCells).
  const auto asked = requestedAt_.find(cell);
  const SpanSet& pending = asked != requestedAt_.end() ? asked->second.spans : kNone;
  std::vector<SplatSpan> lacking;
  for (int i = first; i < end; ++i) {
    const std::uint32_t begin = packet.need_first(i);
    have.forEachGap(begin, begin + packet.need_count(i), [&](std::uint32_t b, std::uint32_t e) {
      pending.forEachGap(b, e, [&](std::uint32_t gb, std::uint32_t ge) {
        lacking.push_back({gb, ge});
      });
    });
  }
  for (const SplatSpan& span : lacking)
    ask(cell, span.begin, span.end, packet.frame_id(), now, requests);
}

namespace {

// The needs are sorted by cell and first splat, disjoint and inside their
// packets; every drawn range lies inside its cell's needs (a statistical
// packet's ranges are nodes, inside the nodes of its needed prefix).
void checkRanges(const v1::RenderPacket& packet, int sourceRank,
                 std::span<const std::uint32_t> cellSplats, std::uint32_t nodeRangesFrom) {
  const auto fail = [&](const std::string& what) {
    throw ProtocolError("render packet " + std::to_string(packet.packet_id()) + " from rank " +
                        std::to_string(sourceRank) + ": " + what);
  };
  const int needs = packet.need_top_level_size();
  if (packet.need_first_size() != needs || packet.need_count_size() != needs) {
    fail("need arrays of different lengths");
  }
  for (int i = 0; i < needs; ++i) {
    const std::uint32_t cell = packet.need_top_level(i);
    const std::uint64_t end = std::uint64_t{packet.need_first(i)} + packet.need_count(i);
    if (cell >= cellSplats.size() || packet.need_count(i) == 0 || end > cellSplats[cell]) {
      fail("needs splats " + std::to_string(packet.need_first(i)) + "+" +
           std::to_string(packet.need_count(i)) + " of top-level cell " + std::to_string(cell) +
           ", not a range inside the dataset's packet");
    }
    if (i > 0 && (cell < packet.need_top_level(i - 1) ||
                  (cell == packet.need_top_level(i - 1) &&
                   packet.need_first(i) <=
                       std::uint64_t{packet.need_first(i - 1)} + packet.need_count(i - 1)))) {
      fail("needs not sorted by cell and splat, or touching");
    }
    if (cell >= nodeRangesFrom && packet.need_first(i) != 0) {
      fail("needs statistical packet " + std::to_string(cell) + " from splat " +
           std::to_string(packet.need_first(i)) + ", not from its start");
    }
  }
  const int ranges = packet.range_top_level_size();
  if (packet.range_offset_size() != ranges || packet.range_count_size() != ranges) {
    fail("range arrays of different lengths");
  }
  // Both lists ascend (the traversal's order): one pass over the needs.
  int at = 0;
  for (int r = 0; r < ranges; ++r) {
    const std::uint32_t cell = packet.range_top_level(r);
    const std::uint64_t first = packet.range_offset(r);
    const std::uint64_t end = first + packet.range_count(r);
    if (r > 0 && cell < packet.range_top_level(r - 1)) fail("ranges not sorted by cell");
    const bool nodes = cell >= nodeRangesFrom;
    const auto needEnd = [&](int i) {
      return std::uint64_t{packet.need_first(i)} + packet.need_count(i);
    };
    while (at < needs && (packet.need_top_level(at) < cell ||
                          (!nodes && packet.need_top_level(at) == cell && needEnd(at) <= first))) {
      ++at;
    }
    if (packet.range_count(r) == 0) continue;
    if (at < needs && packet.need_top_level(at) == cell && nodes) {
      // A statistical packet's ranges are nodes (common/statistical_node.hpp).
      if (end > statisticalNodesInRecords(packet.need_count(at), ~std::uint32_t{0})) {
        fail("range " + std::to_string(r) + " ends at node " + std::to_string(end) +
             " of statistical packet " + std::to_string(cell) + ", beyond the " +
             std::to_string(packet.need_count(at)) + " records it waits for");
      }
      continue;
    }
    if (at == needs || packet.need_top_level(at) != cell || packet.need_first(at) > first ||
        needEnd(at) < end) {
      fail("range " + std::to_string(r) + " draws splats " + std::to_string(first) + "+" +
           std::to_string(packet.range_count(r)) + " of top-level cell " + std::to_string(cell) +
           ", which the packet does not wait for (or ranges not sorted)");
    }
  }
}

}  // namespace

void RenderCore::receivePacket(int sourceRank, v1::RenderPacket packet, TimePoint now,
                               RenderEffects& effects) {
  checkRanges(packet, sourceRank, cellSplats_, nodeRangesFrom_);
  const std::size_t traverse = peers_.indexOf(v1::ROLE_TRAVERSE, sourceRank);
  lastPacketFrom_[traverse] = std::max(lastPacketFrom_[traverse], packet.packet_id());
  workload_ += packet.total_splats();
  QueuedPacket& queued = queue_.emplace_back();
  queued.arrived = now;
  queued.sequence = ++packetsQueued_;
  queued.packet = std::move(packet);
  // Hits, misses and what it waits for, in one pass over its cells.
  Requests requests;
  forEachNeedCell(queued.packet, [&](std::uint32_t cell, int first, int end) {
    if (holdsNeeds(cell, queued.packet, first, end)) {
      ++hits_;
      cache_.touch(cell, now);
      return;
    }
    ++misses_;
    askUnlessPending(queued.packet, first, end, now, requests);
    ++queued.missing;
    waiting_[cell].push_back({queued.sequence, first, end});
  });
  if (queued.missing == 0) queued.dataComplete = now;
  reportDirty_ = true;
  sendRequests(requests, queued.packet.frame_id(), effects);
}

DataVerdict RenderCore::receiveData(std::uint32_t cell, std::uint32_t first, std::uint32_t count,
                                    double transferSeconds, TimePoint now, RenderEffects& effects) {
  if (cell >= cellSplats_.size() || count == 0 ||
      std::uint64_t{first} + count > cellSplats_[cell]) {
    throw ProtocolError("data for top-level cell " + std::to_string(cell) + " holds splats " +
                        std::to_string(first) + "+" + std::to_string(count) +
                        ", which do not lie inside its packet in the dataset's table");
  }
  const std::uint64_t bytes = std::uint64_t{count} * sizeof(Splat);
  dataBytesReceived_ += bytes;
  // T_n: the measured transfer time of the payload per byte.
  if (bytes >= kMinTransferSampleBytes && transferSeconds > 0.0) {
    transferSamples_.add(transferSeconds / static_cast<double>(bytes));
    secondsPerByte_ = transferSamples_.lowerQuartile();
  }
  const std::uint32_t end = first + count;
  // What was asked for and is held now is no longer awaited.
  const auto settle = [&] {
    const auto asked = requestedAt_.find(cell);
    if (asked == requestedAt_.end()) return;
    asked->second.spans.remove(first, end);
    if (asked->second.spans.empty()) requestedAt_.erase(asked);
  };
  if (holds(cell, first, count)) {
    settle();
    return DataVerdict::Duplicate;
  }
  // A copy takes the room up to the last splat held (holes included).
  const std::uint32_t extent = heldExtent(cell);
  const std::uint64_t newBytes = std::uint64_t{std::max(extent, end)} * sizeof(Splat);
  if (!cache_.pinned(cell) && !cache_.canFit(newBytes)) {
    // Prefetched data that cannot fit beside the packet being waited for:
    // drop it (and what is held of the cell) and say so, so that the cell is
    // sent again when it is needed (asked for again once its packet is the
    // head).
    ++droppedPrefetches_;
    requestedAt_.erase(cell);
    if (extent > 0) {
      cache_.evict(cell);
      evict(cell, effects);
    } else {
      evicted_.push_back(cell);
      reportDirty_ = true;
    }
    return DataVerdict::Dropped;
  }
  for (std::uint32_t victim : cache_.insert(cell, newBytes, now)) evict(victim, effects);
  SpanSet& held = held_[cell];
  if (!held.empty()) ++extensions_;
  held.add(first, end);
  heldGrew(cell, now);
  settle();
  loaded_.push_back({cell, first, count});
  reportDirty_ = true;
  return DataVerdict::Store;
}

std::optional<ReadyPacket> RenderCore::nextPacket(TimePoint now, RenderEffects& effects) {
  if (!lastMaintenance_) {
    lastMaintenance_ = now;
  } else if (now - *lastMaintenance_ > kRenderMaintenancePeriod) {
    lastMaintenance_ = now;
    for (std::uint32_t cell : cache_.expire(now)) evict(cell, effects);
    rerequestLateCells(now, effects);
  }
  pinHeadPacket(now, effects);
  if (!stalled()) {
    for (auto it = queue_.begin(); it != queue_.end(); ++it) {
      if (it->missing > 0) continue;
      ReadyPacket packet{std::move(it->packet), it->arrived, it->dataComplete.value_or(now)};
      queue_.erase(it);
      return packet;
    }
  }
  if (reportDirty_) sendReport(effects);
  return std::nullopt;
}

// Only the oldest queued packet holds its cells in the cache: pinning every
// queued packet could hold more than the memory cap. Cells of later packets
// may be evicted and are asked for again when their packet comes first.
void RenderCore::pinHeadPacket(TimePoint now, RenderEffects& effects) {
  // Evictions since the last count: every queued packet counts what it lacks
  // again (the head's count decides what it asks for).
  if (recountMissing_) {
    recountMissing_ = false;
    waiting_.clear();
    for (QueuedPacket& queued : queue_) countMissing(queued);
  }
  const std::uint64_t head = queue_.empty() ? 0 : queue_.front().sequence;
  if (head == pinnedSequence_) return;
  for (std::uint32_t cell : pinnedCells_) cache_.unpin(cell);
  pinnedCells_.clear();
  pinnedSequence_ = head;
  if (queue_.empty()) return;
  const QueuedPacket& first = queue_.front();
  const v1::RenderPacket& packet = first.packet;
  Requests requests;
  forEachNeedCell(packet, [&](std::uint32_t cell, int begin, int end) {
    cache_.pin(cell);
    pinnedCells_.push_back(cell);
    // What it lacks (evicted while it waited, or never asked for) is asked for.
    if (first.missing > 0 && !holdsNeeds(cell, packet, begin, end)) {
      askUnlessPending(packet, begin, end, now, requests);
    }
  });
  sendRequests(requests, packet.frame_id(), effects);
}

void RenderCore::sendRequests(Requests& requests, std::uint64_t frame, RenderEffects& effects) {
  if (requests.empty()) return;
  // Data-send must hear of an eviction before a request for the same cell,
  // or it would take the request for splats already sent.
  if (!evicted_.empty()) sendReport(effects);
  // Owners in ascending order, so the same state always sends the same messages.
  std::vector<std::uint32_t> ownersAsked;
  for (const auto& [owner, ranges] : requests) ownersAsked.push_back(owner);
  std::sort(ownersAsked.begin(), ownersAsked.end());
  for (std::uint32_t owner : ownersAsked) {
    std::vector<CellRange>& ranges = requests[owner];
    normalizeCellRanges(ranges);
    v1::SendOrder order;
    order.set_render_rank(selfRank_);
    order.set_requester_rank(selfRank_);
    order.set_order_id(++orderSequence_);
    order.set_frame_id(frame);
    addRangeFields(ranges, *order.mutable_range_top_level(), *order.mutable_range_first(),
                   *order.mutable_range_count());
    effects.messages.send(peers_.datasends.at(owner), std::move(order));
  }
}

void RenderCore::rerequestLateCells(TimePoint now, RenderEffects& effects) {
  Requests requests;
  std::uint64_t frame = 0;
  for (auto& [cell, asked] : requestedAt_) {
    if (now - asked.at > kRerequestAfter) {
      asked.at = now;
      for (const SplatSpan& span : asked.spans.spans())
        requests[owners_[cell]].push_back({cell, span.begin, span.end - span.begin});
      frame = std::max(frame, asked.frame);
    }
  }
  sendRequests(requests, frame, effects);
}

void RenderCore::evict(std::uint32_t cell, RenderEffects& effects) {
  held_[cell].clear();
  // The report lists the eviction; what is stored after it, as loaded.
  std::erase_if(loaded_, [&](const CellRange& range) { return range.cell == cell; });
  recountMissing_ = true;
  effects.released.push_back(cell);
  evicted_.push_back(cell);
  reportDirty_ = true;
}

v1::TileImageHeader RenderCore::packetDrawn(const ReadyPacket& ready, std::uint64_t splats,
                                            double seconds, TimePoint now, RenderEffects& effects) {
  const v1::RenderPacket& packet = ready.packet;
  forEachNeedCell(packet, [&](std::uint32_t cell, int, int) { cache_.touch(cell, now); });
  if (splats >= kMinDrawSampleSplats && seconds > 0.0) {
    secondsPerSplat_ = movingAverage(secondsPerSplat_, seconds / static_cast<double>(splats));
  }
  busySeconds_ += seconds;
  workload_ -= std::min(workload_, packet.total_splats());
  ++packetsDone_;
  splatsDone_ += splats;

  const auto micros = [](Clock::duration duration) {
    return std::chrono::duration_cast<std::chrono::microseconds>(duration).count();
  };
  v1::TileImageHeader header;
  header.set_frame_id(packet.frame_id());
  header.set_tile_id(packet.tile_id());
  *header.mutable_rect() = packet.rect();
  // A part of a split tile goes as the point kernel's words, to be composed.
  const bool part = packet.part_count() > 1;
  header.set_format(part ? v1::PIXEL_FORMAT_POINT_WORDS64 : v1::PIXEL_FORMAT_RGBA8);
  if (part) {
    header.set_part_index(packet.part_index());
    header.set_part_count(packet.part_count());
  }
  header.set_render_rank(selfRank_);
  header.set_splats_rendered(splats);
  header.set_render_time_us(static_cast<std::int64_t>(seconds * 1e6));
  header.set_attempt(packet.attempt());
  header.set_queued_time_us(micros(now - ready.arrived));
  header.set_data_wait_us(micros(ready.dataComplete - ready.arrived));
  header.set_workload_splats(workload_);
  header.set_cache_hits(hits_);
  header.set_cache_misses(misses_);
  header.set_cache_bytes(cache_.bytes());
  header.set_ordered_bytes(packet.ordered_bytes());
  header.set_ordered_bytes_held_elsewhere(packet.ordered_bytes_held_elsewhere());
  header.set_prefetch_bytes(packet.prefetch_bytes());
  header.set_traverse_rank(packet.traverse_rank());
  header.set_evictions(cache_.evictions());
  header.set_peak_cache_bytes(cache_.peakBytes());
  header.set_data_bytes_received(dataBytesReceived_);
  sendReport(effects);
  // The drawn packet may have been the head: its cells need no pin any more,
  // and the next head's missing cells are asked for now.
  pinHeadPacket(now, effects);
  return header;
}

// Workload and cache changes to every traverse; evictions (and dropped
// prefetches) to every data-send, which only reads those.
void RenderCore::sendReport(RenderEffects& effects) {
  reportDirty_ = false;
  v1::RenderReport report;
  report.set_render_rank(selfRank_);
  report.set_sequence(++reportSequence_);
  report.set_workload_splats(workload_);
  normalizeCellRanges(loaded_);
  addRangeFields(loaded_, *report.mutable_loaded_top_level(), *report.mutable_loaded_first(),
                 *report.mutable_loaded_count());
  for (std::uint32_t cell : evicted_) report.add_evicted_cells(cell);
  report.set_cache_bytes(cache_.bytes());
  report.set_seconds_per_splat(secondsPerSplat_);
  report.set_seconds_per_byte(secondsPerByte_);
  report.set_packets_done(packetsDone_);
  report.set_cache_hits(hits_);
  report.set_cache_misses(misses_);
  for (std::uint64_t id : lastPacketFrom_) report.add_last_packet_from_traverse(id);
  const bool evictions = !evicted_.empty();
  loaded_.clear();
  evicted_.clear();
  std::vector<int> recipients = peers_.traverses;
  if (evictions)
    recipients.insert(recipients.end(), peers_.datasends.begin(), peers_.datasends.end());
  effects.messages.send(std::move(recipients), std::move(report));
}

std::optional<TimePoint> RenderCore::nextMaintenance() const {
  std::optional<TimePoint> due;
  const auto earliest = [&due](TimePoint time) { due = due ? std::min(*due, time) : time; };
  for (const auto& [cell, asked] : requestedAt_) earliest(asked.at + kRerequestAfter);
  if (const auto oldest = cache_.oldestUse()) earliest(*oldest + config_.cacheTimeout);
  if (!due) return std::nullopt;
  // Maintenance runs on the first idle moment a period after the last one.
  const TimePoint period =
      lastMaintenance_ ? *lastMaintenance_ + kRenderMaintenancePeriod : TimePoint{};
  return std::max(*due, period) + std::chrono::microseconds(1);
}

std::string RenderCore::summary() const {
  char line[300];
  std::snprintf(line, sizeof line,
                "packets=%llu splats=%llu busy=%.3fs hits=%llu misses=%llu evictions=%llu "
                "peak_cache=%.1fMiB data_in=%.1fMiB extensions=%llu dropped_prefetches=%llu "
                "t_s=%.3gns/splat t_n=%.3gns/byte",
                static_cast<unsigned long long>(packetsDone_),
                static_cast<unsigned long long>(splatsDone_), busySeconds_,
                static_cast<unsigned long long>(hits_), static_cast<unsigned long long>(misses_),
                static_cast<unsigned long long>(cache_.evictions()),
                static_cast<double>(cache_.peakBytes()) / 1048576.0,
                static_cast<double>(dataBytesReceived_) / 1048576.0,
                static_cast<unsigned long long>(extensions_),
                static_cast<unsigned long long>(droppedPrefetches_), secondsPerSplat_ * 1e9,
                secondsPerByte_ * 1e9);
  return line;
}

void checkDataPacketHeader(const v1::DataPacketHeader& header, std::size_t payloadBytes,
                           int sourceRank) {
  const auto fail = [&](const std::string& what) {
    const std::string cell =
        header.parts_size() > 0
            ? "top-level cell " + std::to_string(header.parts(0).top_level_cell())
            : "no top-level cell";
    throw ProtocolError("data packet for " + cell + " from rank " + std::to_string(sourceRank) +
                        " with " + std::to_string(payloadBytes) + " bytes: " + what);
  };
  if (header.record_size() != sizeof(Splat)) {
    fail("records of " + std::to_string(header.record_size()) + " bytes, not " +
         std::to_string(sizeof(Splat)));
  }
  // Parts read in place come without a payload.
  const bool shared = header.has_shared();
  if (shared && payloadBytes != 0) fail("its parts are in shared memory, yet bytes follow");
  if (!shared && header.byte_size() != payloadBytes) {
    fail("its header says " + std::to_string(header.byte_size()) + " bytes");
  }
  if (header.parts_size() == 0) fail("no parts");
  // Counts past 32 bits are refused before anything is multiplied or summed.
  std::uint64_t splats = 0;
  for (const v1::DataPart& part : header.parts()) {
    if (part.splat_count() == 0 || part.splat_count() > std::numeric_limits<std::uint32_t>::max() ||
        part.first_splat() > std::numeric_limits<std::uint32_t>::max()) {
      fail("the part of top-level cell " + std::to_string(part.top_level_cell()) +
           " names splats " + std::to_string(part.first_splat()) + "+" +
           std::to_string(part.splat_count()));
    }
    if (header.has_shared_groups()) {
      const std::uint64_t size = header.shared_groups().byte_size();
      const std::uint64_t offset = part.shared_groups_offset();
      const std::uint64_t block = PointGroups::blockBytes(
          static_cast<std::size_t>(part.first_splat() + part.splat_count()));
      if (!shared || offset % PointGroups::kAlignment != 0 || offset > size ||
          block > size - offset) {
        fail("the part of top-level cell " + std::to_string(part.top_level_cell()) +
             " is drawn from byte " + std::to_string(offset) + ", not a block inside the " +
             std::to_string(size) + "-byte segment of kernel groups");
      }
    }
    if (shared) {
      const std::uint64_t size = header.shared().byte_size();
      const std::uint64_t offset = part.shared_offset();
      if (offset % alignof(Splat) != 0 || offset > size ||
          part.splat_count() * sizeof(Splat) > size - offset) {
        fail("the part of top-level cell " + std::to_string(part.top_level_cell()) +
             " lies at byte " + std::to_string(offset) + ", not inside the " +
             std::to_string(size) + "-byte shared segment");
      }
    }
    splats += part.splat_count();
  }
  if (splats * sizeof(Splat) != header.byte_size()) {
    fail("its parts hold " + std::to_string(splats) + " splats of " +
         std::to_string(sizeof(Splat)) + " bytes, not the " + std::to_string(header.byte_size()) +
         " its header says");
  }
}

}  // namespace pointillist::render
