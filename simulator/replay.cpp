#include "simulator/replay.hpp"

#include <google/protobuf/util/message_differencer.h>

#include "common/ownership.hpp"
#include "traverse/core/octree_traversal.hpp"
#include "traverse/core/packet_planner.hpp"

namespace pointillist::simulator {
namespace {

// Field-by-field differences of the logged replies and the replayed ones.
std::string compare(const google::protobuf::RepeatedPtrField<v1::DecisionOutput>& logged,
                    const std::vector<v1::DecisionOutput>& replayed) {
  if (static_cast<std::size_t>(logged.size()) != replayed.size()) {
    return "the job sent " + std::to_string(logged.size()) + " messages, the replay " +
           std::to_string(replayed.size());
  }
  std::string report;
  for (std::size_t i = 0; i < replayed.size(); ++i) {
    google::protobuf::util::MessageDifferencer differencer;
    std::string difference;
    differencer.ReportDifferencesToString(&difference);
    if (!differencer.Compare(logged.Get(static_cast<int>(i)), replayed[i])) {
      report += "message " + std::to_string(i) + ": " + difference;
    }
  }
  return report;
}

}  // namespace

ReplayResult replayDecisions(const traverse::DecisionLog& log, std::span<const OctreeCell> cells,
                             std::span<const TopLevelCell> topLevel) {
  const PeerRanks peers = traverse::peersOf(log.start);
  const auto layers = std::make_shared<const traverse::PacketLayers>(cells, topLevel);
  traverse::PacketPlanner planner(
      peers, log.start.self_rank(), log.start.settings(), layers,
      assignOwners(topLevel, static_cast<std::uint32_t>(peers.datasends.size())));
  const traverse::CullingTable culling(cells, planner.traversal().sizeScale);
  ReplayResult result;
  for (std::size_t index = 0; index < log.decisions.size(); ++index) {
    const v1::TraverseDecision& decision = log.decisions[index];
    const TimePoint now = traverse::decisionTime(decision);
    if (decision.has_report()) {
      planner.applyReport(decision.source_rank(), decision.report(), now);
      ++result.reports;
      continue;
    }
    if (!decision.has_task()) continue;
    ++result.tasks;
    const v1::TileTask& task = decision.task();
    const traverse::TraversalSettings traversal = planner.traversalFor(task);
    const traverse::TraversalResult walk =
        traverse::traverseTile(culling, task.camera(), task.rect(), traversal);
    std::vector<CellPrefix> ahead;
    if (const auto camera = planner.lookaheadCamera(task)) {
      ahead = traverse::topLevelCellsInTile(culling, *layers, *camera, task.rect(), traversal);
    }
    Outbox out;
    planner.planPackets(task, traverse::walkOf(walk), ahead, now, out);
    const std::string difference =
        compare(decision.outputs(), traverse::decisionOutputs(out.entries()));
    if (difference.empty()) {
      ++result.identical;
    } else {
      result.mismatches.push_back({index, difference});
    }
  }
  return result;
}

}  // namespace pointillist::simulator
