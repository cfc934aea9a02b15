#include "datasend/datasend_role.hpp"

#include <chrono>
#include <cstdio>
#include <deque>
#include <map>
#include <unordered_set>

#include "common/dataset.hpp"
#include "common/mpi/role_options.hpp"
#include "common/mpi/serve.hpp"
#include "common/ownership.hpp"

namespace pointillist::datasend {
namespace {

class DataSendProcess {
 public:
  DataSendProcess(Job& job, const std::string& datasetPath)
      : job_(job), dataset_(Dataset::open(datasetPath, DatasetParts::TopLevel)) {
    owners_ = assignOwners(dataset_.topLevelCells(), job.layout().datasend);
    const auto me = static_cast<std::uint32_t>(job.indexInRole());
    // Hold only the cells this process owns (seed 003: no process needs all data).
    const auto start = std::chrono::steady_clock::now();
    for (std::uint32_t cell = 0; cell < owners_.size(); ++cell) {
      if (owners_[cell] != me) continue;
      auto splats = std::make_shared<std::vector<Splat>>(dataset_.readTopLevel(cell));
      bytesHeld_ += splats->size() * sizeof(Splat);
      packets_.emplace(cell, std::move(splats));
    }
    loadSeconds_ = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    const auto& renders = job.ranksOf(v1::ROLE_RENDER);
    for (std::size_t i = 0; i < renders.size(); ++i) renderIndex_[renders[i]] = i;
    sentTo_.resize(renders.size());
  }

  std::string readyDetail() const {
    char line[160];
    std::snprintf(line, sizeof line, "owns %zu of %zu top-level cells, %.1f MiB, loaded in %.2f s",
                  packets_.size(), owners_.size(),
                  static_cast<double>(bytesHeld_) / (1024.0 * 1024.0), loadSeconds_);
    return line;
  }

  void onMessage(Envelope& envelope) {
    switch (envelope.kind) {
      case MessageKind::SendOrder:
        handleOrder(envelope.as<v1::SendOrder>());
        break;
      case MessageKind::RenderReport: {
        const auto report = envelope.as<v1::RenderReport>();
        auto& sent = sentTo_.at(renderSlot(envelope.source));
        // An evicted cell must be sent again when it is next ordered.
        for (std::uint32_t cell : report.evicted_cells()) sent.erase(cell);
        break;
      }
      default:
        throw ProtocolError(std::string("data-send got an unexpected ") +
                            messageKindName(envelope.kind) + " from rank " +
                            std::to_string(envelope.source));
    }
  }

  bool sendsPending() const { return !sends_.empty(); }

  // Frees finished sends; nothing else to do between messages.
  bool onIdle() {
    while (!sends_.empty() && sends_.front().test()) sends_.pop_front();
    return false;
  }

  std::string summary() const {
    char line[200];
    std::snprintf(line, sizeof line, "packets_sent=%llu bytes_sent=%llu duplicates_skipped=%llu",
                  static_cast<unsigned long long>(packetsSent_),
                  static_cast<unsigned long long>(bytesSent_),
                  static_cast<unsigned long long>(duplicatesSkipped_));
    return line;
  }

 private:
  std::size_t renderSlot(int rank) const {
    const auto found = renderIndex_.find(rank);
    if (found == renderIndex_.end()) {
      throw ProtocolError("rank " + std::to_string(rank) + " is not a render process");
    }
    return found->second;
  }

  void handleOrder(const v1::SendOrder& order) {
    const std::size_t slot = renderSlot(order.render_rank());
    for (std::uint32_t cell : order.top_level_cells()) {
      const auto found = packets_.find(cell);
      if (found == packets_.end()) {
        throw ProtocolError("rank " + std::to_string(order.traverse_rank()) +
                            " ordered top-level cell " + std::to_string(cell) +
                            ", which this data-send process does not own");
      }
      // Never the same cell to the same render twice while it is there or on its way.
      if (!sentTo_[slot].insert(cell).second) {
        ++duplicatesSkipped_;
        continue;
      }
      const auto& splats = *found->second;
      v1::DataPacketHeader header;
      header.set_top_level_cell(cell);
      header.set_splat_count(splats.size());
      header.set_byte_size(splats.size() * sizeof(Splat));
      header.set_record_size(sizeof(Splat));
      header.set_checksum(dataset_.packetChecksum(cell));
      header.set_datasend_rank(job_.worldRank());
      const std::span<const std::byte> bytes(reinterpret_cast<const std::byte*>(splats.data()),
                                             splats.size() * sizeof(Splat));
      sends_.push_back(
          job_.channel().post(order.render_rank(), MessageKind::DataPacket, header, bytes));
      ++packetsSent_;
      bytesSent_ += bytes.size();
    }
  }

  Job& job_;
  Dataset dataset_;
  std::vector<std::uint32_t> owners_;
  std::map<std::uint32_t, std::shared_ptr<std::vector<Splat>>> packets_;
  std::map<int, std::size_t> renderIndex_;
  std::vector<std::unordered_set<std::uint32_t>> sentTo_;
  std::deque<SendHandle> sends_;
  std::uint64_t bytesHeld_ = 0;
  double loadSeconds_ = 0.0;
  std::uint64_t packetsSent_ = 0;
  std::uint64_t bytesSent_ = 0;
  std::uint64_t duplicatesSkipped_ = 0;
};

}  // namespace

int runDatasendRole(Job& job, int argc, char** argv) {
  CLI::App app{"Pointillist data-send process (started by deploy/run.sh)"};
  CommonRoleOptions common;
  std::string datasetPath;
  addCommonRoleOptions(app, common);
  app.add_option("--dataset", datasetPath, "Dataset directory written by pointillist-preprocess");
  if (!parseRoleOptions(app, job, argc, argv)) return 0;

  if (datasetPath.empty()) {  // a handshake-only job
    runWorkerRole(job, handshakeOptions(common), "no dataset", ServeHandlers{});
    return 0;
  }
  DataSendProcess process(job, datasetPath);
  const ServeHandlers handlers = handlersFor(process);
  runWorkerRole(job, handshakeOptions(common), process.readyDetail(), handlers);
  return 0;
}

}  // namespace pointillist::datasend
