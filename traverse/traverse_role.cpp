#include "traverse/traverse_role.hpp"

#include <algorithm>
#include <cstdio>
#include <deque>
#include <map>

#include "common/dataset.hpp"
#include "common/mpi/role_options.hpp"
#include "common/mpi/serve.hpp"
#include "common/ownership.hpp"
#include "traverse/octree_traversal.hpp"
#include "traverse/render_model.hpp"

namespace pointillist::traverse {
namespace {

class TraverseProcess {
 public:
  TraverseProcess(Job& job, const std::string& datasetPath)
      : job_(job),
        dataset_(Dataset::open(datasetPath, DatasetParts::Cells)),
        owners_(assignOwners(dataset_.topLevelCells(), job.layout().datasend)),
        model_(job.layout().render, dataset_.topLevelCells()) {
    const auto& renders = job.ranksOf(v1::ROLE_RENDER);
    for (std::size_t i = 0; i < renders.size(); ++i) renderIndex_[renders[i]] = i;
  }

  std::string readyDetail() const {
    return "cells=" + std::to_string(dataset_.cells().size()) +
           " top-level=" + std::to_string(dataset_.topLevelCells().size());
  }

  void requestWork() {
    v1::WorkRequest request;
    request.set_traverse_rank(job_.worldRank());
    request.set_tasks_done(tasksDone_);
    sends_.push_back(job_.channel().post(job_.displayRank(), MessageKind::WorkRequest, request));
  }

  void onMessage(Envelope& envelope) {
    switch (envelope.kind) {
      case MessageKind::TileTask:
        handleTask(envelope.as<v1::TileTask>());
        requestWork();
        break;
      case MessageKind::RenderReport:
        handleReport(envelope.source, envelope.as<v1::RenderReport>());
        break;
      default:
        throw ProtocolError(std::string("traverse got an unexpected ") +
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
    char line[256];
    std::snprintf(line, sizeof line,
                  "tasks=%llu splats=%llu ordered_cells=%llu ordered_bytes=%llu "
                  "prefetched_cells=%llu prefetched_bytes=%llu largest_tile_data=%.2fMiB "
                  "T_s=%.3gs/splat T_n=%.3gs/B",
                  static_cast<unsigned long long>(tasksDone_),
                  static_cast<unsigned long long>(splatsPacked_),
                  static_cast<unsigned long long>(cellsOrdered_),
                  static_cast<unsigned long long>(bytesOrdered_),
                  static_cast<unsigned long long>(cellsPrefetched_),
                  static_cast<unsigned long long>(bytesPrefetched_),
                  static_cast<double>(maxPacketBytes_) / 1048576.0, model_.secondsPerSplat(),
                  model_.secondsPerByte());
    return line;
  }

 private:
  void handleTask(const v1::TileTask& task) {
    TraversalSettings settings;
    settings.lodPixels = task.lod_pixels() > 0.0f ? task.lod_pixels() : 1.0f;
    settings.sizeScale = task.size_scale() > 0.0f ? task.size_scale() : 1.0f;
    settings.backfaceCull = task.backface_cull();
    const TraversalResult result =
        traverseTile(dataset_.cells(), task.camera(), task.rect(), settings);

    model_.setCostModel(task.cost_model() == v1::COST_MODEL_OVERLAP ? CostModel::Overlap
                                                                    : CostModel::Paper);
    const RenderChoice choice =
        task.scheduler() == v1::SCHEDULER_COST
            ? model_.choose(result.topLevelCells, result.splats)
            : model_.assigned(task.assigned_render(), result.topLevelCells, result.splats);
    const int renderRank = job_.ranksOf(v1::ROLE_RENDER).at(choice.render);

    // Order what the chosen render lacks from the data-send processes owning it.
    std::map<std::uint32_t, v1::SendOrder> orders;
    for (std::uint32_t cell : choice.missingCells) {
      v1::SendOrder& order = orders[owners_.at(cell)];
      order.add_top_level_cells(cell);
    }
    // Prefetch along the camera path: what this rect will need a few frames on
    // goes to the render drawing it now, which the cost function then favours
    // for that part of the screen.
    std::uint64_t prefetchBytes = 0;
    if (task.scheduler() == v1::SCHEDULER_COST && task.has_lookahead_camera()) {
      const auto ahead =
          topLevelCellsInTile(dataset_.cells(), task.lookahead_camera(), task.rect(), settings);
      std::vector<std::uint32_t> prefetch;
      for (std::uint32_t cell : model_.missingCells(choice.render, ahead)) {
        if (std::binary_search(choice.missingCells.begin(), choice.missingCells.end(), cell)) {
          continue;
        }
        const std::uint64_t bytes = dataset_.topLevelCells()[cell].byteSize;
        if (prefetchBytes + bytes > kPrefetchBudgetBytes) break;
        prefetchBytes += bytes;
        prefetch.push_back(cell);
        orders[owners_.at(cell)].add_top_level_cells(cell);
      }
      model_.recordPrefetch(choice.render, prefetch);
      cellsPrefetched_ += prefetch.size();
      bytesPrefetched_ += prefetchBytes;
    }
    const auto& datasends = job_.ranksOf(v1::ROLE_DATASEND);
    for (auto& [owner, order] : orders) {
      order.set_render_rank(renderRank);
      order.set_traverse_rank(job_.worldRank());
      order.set_order_id(++ordersSent_);
      sends_.push_back(job_.channel().post(datasends.at(owner), MessageKind::SendOrder, order));
    }

    v1::RenderPacket packet;
    packet.set_frame_id(task.frame_id());
    packet.set_tile_id(task.tile_id());
    *packet.mutable_camera() = task.camera();
    *packet.mutable_rect() = task.rect();
    packet.set_timestamp_ns(task.timestamp_ns());
    packet.set_attempt(task.attempt());
    packet.set_mode(task.mode());
    packet.set_point_size_scale(settings.sizeScale);
    for (std::uint32_t cell : result.topLevelCells) packet.add_top_level_cells(cell);
    packet.mutable_range_top_level()->Reserve(static_cast<int>(result.ranges.size()));
    for (const PacketRange& range : result.ranges) {
      packet.add_range_top_level(range.topLevel);
      packet.add_range_offset(range.offset);
      packet.add_range_count(range.count);
    }
    packet.set_total_splats(result.splats);
    packet.set_traverse_rank(job_.worldRank());
    packet.set_packet_id(++packetsSent_);
    packet.set_ordered_bytes(choice.missingBytes);
    packet.set_chosen_cost(choice.cost);
    packet.set_prefetch_bytes(prefetchBytes);
    sends_.push_back(job_.channel().post(renderRank, MessageKind::RenderPacket, packet));
    model_.recordPacket(choice.render, packetsSent_, result.splats, choice.missingCells);

    ++tasksDone_;
    std::uint64_t packetBytes = 0;
    for (std::uint32_t cell : result.topLevelCells) {
      packetBytes += dataset_.topLevelCells()[cell].byteSize;
    }
    maxPacketBytes_ = std::max(maxPacketBytes_, packetBytes);
    splatsPacked_ += result.splats;
    cellsOrdered_ += choice.missingCells.size();
    bytesOrdered_ += choice.missingBytes;
  }

  void handleReport(int source, const v1::RenderReport& report) {
    const auto found = renderIndex_.find(source);
    if (found == renderIndex_.end()) {
      throw ProtocolError("render report from rank " + std::to_string(source) +
                          ", which is not a render process");
    }
    RenderReportView view;
    view.workloadSplats = report.workload_splats();
    view.loaded = {report.loaded_cells().data(),
                   static_cast<std::size_t>(report.loaded_cells_size())};
    view.evicted = {report.evicted_cells().data(),
                    static_cast<std::size_t>(report.evicted_cells_size())};
    view.secondsPerSplat = report.seconds_per_splat();
    view.secondsPerByte = report.seconds_per_byte();
    view.lastPacketFromUs = report.last_packet_from_recipient();
    view.packetsDone = report.packets_done();
    model_.applyReport(found->second, view);
  }

  Job& job_;
  Dataset dataset_;
  std::vector<std::uint32_t> owners_;
  RenderModel model_;
  std::map<int, std::size_t> renderIndex_;
  std::deque<SendHandle> sends_;
  std::uint64_t tasksDone_ = 0;
  std::uint64_t packetsSent_ = 0;
  std::uint64_t ordersSent_ = 0;
  std::uint64_t splatsPacked_ = 0;
  std::uint64_t cellsOrdered_ = 0;
  std::uint64_t bytesOrdered_ = 0;
  std::uint64_t maxPacketBytes_ = 0;  // largest working set of one tile
  std::uint64_t cellsPrefetched_ = 0;
  std::uint64_t bytesPrefetched_ = 0;
};

}  // namespace

int runTraverseRole(Job& job, int argc, char** argv) {
  CLI::App app{"Pointillist traverse process (started by deploy/run.sh)"};
  CommonRoleOptions common;
  std::string datasetPath;
  addCommonRoleOptions(app, common);
  app.add_option("--dataset", datasetPath, "Dataset directory written by pointillist-preprocess");
  if (!parseRoleOptions(app, job, argc, argv)) return 0;

  if (datasetPath.empty()) {  // a handshake-only job
    runWorkerRole(job, handshakeOptions(common), "no dataset", ServeHandlers{});
    return 0;
  }
  // Load before the handshake so a bad dataset fails fast, with peers told.
  TraverseProcess process(job, datasetPath);
  const ServeHandlers handlers = handlersFor(process);
  runWorkerRole(job, handshakeOptions(common), process.readyDetail(), handlers,
                [&] { process.requestWork(); });
  return 0;
}

}  // namespace pointillist::traverse
