#pragma once
// Replays a traverse process's decision log (pointillist-traverse
// --decision-log) through a fresh PacketPlanner, the core the simulator's
// traverse processes run: the same reports at the same times and the same
// tiles must give the same render packets, orders and work requests. It shows
// that the process decides nothing outside its core, and that the simulator
// chooses as a real job would for the same reports.
#include <cstddef>
#include <filesystem>
#include <span>
#include <string>
#include <vector>

#include "common/octree_cell.hpp"
#include "traverse/core/decision_log.hpp"

namespace pointillist::simulator {

struct ReplayMismatch {
  std::size_t decision = 0;  // index in the log
  std::string difference;    // what differs, field by field
};

struct ReplayResult {
  std::size_t tasks = 0;
  std::size_t reports = 0;
  std::size_t identical = 0;  // tasks whose replies match exactly
  std::vector<ReplayMismatch> mismatches;
};

ReplayResult replayDecisions(const traverse::DecisionLog& log, std::span<const OctreeCell> cells,
                             std::span<const TopLevelCell> topLevel);

}  // namespace pointillist::simulator
