#include "traverse/core/decision_log.hpp"

#include <google/protobuf/io/zero_copy_stream_impl.h>
#include <google/protobuf/util/delimited_message_util.h>

#include "common/errors.hpp"

namespace pointillist::traverse {

DecisionLogWriter::DecisionLogWriter(const std::filesystem::path& file,
                                     const v1::DecisionLogStart& start, TimePoint origin)
    : file_(file), stream_(file, std::ios::binary | std::ios::trunc), origin_(origin) {
  if (!stream_) throw InputError("cannot write the decision log " + file.string());
  v1::DecisionLogEntry entry;
  *entry.mutable_start() = start;
  write(entry);
}

void DecisionLogWriter::write(const v1::DecisionLogEntry& entry) {
  if (!google::protobuf::util::SerializeDelimitedToOstream(entry, &stream_)) {
    throw InputError("cannot write the decision log " + file_.string());
  }
  stream_.flush();
}

void DecisionLogWriter::recordReport(TimePoint now, int sourceRank,
                                     const v1::RenderReport& report) {
  v1::DecisionLogEntry entry;
  v1::TraverseDecision& decision = *entry.mutable_decision();
  decision.set_time_ns(std::chrono::duration_cast<std::chrono::nanoseconds>(now - origin_).count());
  decision.set_source_rank(sourceRank);
  *decision.mutable_report() = report;
  write(entry);
}

void DecisionLogWriter::recordTask(TimePoint now, int sourceRank, const v1::TileTask& task,
                                   std::span<const Outgoing> outputs) {
  v1::DecisionLogEntry entry;
  v1::TraverseDecision& decision = *entry.mutable_decision();
  decision.set_time_ns(std::chrono::duration_cast<std::chrono::nanoseconds>(now - origin_).count());
  decision.set_source_rank(sourceRank);
  *decision.mutable_task() = task;
  for (v1::DecisionOutput& output : decisionOutputs(outputs)) {
    *decision.add_outputs() = std::move(output);
  }
  write(entry);
}

DecisionLog readDecisionLog(const std::filesystem::path& file) {
  std::ifstream stream(file, std::ios::binary);
  if (!stream) throw InputError("cannot read the decision log " + file.string());
  google::protobuf::io::IstreamInputStream input(&stream);
  DecisionLog log;
  for (std::size_t index = 0;; ++index) {
    v1::DecisionLogEntry entry;
    bool clean = false;
    if (!google::protobuf::util::ParseDelimitedFromZeroCopyStream(&entry, &input, &clean)) {
      if (clean) break;
      throw InputError(file.string() + ": entry " + std::to_string(index) +
                       " is damaged or cut short");
    }
    if (index == 0) {
      if (!entry.has_start()) {
        throw InputError(file.string() + " does not begin with a decision log start");
      }
      log.start = entry.start();
    } else if (entry.has_decision()) {
      log.decisions.push_back(entry.decision());
    } else {
      throw InputError(file.string() + ": entry " + std::to_string(index) + " is not a decision");
    }
  }
  if (!log.start.has_settings() && log.start.render_ranks().empty()) {
    throw InputError(file.string() + " is empty");
  }
  return log;
}

std::vector<v1::DecisionOutput> decisionOutputs(std::span<const Outgoing> outputs) {
  std::vector<v1::DecisionOutput> records;
  for (const Outgoing& outgoing : outputs) {
    for (int destination : outgoing.destinations) {
      v1::DecisionOutput& record = records.emplace_back();
      record.set_destination(destination);
      switch (outgoing.kind) {
        case MessageKind::RenderPacket:
          *record.mutable_packet() = outgoing.as<v1::RenderPacket>();
          break;
        case MessageKind::SendOrder:
          *record.mutable_order() = outgoing.as<v1::SendOrder>();
          break;
        case MessageKind::WorkRequest:
          *record.mutable_work_request() = outgoing.as<v1::WorkRequest>();
          break;
        case MessageKind::TileImage:
          *record.mutable_tile_image() = outgoing.as<v1::TileImageHeader>();
          break;
        default:
          throw ProtocolError(std::string("a traverse does not send ") +
                              messageKindName(outgoing.kind) + " messages");
      }
    }
  }
  return records;
}

PeerRanks peersOf(const v1::DecisionLogStart& start) {
  PeerRanks peers;
  peers.display = start.display_rank();
  peers.traverses.assign(start.traverse_ranks().begin(), start.traverse_ranks().end());
  peers.datasends.assign(start.datasend_ranks().begin(), start.datasend_ranks().end());
  peers.renders.assign(start.render_ranks().begin(), start.render_ranks().end());
  return peers;
}

v1::DecisionLogStart decisionLogStart(const PeerRanks& peers, int selfRank,
                                      const v1::RunSettings& settings, const std::string& dataset) {
  v1::DecisionLogStart start;
  *start.mutable_settings() = settings;
  start.set_self_rank(selfRank);
  start.set_display_rank(peers.display);
  for (int rank : peers.traverses) start.add_traverse_ranks(rank);
  for (int rank : peers.datasends) start.add_datasend_ranks(rank);
  for (int rank : peers.renders) start.add_render_ranks(rank);
  start.set_dataset(dataset);
  return start;
}

TimePoint decisionTime(const v1::TraverseDecision& decision) {
  return TimePoint{} +
         std::chrono::duration_cast<Clock::duration>(std::chrono::nanoseconds(decision.time_ns()));
}

}  // namespace pointillist::traverse
