#include "render/render_role.hpp"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <deque>
#include <map>
#include <optional>
#include <thread>
#include <unordered_map>
#include <unordered_set>

#include "common/dataset.hpp"
#include "common/mpi/role_options.hpp"
#include "common/mpi/serve.hpp"
#include "common/ownership.hpp"
#include "common/rate_estimates.hpp"
#include "render/cell_cache.hpp"
#include "render/splat_renderer.hpp"

namespace pointillist::render {
namespace {

using Clock = std::chrono::steady_clock;

struct RenderOptions {
  CommonRoleOptions common;
  std::string datasetPath;
  double cacheMegabytes = 1024.0;
  double cacheTimeoutSeconds = 30.0;
  std::string profile = "compat";
  // Test hooks: simulate a slow or stalled render process.
  double slowMillisecondsPerPacket = 0.0;
  int stallIndex = -1;  // which render process (index among renders) stalls
  long stallAfterPackets = 0;
};

class RenderProcess {
 public:
  RenderProcess(Job& job, const RenderOptions& options)
      : job_(job),
        options_(options),
        dataset_(Dataset::open(options.datasetPath, DatasetParts::TopLevel)),
        owners_(assignOwners(dataset_.topLevelCells(), job.layout().datasend)),
        cache_(static_cast<std::uint64_t>(options.cacheMegabytes * 1024.0 * 1024.0),
               std::chrono::milliseconds(static_cast<long>(options.cacheTimeoutSeconds * 1000.0))),
        context_(64, 64, parseProfile(options.profile)),
        renderer_(context_) {
    const auto& traverses = job.ranksOf(v1::ROLE_TRAVERSE);
    for (std::size_t i = 0; i < traverses.size(); ++i) traverseIndex_[traverses[i]] = i;
    lastPacketFrom_.assign(traverses.size(), 0);
  }

  std::string readyDetail() const {
    return std::string("GL ") + context_.versionString() + " on " + context_.rendererString() +
           ", cache cap " + std::to_string(cache_.capBytes() >> 20) + " MiB";
  }

  void onMessage(Envelope& envelope) {
    switch (envelope.kind) {
      case MessageKind::DataPacket:
        handleData(envelope);
        break;
      case MessageKind::RenderPacket:
        handlePacket(envelope.as<v1::RenderPacket>());
        break;
      default:
        throw ProtocolError(std::string("render got an unexpected ") +
                            messageKindName(envelope.kind) + " from rank " +
                            std::to_string(envelope.source));
    }
  }

  // Renders one ready packet, expires old cells, re-requests late data.
  bool onIdle() {
    reapSends();
    const auto now = Clock::now();
    if (now - lastMaintenance_ > std::chrono::milliseconds(250)) {
      lastMaintenance_ = now;
      for (std::uint32_t cell : cache_.expire(now)) evict(cell);
      rerequestLateCells(now);
    }
    pinHeadPacket();
    bool worked = false;
    if (!stalled()) {
      for (auto it = queue_.begin(); it != queue_.end(); ++it) {
        if (ready(*it)) {
          QueuedPacket packet = std::move(*it);
          queue_.erase(it);
          renderPacket(packet);
          worked = true;
          break;
        }
      }
    }
    if (reportDirty_) sendReports();
    return worked;
  }

  bool sendsPending() const { return !sends_.empty(); }

  std::string summary() const {
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

 private:
  struct QueuedPacket {
    v1::RenderPacket packet;
    Clock::time_point arrived;
    std::optional<Clock::time_point> dataComplete;  // when every cell was first present
    std::uint64_t sequence = 0;
  };

  // Only the oldest queued packet holds its cells in the cache: pinning every
  // queued packet could hold more than the memory cap. Cells of later packets
  // may be evicted and are asked for again when their packet comes first.
  void pinHeadPacket() {
    const std::uint64_t head = queue_.empty() ? 0 : queue_.front().sequence;
    if (head == pinnedSequence_) return;
    for (std::uint32_t cell : pinnedCells_) cache_.unpin(cell);
    pinnedCells_.clear();
    pinnedSequence_ = head;
    if (queue_.empty()) return;
    std::map<std::uint32_t, v1::SendOrder> requests;
    const auto now = Clock::now();
    for (std::uint32_t cell : queue_.front().packet.top_level_cells()) {
      cache_.pin(cell);
      pinnedCells_.push_back(cell);
      if (!cache_.contains(cell) && !requestedAt_.contains(cell)) {
        requestedAt_[cell] = now;
        requests[owners_[cell]].add_top_level_cells(cell);
      }
    }
    sendRequests(requests);
  }

  bool stalled() const {
    return options_.stallIndex == job_.indexInRole() &&
           packetsDone_ >= static_cast<std::uint64_t>(std::max(0L, options_.stallAfterPackets));
  }

  bool ready(const QueuedPacket& queued) const {
    for (std::uint32_t cell : queued.packet.top_level_cells()) {
      if (!cache_.contains(cell)) return false;
    }
    return true;
  }

  // Stamps the packets whose data has just become complete (for data_wait_us).
  void stampReadyPackets(Clock::time_point now) {
    for (QueuedPacket& queued : queue_) {
      if (!queued.dataComplete && ready(queued)) queued.dataComplete = now;
    }
  }

  void handleData(const Envelope& envelope) {
    const auto header = envelope.as<v1::DataPacketHeader>();
    const std::uint32_t cell = header.top_level_cell();
    const auto& table = dataset_.topLevelCells();
    if (cell >= table.size() || header.byte_size() != envelope.payload.size() ||
        header.byte_size() != table[cell].byteSize || header.record_size() != sizeof(Splat)) {
      throw ProtocolError("data packet for top-level cell " + std::to_string(cell) + " from rank " +
                          std::to_string(envelope.source) + " has " +
                          std::to_string(envelope.payload.size()) +
                          " bytes, which does not match the dataset's table");
    }
    if (fnv1a64(envelope.payload.data(), envelope.payload.size()) != header.checksum() ||
        header.checksum() != dataset_.packetChecksum(cell)) {
      throw ProtocolError("data packet for top-level cell " + std::to_string(cell) + " from rank " +
                          std::to_string(envelope.source) + " fails its checksum");
    }
    dataBytesReceived_ += envelope.payload.size();
    const auto now = Clock::now();
    // T_n: the measured transfer time of the payload per byte.
    if (envelope.payload.size() >= 4096 && envelope.payloadSeconds > 0.0) {
      transferSamples_.add(envelope.payloadSeconds / static_cast<double>(envelope.payload.size()));
      secondsPerByte_ = transferSamples_.lowerQuartile();
    }
    requestedAt_.erase(cell);
    if (cache_.contains(cell)) return;  // already here (a late duplicate)
    if (!cache_.pinned(cell) && !cache_.canFit(envelope.payload.size())) {
      // Prefetched data that cannot fit beside the packet being waited for:
      // drop it and say so, so it is sent again when it is needed.
      ++droppedPrefetches_;
      evicted_.push_back(cell);
      reportDirty_ = true;
      return;
    }
    for (std::uint32_t victim : cache_.insert(cell, envelope.payload.size(), now)) evict(victim);
    const std::span<const Splat> splats(reinterpret_cast<const Splat*>(envelope.payload.data()),
                                        envelope.payload.size() / sizeof(Splat));
    renderer_.uploadCell(cell, splats);
    stampReadyPackets(Clock::now());
    loaded_.push_back(cell);
    reportDirty_ = true;
  }

  void handlePacket(v1::RenderPacket packet) {
    const auto found = traverseIndex_.find(packet.traverse_rank());
    if (found != traverseIndex_.end()) {
      lastPacketFrom_[found->second] = std::max(lastPacketFrom_[found->second], packet.packet_id());
    }
    const auto now = Clock::now();
    std::map<std::uint32_t, v1::SendOrder> requests;
    for (std::uint32_t cell : packet.top_level_cells()) {
      if (cell >= owners_.size()) {
        throw ProtocolError("render packet names top-level cell " + std::to_string(cell) +
                            " beyond the dataset's " + std::to_string(owners_.size()));
      }
      if (cache_.contains(cell)) {
        ++hits_;
        cache_.touch(cell, now);
        continue;
      }
      ++misses_;
      // The traverse ordered it already; asking too covers a cell evicted after
      // the traverse last heard from us (data-send drops the duplicate).
      if (!requestedAt_.contains(cell)) {
        requestedAt_[cell] = now;
        requests[owners_[cell]].add_top_level_cells(cell);
      }
    }
    sendRequests(requests);
    workload_ += packet.total_splats();
    queue_.push_back({std::move(packet), now, std::nullopt, ++packetsQueued_});
    if (ready(queue_.back())) queue_.back().dataComplete = now;
    reportDirty_ = true;
  }

  void sendRequests(std::map<std::uint32_t, v1::SendOrder>& requests) {
    if (requests.empty()) return;
    // Data-send must hear of an eviction before a request for the same cell,
    // or it would drop the request as a duplicate.
    if (!evicted_.empty()) sendReports();
    const auto& datasends = job_.ranksOf(v1::ROLE_DATASEND);
    for (auto& [owner, order] : requests) {
      order.set_render_rank(job_.worldRank());
      order.set_traverse_rank(job_.worldRank());
      sends_.push_back(job_.channel().post(datasends.at(owner), MessageKind::SendOrder, order));
    }
  }

  void rerequestLateCells(Clock::time_point now) {
    std::map<std::uint32_t, v1::SendOrder> requests;
    for (auto& [cell, when] : requestedAt_) {
      if (now - when > std::chrono::seconds(1)) {
        when = now;
        requests[owners_[cell]].add_top_level_cells(cell);
      }
    }
    sendRequests(requests);
  }

  void evict(std::uint32_t cell) {
    renderer_.releaseCell(cell);
    evicted_.push_back(cell);
    reportDirty_ = true;
  }

  void renderPacket(QueuedPacket& queued) {
    const v1::RenderPacket& packet = queued.packet;
    std::vector<DrawRange> ranges;
    ranges.reserve(static_cast<std::size_t>(packet.range_count_size()));
    for (int i = 0; i < packet.range_count_size(); ++i) {
      ranges.push_back({packet.range_top_level(i), packet.range_offset(i), packet.range_count(i)});
    }
    RenderSettings settings;
    settings.mode = splatModeFromProto(
        packet.mode() == v1::RENDER_MODE_UNSPECIFIED ? v1::RENDER_MODE_POINTS : packet.mode());
    settings.sizeScale = packet.point_size_scale() > 0.0f ? packet.point_size_scale() : 1.0f;
    if (options_.slowMillisecondsPerPacket > 0.0) {
      std::this_thread::sleep_for(
          std::chrono::duration<double, std::milli>(options_.slowMillisecondsPerPacket));
    }
    const RenderStats stats = renderer_.render(packet.camera(), packet.rect(), ranges, settings);
    const auto now = Clock::now();
    for (std::uint32_t cell : packet.top_level_cells()) cache_.touch(cell, now);
    if (stats.splats >= 1000 && stats.seconds > 0.0) {
      secondsPerSplat_ =
          movingAverage(secondsPerSplat_, stats.seconds / static_cast<double>(stats.splats));
    }
    busySeconds_ += stats.seconds;
    workload_ -= std::min(workload_, packet.total_splats());
    ++packetsDone_;
    splatsDone_ += stats.splats;

    v1::TileImageHeader header;
    header.set_frame_id(packet.frame_id());
    header.set_tile_id(packet.tile_id());
    *header.mutable_rect() = packet.rect();
    header.set_format(v1::PIXEL_FORMAT_RGBA8);
    header.set_render_rank(job_.worldRank());
    header.set_splats_rendered(stats.splats);
    header.set_render_time_us(static_cast<std::int64_t>(stats.seconds * 1e6));
    header.set_attempt(packet.attempt());
    header.set_queued_time_us(
        std::chrono::duration_cast<std::chrono::microseconds>(now - queued.arrived).count());
    header.set_data_wait_us(std::chrono::duration_cast<std::chrono::microseconds>(
                                queued.dataComplete.value_or(queued.arrived) - queued.arrived)
                                .count());
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
    const auto pixels = context_.pixels();
    auto payload = std::make_shared<std::vector<std::byte>>(
        reinterpret_cast<const std::byte*>(pixels.data()),
        reinterpret_cast<const std::byte*>(pixels.data()) + pixels.size());
    sends_.push_back(job_.channel().post(job_.displayRank(), MessageKind::TileImage, header,
                                         std::shared_ptr<const std::vector<std::byte>>(payload)));
    reportDirty_ = true;
  }

  // Workload and cache changes to every traverse and data-send process.
  void sendReports() {
    reportDirty_ = false;
    v1::RenderReport report;
    report.set_render_rank(job_.worldRank());
    report.set_sequence(++reportSequence_);
    report.set_workload_splats(workload_);
    for (std::uint32_t cell : loaded_) report.add_loaded_cells(cell);
    for (std::uint32_t cell : evicted_) report.add_evicted_cells(cell);
    report.set_cache_bytes(cache_.bytes());
    report.set_seconds_per_splat(secondsPerSplat_);
    report.set_seconds_per_byte(secondsPerByte_);
    report.set_timestamp_ns(
        std::chrono::duration_cast<std::chrono::nanoseconds>(Clock::now().time_since_epoch())
            .count());
    report.set_packets_done(packetsDone_);
    report.set_cache_hits(hits_);
    report.set_cache_misses(misses_);
    loaded_.clear();
    evicted_.clear();
    const auto& traverses = job_.ranksOf(v1::ROLE_TRAVERSE);
    for (std::size_t i = 0; i < traverses.size(); ++i) {
      report.set_last_packet_from_recipient(lastPacketFrom_[i]);
      sends_.push_back(job_.channel().post(traverses[i], MessageKind::RenderReport, report));
    }
    report.clear_last_packet_from_recipient();
    for (int rank : job_.ranksOf(v1::ROLE_DATASEND)) {
      sends_.push_back(job_.channel().post(rank, MessageKind::RenderReport, report));
    }
  }

  void reapSends() {
    while (!sends_.empty() && sends_.front().test()) sends_.pop_front();
  }

  Job& job_;
  RenderOptions options_;
  Dataset dataset_;
  std::vector<std::uint32_t> owners_;
  CellCache cache_;
  OffscreenContext context_;
  SplatRenderer renderer_;
  std::map<int, std::size_t> traverseIndex_;
  std::vector<std::uint64_t> lastPacketFrom_;
  std::deque<QueuedPacket> queue_;
  std::uint64_t packetsQueued_ = 0;
  std::uint64_t pinnedSequence_ = 0;
  std::vector<std::uint32_t> pinnedCells_;
  std::unordered_map<std::uint32_t, Clock::time_point> requestedAt_;
  std::vector<std::uint32_t> loaded_;
  std::vector<std::uint32_t> evicted_;
  std::deque<SendHandle> sends_;
  Clock::time_point lastMaintenance_ = Clock::now();
  bool reportDirty_ = true;
  std::uint64_t reportSequence_ = 0;
  std::uint64_t workload_ = 0;
  std::uint64_t packetsDone_ = 0;
  std::uint64_t splatsDone_ = 0;
  std::uint64_t hits_ = 0;
  std::uint64_t misses_ = 0;
  std::uint64_t dataBytesReceived_ = 0;
  std::uint64_t droppedPrefetches_ = 0;
  double busySeconds_ = 0.0;
  double secondsPerSplat_ = 0.0;
  double secondsPerByte_ = 0.0;
  RecentSamples transferSamples_{32};  // T_n: their lower quartile
};

}  // namespace

int runRenderRole(Job& job, int argc, char** argv) {
  CLI::App app{"Pointillist render process (started by deploy/run.sh)"};
  RenderOptions options;
  addCommonRoleOptions(app, options.common);
  app.add_option("--dataset", options.datasetPath,
                 "Dataset directory (the render reads only its top-level table)");
  app.add_option("--cache-mb", options.cacheMegabytes, "Memory cap of the top-level cell cache")
      ->check(CLI::PositiveNumber);
  app.add_option("--cache-timeout", options.cacheTimeoutSeconds,
                 "Seconds after which an unused cell is dropped")
      ->check(CLI::PositiveNumber);
  app.add_option("--gl-profile", options.profile, "OSMesa context profile: compat or core");
  app.add_option("--slow-ms", options.slowMillisecondsPerPacket)->group("");
  app.add_option("--stall-index", options.stallIndex)->group("");
  app.add_option("--stall-after", options.stallAfterPackets)->group("");
  if (!parseRoleOptions(app, job, argc, argv)) return 0;

  if (options.datasetPath.empty()) {  // a handshake-only job
    runWorkerRole(job, handshakeOptions(options.common), "no dataset", ServeHandlers{});
    return 0;
  }
  RenderProcess process(job, options);
  const ServeHandlers handlers = handlersFor(process);
  runWorkerRole(job, handshakeOptions(options.common), process.readyDetail(), handlers);
  return 0;
}

}  // namespace pointillist::render
