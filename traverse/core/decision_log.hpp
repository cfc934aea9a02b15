#pragma once
// A traverse process's decision log (pointillist-traverse --decision-log): the
// run settings and peers it started with, then every message it handled with
// the time and what it sent in reply. Replaying the log through a fresh
// PacketPlanner must give the same replies: the process decides nothing
// outside its core (pointillist-simulate --replay checks it).
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <span>
#include <vector>

#include "common/clock.hpp"
#include "common/messages.hpp"
#include "common/peer_ranks.hpp"

namespace pointillist::traverse {

class DecisionLogWriter {
 public:
  // Creates the file; an InputError names it when it cannot be written.
  // Times are counted from `origin`.
  DecisionLogWriter(const std::filesystem::path& file, const v1::DecisionLogStart& start,
                    TimePoint origin);

  void recordReport(TimePoint now, int sourceRank, const v1::RenderReport& report);
  void recordTask(TimePoint now, int sourceRank, const v1::TileTask& task,
                  std::span<const Outgoing> outputs);

 private:
  void write(const v1::DecisionLogEntry& entry);

  std::filesystem::path file_;
  std::ofstream stream_;
  TimePoint origin_;
};

struct DecisionLog {
  v1::DecisionLogStart start;
  std::vector<v1::TraverseDecision> decisions;
};

// Reads a whole log; an InputError names the file and the entry that is damaged.
DecisionLog readDecisionLog(const std::filesystem::path& file);

// The outputs as the log keeps them: one per destination, in order.
std::vector<v1::DecisionOutput> decisionOutputs(std::span<const Outgoing> outputs);

PeerRanks peersOf(const v1::DecisionLogStart& start);
v1::DecisionLogStart decisionLogStart(const PeerRanks& peers, int selfRank,
                                      const v1::RunSettings& settings, const std::string& dataset);
// A time of the log as the time point it stands for.
TimePoint decisionTime(const v1::TraverseDecision& decision);

}  // namespace pointillist::traverse
