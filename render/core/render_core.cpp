#include "render/core/render_core.hpp"

#include <algorithm>
#include <cstdio>

namespace pointillist::render {

RenderCore::RenderCore(const RenderCoreConfig& config, PeerRanks peers, int selfRank,
                       std::span<const TopLevelCell> topLevel, std::vector<std::uint32_t> owners)
    : config_(config),
      peers_(std::move(peers)),
      selfRank_(selfRank),
      owners_(std::move(owners)),
      cache_(config.cacheCapBytes, config.cacheTimeout),
      lastPacketFrom_(peers_.traverses.size(), 0) {
  cellBytes_.reserve(topLevel.size());
  for (const TopLevelCell& cell : topLevel) cellBytes_.push_back(cell.byteSize);
  if (owners_.size() != cellBytes_.size()) {
    throw UsageError("render core: " + std::to_string(owners_.size()) + " owners for " +
                     std::to_string(cellBytes_.size()) + " top-level cells");
  }
}

bool RenderCore::stalled() const {
  return config_.stallAfterPackets && packetsDone_ >= *config_.stallAfterPackets;
}

bool RenderCore::ready(const v1::RenderPacket& packet) const {
  return std::all_of(packet.top_level_cells().begin(), packet.top_level_cells().end(),
                     [this](std::uint32_t cell) { return cache_.contains(cell); });
}

void RenderCore::ask(std::uint32_t cell, std::uint64_t frame, TimePoint now, Requests& requests) {
  requests[owners_[cell]].push_back(cell);
  requestedAt_[cell] = {now, frame};
}

void RenderCore::receivePacket(int sourceRank, v1::RenderPacket packet, TimePoint now,
                               RenderEffects& effects) {
  const std::size_t traverse = peers_.indexOf(v1::ROLE_TRAVERSE, sourceRank);
  lastPacketFrom_[traverse] = std::max(lastPacketFrom_[traverse], packet.packet_id());
  Requests requests;
  for (std::uint32_t cell : packet.top_level_cells()) {
    if (cell >= cellBytes_.size()) {
      throw ProtocolError("render packet from rank " + std::to_string(sourceRank) +
                          " names top-level cell " + std::to_string(cell) +
                          " beyond the dataset's " + std::to_string(cellBytes_.size()));
    }
    if (cache_.contains(cell)) {
      ++hits_;
      cache_.touch(cell, now);
      continue;
    }
    ++misses_;
    if (!requestedAt_.contains(cell)) ask(cell, packet.frame_id(), now, requests);
  }
  sendRequests(requests, packet.frame_id(), effects);
  workload_ += packet.total_splats();
  QueuedPacket& queued = queue_.emplace_back();
  queued.arrived = now;
  queued.sequence = ++packetsQueued_;
  if (ready(packet)) queued.dataComplete = now;
  queued.packet = std::move(packet);
  reportDirty_ = true;
}

DataVerdict RenderCore::receiveData(std::uint32_t cell, std::uint64_t bytes, double transferSeconds,
                                    TimePoint now, RenderEffects& effects) {
  if (cell >= cellBytes_.size() || bytes != cellBytes_[cell]) {
    throw ProtocolError("data for top-level cell " + std::to_string(cell) + " has " +
                        std::to_string(bytes) + " bytes, which does not match the dataset's table");
  }
  dataBytesReceived_ += bytes;
  // T_n: the measured transfer time of the payload per byte.
  if (bytes >= kMinTransferSampleBytes && transferSeconds > 0.0) {
    transferSamples_.add(transferSeconds / static_cast<double>(bytes));
    secondsPerByte_ = transferSamples_.lowerQuartile();
  }
  requestedAt_.erase(cell);
  if (cache_.contains(cell)) return DataVerdict::Duplicate;
  if (!cache_.pinned(cell) && !cache_.canFit(bytes)) {
    // Prefetched data that cannot fit beside the packet being waited for:
    // drop it and say so, so that it is sent again when it is needed.
    ++droppedPrefetches_;
    evicted_.push_back(cell);
    reportDirty_ = true;
    return DataVerdict::Dropped;
  }
  for (std::uint32_t victim : cache_.insert(cell, bytes, now)) evict(victim, effects);
  for (QueuedPacket& queued : queue_) {
    if (!queued.dataComplete && ready(queued.packet)) queued.dataComplete = now;
  }
  loaded_.push_back(cell);
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
      if (!ready(it->packet)) continue;
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
  const std::uint64_t head = queue_.empty() ? 0 : queue_.front().sequence;
  if (head == pinnedSequence_) return;
  for (std::uint32_t cell : pinnedCells_) cache_.unpin(cell);
  pinnedCells_.clear();
  pinnedSequence_ = head;
  if (queue_.empty()) return;
  const v1::RenderPacket& packet = queue_.front().packet;
  Requests requests;
  for (std::uint32_t cell : packet.top_level_cells()) {
    cache_.pin(cell);
    pinnedCells_.push_back(cell);
    if (!cache_.contains(cell) && !requestedAt_.contains(cell)) {
      ask(cell, packet.frame_id(), now, requests);
    }
  }
  sendRequests(requests, packet.frame_id(), effects);
}

void RenderCore::sendRequests(Requests& requests, std::uint64_t frame, RenderEffects& effects) {
  if (requests.empty()) return;
  // Data-send must hear of an eviction before a request for the same cell,
  // or it would drop the request as a duplicate.
  if (!evicted_.empty()) sendReport(effects);
  // Owners in ascending order, so the same state always sends the same messages.
  std::vector<std::uint32_t> ownersAsked;
  for (const auto& [owner, cells] : requests) ownersAsked.push_back(owner);
  std::sort(ownersAsked.begin(), ownersAsked.end());
  for (std::uint32_t owner : ownersAsked) {
    std::vector<std::uint32_t>& cells = requests[owner];
    std::sort(cells.begin(), cells.end());
    v1::SendOrder order;
    order.set_render_rank(selfRank_);
    order.set_requester_rank(selfRank_);
    order.set_order_id(++orderSequence_);
    order.set_frame_id(frame);
    for (std::uint32_t cell : cells) order.add_top_level_cells(cell);
    effects.messages.send(peers_.datasends.at(owner), std::move(order));
  }
}

void RenderCore::rerequestLateCells(TimePoint now, RenderEffects& effects) {
  Requests requests;
  std::uint64_t frame = 0;
  for (auto& [cell, asked] : requestedAt_) {
    if (now - asked.first > kRerequestAfter) {
      asked.first = now;
      requests[owners_[cell]].push_back(cell);
      frame = std::max(frame, asked.second);
    }
  }
  sendRequests(requests, frame, effects);
}

void RenderCore::evict(std::uint32_t cell, RenderEffects& effects) {
  effects.released.push_back(cell);
  evicted_.push_back(cell);
  reportDirty_ = true;
}

v1::TileImageHeader RenderCore::packetDrawn(const ReadyPacket& ready, std::uint64_t splats,
                                            double seconds, TimePoint now, RenderEffects& effects) {
  const v1::RenderPacket& packet = ready.packet;
  for (std::uint32_t cell : packet.top_level_cells()) cache_.touch(cell, now);
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
  header.set_format(v1::PIXEL_FORMAT_RGBA8);
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
  for (std::uint32_t cell : loaded_) report.add_loaded_cells(cell);
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
  for (const auto& [cell, asked] : requestedAt_) earliest(asked.first + kRerequestAfter);
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
                "peak_cache=%.1fMiB data_in=%.1fMiB dropped_prefetches=%llu",
                static_cast<unsigned long long>(packetsDone_),
                static_cast<unsigned long long>(splatsDone_), busySeconds_,
                static_cast<unsigned long long>(hits_), static_cast<unsigned long long>(misses_),
                static_cast<unsigned long long>(cache_.evictions()),
                static_cast<double>(cache_.peakBytes()) / 1048576.0,
                static_cast<double>(dataBytesReceived_) / 1048576.0,
                static_cast<unsigned long long>(droppedPrefetches_));
  return line;
}

}  // namespace pointillist::render
