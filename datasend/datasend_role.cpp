#include "datasend/datasend_role.hpp"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <map>
#include <memory>

#include "common/checksum.hpp"
#include "common/dataset.hpp"
#include "common/mpi/worker.hpp"
#include "common/ownership.hpp"
#include "common/point_groups.hpp"
#include "common/run_settings.hpp"
#include "common/shared_packets.hpp"
#include "datasend/core/send_ledger.hpp"

namespace pointillist::datasend {
namespace {

class DataSendProcess final : public WorkerProcess {
 public:
  DataSendProcess(Job& job, const std::string& datasetPath)
      : job_(job),
        dataset_(Dataset::open(datasetPath, DatasetParts::TopLevel)),
        ledger_(job.peers(),
                assignPacketOwners(dataset_.topLevelCells(), job.layout().datasend,
                                   dataset_.packetCount()),
                static_cast<std::uint32_t>(job.indexInRole())) {
    // Hold only the packets this process owns (seed 003: no process needs all
    // data); a statistical packet goes with its top-level cell's. They live
    // in one shared segment, which render processes of this machine read in
    // place (common/shared_packets.hpp).
    const auto start = std::chrono::steady_clock::now();
    std::uint64_t splats = 0;
    for (std::uint32_t cell = 0; cell < dataset_.packetCount(); ++cell) {
      if (ledger_.owns(cell)) splats += dataset_.packetSplats(cell);
    }
    segment_ = std::make_shared<SharedSegment>(
        splats * sizeof(Splat), "pointillist-packets-" + std::to_string(job.worldRank()));
    auto* records = reinterpret_cast<Splat*>(segment_->data());
    packets_.resize(dataset_.packetCount());
    std::uint64_t at = 0;
    for (std::uint32_t cell = 0; cell < dataset_.packetCount(); ++cell) {
      if (!ledger_.owns(cell)) continue;
      const std::span<Splat> packet(records + at,
                                    static_cast<std::size_t>(dataset_.packetSplats(cell)));
      dataset_.readTopLevelInto(cell, packet);
      packets_[cell] = packet;
      ++packetsOwned_;
      at += packet.size();
    }
    bytesHeld_ = at * sizeof(Splat);
    loadSeconds_ = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  }

  std::string readyDetail() const override {
    char line[240];
    int length = std::snprintf(
        line, sizeof line, "owns %zu of %u packets, %.1f MiB, loaded in %.2f s", packetsOwned_,
        dataset_.packetCount(), static_cast<double>(bytesHeld_) / (1024.0 * 1024.0), loadSeconds_);
    if (groups_ && length > 0 && static_cast<std::size_t>(length) < sizeof line) {
      std::snprintf(line + length, sizeof line - static_cast<std::size_t>(length),
                    "; %.1f MiB laid out for the cpu kernel in %.2f s",
                    static_cast<double>(groups_->size()) / (1024.0 * 1024.0), groupSeconds_);
    }
    return line;
  }

  void begin(const v1::RunSettings& settings) override {
    sharedPackets_ = !settings.no_shared_packets();
    const auto& renders = job_.ranksOf(v1::ROLE_RENDER);
    const bool neighbours = std::any_of(renders.begin(), renders.end(),
                                        [&](int rank) { return job_.onThisMachine(rank); });
    // Render processes of this machine that draw the run's frames with the
    // CPU kernel draw these packets in place, from the kernel's layout: no
    // copy into a cell of their own, and no fresh memory to fault in for it.
    // (A served frame of another mode than the run's still draws, from copies.)
    const bool kernel = resolveRenderer(settings.renderer(), settings.mode()) == v1::RENDERER_CPU;
    if (sharedPackets_ && neighbours && kernel) layOutGroups();
  }

  void onMessage(Envelope& envelope) override {
    switch (envelope.kind) {
      case MessageKind::SendOrder:
        send(envelope.as<v1::SendOrder>());
        break;
      case MessageKind::RenderReport:
        ledger_.applyReport(envelope.source, envelope.as<v1::RenderReport>());
        break;
      default:
        throw ProtocolError(std::string("data-send got an unexpected ") +
                            messageKindName(envelope.kind) + " from rank " +
                            std::to_string(envelope.source));
    }
  }

  std::string summary() const override {
    char line[320];
    std::snprintf(line, sizeof line,
                  "data_packets=%llu shared_in_place=%llu parts_sent=%llu extensions=%llu "
                  "bytes_sent=%llu bytes_in_place=%llu duplicates_skipped=%llu",
                  static_cast<unsigned long long>(messagesSent_),
                  static_cast<unsigned long long>(sharedMessages_),
                  static_cast<unsigned long long>(packetsSent_),
                  static_cast<unsigned long long>(extensionsSent_),
                  static_cast<unsigned long long>(bytesSent_),
                  static_cast<unsigned long long>(bytesInPlace_),
                  static_cast<unsigned long long>(ledger_.duplicatesSkipped()));
    return line;
  }

 private:
  void send(const v1::SendOrder& order) {
    const std::vector<CellRange> ranges = ledger_.rangesToSend(order);
    for (const CellRange& range : ranges) {
      if (range.end() > packets_.at(range.cell).size()) {
        throw ProtocolError("rank " + std::to_string(order.requester_rank()) + " ordered splats " +
                            std::to_string(range.first) + "+" + std::to_string(range.count) +
                            " of top-level cell " + std::to_string(range.cell) + ", which holds " +
                            std::to_string(packets_[range.cell].size()));
      }
    }
    for (const std::span<const CellRange> group : dataPacketGroups(ranges)) {
      sendGroup(order.render_rank(), group);
    }
  }

  // Every packet held, also in the CPU kernel's layout, in a second segment
  // (its padding stays zero, as a new memory file is).
  void layOutGroups() {
    const auto start = std::chrono::steady_clock::now();
    std::uint64_t bytes = 0;
    for (std::uint32_t cell = 0; cell < packets_.size(); ++cell) {
      if (ledger_.owns(cell)) bytes += PointGroups::blockBytes(packets_[cell].size());
    }
    groups_ = std::make_shared<SharedSegment>(
        bytes, "pointillist-point-groups-" + std::to_string(job_.worldRank()));
    std::uint64_t at = 0;
    groupsAt_.resize(packets_.size());
    for (std::uint32_t cell = 0; cell < packets_.size(); ++cell) {
      if (!ledger_.owns(cell)) continue;
      const std::span<const Splat> splats = packets_[cell];
      auto* values = reinterpret_cast<float*>(groups_->data() + at);
      groupsAt_[cell] = GroupsPlace{at, writePointGroups(splats, 0, values)};
      at += PointGroups::blockBytes(splats.size());
    }
    groupSeconds_ = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  }

  static void name(const SharedSegmentId& id, v1::SharedSegment& named) {
    named.set_pid(id.pid);
    named.set_fd(id.fd);
    named.set_inode(id.inode);
    named.set_byte_size(id.byteSize);
  }

  // One data packet. To a render process of this machine it names where the
  // parts lie in the shared segment; otherwise a single range goes straight
  // from the held packet, and more are copied back to back into one payload.
  void sendGroup(int renderRank, std::span<const CellRange> group) {
    const bool shared = sharedPackets_ && job_.onThisMachine(renderRank);
    v1::DataPacketHeader header;
    header.set_record_size(sizeof(Splat));
    header.set_datasend_rank(job_.worldRank());
    if (shared) {
      name(segment_->id(), *header.mutable_shared());
      if (groups_) name(groups_->id(), *header.mutable_shared_groups());
    }
    std::uint64_t total = 0;
    header.mutable_parts()->Reserve(static_cast<int>(group.size()));
    for (const CellRange& range : group) {
      const std::span<const Splat> packet = packets_[range.cell];
      const std::span<const Splat> splats = packet.subspan(range.first, range.count);
      v1::DataPart& part = *header.add_parts();
      part.set_top_level_cell(range.cell);
      part.set_first_splat(range.first);
      part.set_splat_count(range.count);
      if (shared) {
        part.set_shared_offset(static_cast<std::uint64_t>(
            reinterpret_cast<const std::byte*>(splats.data()) - segment_->data()));
        if (groups_) {
          const GroupsPlace& place = groupsAt_[range.cell];
          part.set_shared_groups_offset(place.offset);
          part.set_shared_has_normals(place.hasNormals);
        }
      } else {
        // The whole packet's checksum was verified at load; a part gets its own.
        part.set_checksum(range.first == 0 && range.count == packet.size()
                              ? dataset_.packetChecksum(range.cell)
                              : checksum64(splats.data(), splats.size_bytes()));
      }
      total += splats.size_bytes();
      ++packetsSent_;
      if (range.first > 0) ++extensionsSent_;
    }
    header.set_byte_size(total);
    bytesSent_ += total;
    ++messagesSent_;
    if (shared) {
      ++sharedMessages_;
      bytesInPlace_ += total;
      job_.sends().post(renderRank, MessageKind::DataPacket, header);
      return;
    }
    if (group.size() == 1) {
      const CellRange& range = group.front();
      const std::span<const Splat> splats =
          packets_.at(range.cell).subspan(range.first, range.count);
      job_.sends().post(renderRank, MessageKind::DataPacket, header, std::as_bytes(splats),
                        segment_);
      return;
    }
    auto payload = std::make_shared<std::vector<std::byte>>(total);
    std::byte* out = payload->data();
    for (const CellRange& range : group) {
      const std::span<const Splat> splats =
          packets_.at(range.cell).subspan(range.first, range.count);
      std::memcpy(out, splats.data(), splats.size_bytes());
      out += splats.size_bytes();
    }
    const std::span<const std::byte> bytes(*payload);
    job_.sends().post(renderRank, MessageKind::DataPacket, header, bytes, std::move(payload));
  }

  Job& job_;
  Dataset dataset_;
  SendLedger ledger_;
  std::shared_ptr<SharedSegment> segment_;  // every packet held, back to back
  struct GroupsPlace {
    std::uint64_t offset = 0;  // of the packet's block in groups_
    bool hasNormals = false;
  };
  std::shared_ptr<SharedSegment> groups_;  // the same in the CPU kernel's layout, or none
  std::vector<GroupsPlace> groupsAt_;      // by cell, for the cells owned
  double groupSeconds_ = 0.0;
  std::vector<std::span<const Splat>> packets_;  // by cell: empty for cells not owned
  std::size_t packetsOwned_ = 0;
  bool sharedPackets_ = true;
  std::uint64_t sharedMessages_ = 0;  // data packets sent as places in segment_
  std::uint64_t bytesInPlace_ = 0;    // of bytesSent_, in those: read in place, not copied
  std::uint64_t bytesHeld_ = 0;
  double loadSeconds_ = 0.0;
  std::uint64_t messagesSent_ = 0;
  std::uint64_t packetsSent_ = 0;  // parts: ranges of cells
  std::uint64_t extensionsSent_ = 0;
  std::uint64_t bytesSent_ = 0;
};

}  // namespace

int runDatasendMain(int argc, char** argv) {
  return runWorkerMain(argc, argv, v1::ROLE_DATASEND,
                       "Pointillist data-send process (started by deploy/run.sh)", {},
                       [](Job& job, const std::string& datasetPath) {
                         return std::make_unique<DataSendProcess>(job, datasetPath);
                       });
}

}  // namespace pointillist::datasend
