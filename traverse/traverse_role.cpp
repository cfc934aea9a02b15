#include "traverse/traverse_role.hpp"

#include <memory>
#include <optional>

#include "common/dataset.hpp"
#include "common/mpi/worker.hpp"
#include "common/ownership.hpp"
#include "traverse/core/decision_log.hpp"
#include "traverse/core/octree_traversal.hpp"
#include "traverse/core/packet_planner.hpp"

namespace pointillist::traverse {
namespace {

class TraverseProcess final : public WorkerProcess {
 public:
  TraverseProcess(Job& job, const std::string& datasetPath, std::string decisionLogDir)
      : job_(job),
        datasetPath_(datasetPath),
        dataset_(Dataset::open(datasetPath, DatasetParts::Cells)),
        layers_(std::make_shared<const PacketLayers>(dataset_.cells(), dataset_.topLevelCells())),
        decisionLogDir_(std::move(decisionLogDir)) {}

  std::string readyDetail() const override {
    return "cells=" + std::to_string(dataset_.cells().size()) +
           " top-level=" + std::to_string(dataset_.topLevelCells().size());
  }

  void begin(const v1::RunSettings& settings) override {
    const PeerRanks peers = job_.peers();
    // Frames may ask for the statistical mode whenever the dataset has hierarchies.
    if (settings.mode() == v1::RENDER_MODE_STATISTICAL || settings.statistical_hierarchy()) {
      auto trees = StatisticalTrees::load(dataset_);
      layers_ = std::make_shared<const PacketLayers>(dataset_.cells(), dataset_.topLevelCells(),
                                                     trees.get());
      statistical_ = std::make_shared<StatisticalCutMemo>(std::move(trees));
    }
    planner_.emplace(peers, job_.worldRank(), settings, layers_,
                     assignPacketOwners(dataset_.topLevelCells(), job_.layout().datasend,
                                        static_cast<std::uint32_t>(layers_->cellCount())));
    culling_.emplace(dataset_.cells(), planner_->traversal().sizeScale);
    // Frames may ask for the instanced mode whenever the dataset has sections.
    runMode_ = settings.mode();
    if (runMode_ == v1::RENDER_MODE_INSTANCED || settings.instanced_sections())
      instanced_ = InstancedCells::load(dataset_);
    const TimePoint now = Clock::now();
    if (!decisionLogDir_.empty()) {
      std::filesystem::create_directories(decisionLogDir_);
      const auto file = std::filesystem::path(decisionLogDir_) /
                        ("traverse-" + std::to_string(job_.worldRank()) + ".decisions");
      log_.emplace(file, decisionLogStart(peers, job_.worldRank(), settings, datasetPath_), now);
    }
    Outbox out;
    planner_->startWork(out);
    job_.sends().post(out);
  }

  void onMessage(Envelope& envelope) override {
    const TimePoint now = Clock::now();
    switch (envelope.kind) {
      case MessageKind::TileTask: {
        const auto task = envelope.as<v1::TileTask>();
        TraversalSettings traversal = planner_->traversalFor(task);
        const v1::RenderMode frameMode =
            task.has_frame_settings() ? task.frame_settings().mode() : v1::RENDER_MODE_UNSPECIFIED;
        if ((frameMode != v1::RENDER_MODE_UNSPECIFIED ? frameMode : runMode_) ==
            v1::RENDER_MODE_INSTANCED) {
          if (!instanced_)
            throw ProtocolError(
                "a frame asks for the instanced mode of a dataset without sections");
          traversal.instanced = instanced_;
        }
        if ((frameMode != v1::RENDER_MODE_UNSPECIFIED ? frameMode : runMode_) ==
            v1::RENDER_MODE_STATISTICAL) {
          if (!statistical_)
            throw ProtocolError(
                "a frame asks for the statistical mode of a dataset without hierarchies");
          traversal.statistical = statistical_;
        }
        const TraversalResult walk = traverseTile(*culling_, task.camera(), task.rect(), traversal);
        std::vector<CellPrefix> ahead;
        if (const auto camera = planner_->lookaheadCamera(task)) {
          ahead = topLevelCellsInTile(*culling_, *layers_, *camera, task.rect(), traversal);
        }
        Outbox out;
        planner_->planPackets(task, walkOf(walk), ahead, now, out);
        if (log_) log_->recordTask(now, envelope.source, task, out.entries());
        job_.sends().post(out);
        break;
      }
      case MessageKind::RenderReport: {
        const auto report = envelope.as<v1::RenderReport>();
        planner_->applyReport(envelope.source, report, now);
        if (log_) log_->recordReport(now, envelope.source, report);
        break;
      }
      default:
        throw ProtocolError(std::string("traverse got an unexpected ") +
                            messageKindName(envelope.kind) + " from rank " +
                            std::to_string(envelope.source));
    }
  }

  std::string summary() const override { return planner_ ? planner_->summary() : std::string(); }

  void onPeerLost(int rank, v1::Role role) override {
    if (role == v1::ROLE_RENDER && planner_) planner_->renderLost(rank);
  }

 private:
  Job& job_;
  std::string datasetPath_;
  Dataset dataset_;
  std::shared_ptr<const PacketLayers> layers_;
  std::string decisionLogDir_;
  std::optional<PacketPlanner> planner_;
  std::optional<CullingTable> culling_;              // for the run's size scale
  std::shared_ptr<const InstancedCells> instanced_;  // the dataset's sections, if it has them
  std::shared_ptr<StatisticalCutMemo> statistical_;  // its hierarchies, if it has them
  v1::RenderMode runMode_ = v1::RENDER_MODE_POINTS;
  std::optional<DecisionLogWriter> log_;
};

}  // namespace

int runTraverseMain(int argc, char** argv) {
  std::string decisionLogDir;
  return runWorkerMain(
      argc, argv, v1::ROLE_TRAVERSE, "Pointillist traverse process (started by deploy/run.sh)",
      [&](CLI::App& app) {
        app.add_option("--decision-log", decisionLogDir,
                       "Folder for each traverse's decision log (replay it with "
                       "pointillist-simulate --replay)");
      },
      [&](Job& job, const std::string& datasetPath) {
        // Load before the handshake so a bad dataset fails fast, with peers told.
        return std::make_unique<TraverseProcess>(job, datasetPath, decisionLogDir);
      });
}

}  // namespace pointillist::traverse
