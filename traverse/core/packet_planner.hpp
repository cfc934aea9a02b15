#pragma once
// Every decision of a traverse process (seed 003 §4.3), without MPI: for one
// walked tile it picks the render process with the cost function (or takes
// the display's choice), orders what that process lacks from the data-send
// processes owning it, orders ahead along the camera path within a budget,
// and builds the render packet; it keeps the model of every render process
// from their reports.
//
// The core is told what arrived and `now` and appends what to send to an
// Outbox. The MPI traverse process and the simulator both drive this class.
#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "common/camera.hpp"
#include "common/clock.hpp"
#include "common/messages.hpp"
#include "common/octree_cell.hpp"
#include "common/peer_ranks.hpp"
#include "traverse/core/octree_traversal.hpp"
#include "traverse/core/packet_layers.hpp"
#include "traverse/core/render_model.hpp"

namespace pointillist::traverse {

// What the walk of one tile found (traverseTile's result, or the simulator's
// memo of it).
struct TileWalk {
  // Distinct cells, ascending, each with the prefix holding its ranges.
  std::span<const CellPrefix> needs;
  std::uint64_t splats = 0;
  std::span<const PacketRange> ranges;  // sorted by cell: a block per need
  // Parallel to needs where known (TraversalResult::needBoxes): a packet
  // carries the box of its needs' (RenderPacket.screen_box).
  std::span<const ScreenBox> needBoxes;
};

// What the render drawing `part` of `walk` waits for: the drawn ranges of
// each point packet, joined where at most `gapSplats` apart (the gap costs
// fewer bytes than the range it saves costs to name, hold and look up:
// needGapSplats), and for a statistical packet its prefix
// (PacketLayers::neededAsPrefix). Sorted by cell and first splat.
std::vector<CellRange> needRanges(const TileWalk& walk, std::size_t firstNeed, std::size_t endNeed,
                                  std::size_t firstRange, std::size_t endRange,
                                  const PacketLayers& layers, std::uint32_t gapSplats);

TileWalk walkOf(const TraversalResult& result);

// One part of a split walk: needs [firstNeed, endNeed) and their ranges
// [firstRange, endRange).
struct WalkPart {
  std::size_t firstNeed = 0, endNeed = 0;
  std::size_t firstRange = 0, endRange = 0;
  std::uint64_t splats = 0;
  bool operator==(const WalkPart&) const = default;
};

// Cuts a walk into at most `parts` pieces of whole top-level cells, runs of
// neighbours in cell order (so the same cells tend to fall to the same part
// from frame to frame, and stay cached where they went), each cut where the
// running count of drawn splats is nearest an equal share. Never an empty
// piece; one piece when the walk draws from one cell. ProtocolError when
// ranges and needs disagree, or a walk with needs has no ranges.
std::vector<WalkPart> splitWalk(const TileWalk& walk, std::size_t parts);

// The traversal settings of a run (level of detail, size scale, culling).
TraversalSettings traversalSettings(const v1::RunSettings& settings);

// What planPackets decided for one render packet, beside the messages it queued.
struct PacketPlan {
  RenderChoice choice;
  int renderRank = -1;
  std::vector<CellRange> needs;  // what its render waits for (needRanges)
  std::uint64_t prefetchBytes = 0;
  std::uint64_t orderedBytesHeldElsewhere = 0;  // of choice.missingBytes
  std::vector<CellRange> prefetch;
  std::uint64_t splats = 0;
  std::uint32_t partIndex = 0;
  std::uint32_t partCount = 1;  // > 1: a part of a split tile
};

class PacketPlanner {
 public:
  PacketPlanner(PeerRanks peers, int selfRank, const v1::RunSettings& settings,
                std::shared_ptr<const PacketLayers> layers, std::vector<std::uint32_t> owners);

  const TraversalSettings& traversal() const { return traversal_; }
  // The walk for one task: the run's, at the task's own level of detail if it has one.
  TraversalSettings traversalFor(const v1::TileTask& task) const;
  // The task's scheduler (a served frame's), else the run's.
  v1::Scheduler schedulerFor(const v1::TileTask& task) const;
  const v1::RunSettings& settings() const { return settings_; }

  // Asks the display for the run's tile tasks ahead (at start-up; planPacket
  // asks for one more after each tile, keeping that many on request).
  void startWork(Outbox& out);
  void requestWork(Outbox& out);
  // The same, telling the display where `task` went: the render of each of
  // its packets just sent (`placed`).
  void requestWork(Outbox& out, const v1::TileTask& task, std::span<const PacketPlan> placed);
  // The camera whose view of the task's rect should be ordered ahead, if the
  // run prefetches along the camera path; the caller walks it for planPacket.
  std::optional<Camera> lookaheadCamera(const v1::TileTask& task) const;
  // How many parts a tile's walk is cut into: walk.splats / task.part_splats
  // when at least two, as far as the frame may be split (tileSplitAllowed),
  // the walk has cells, and renders can take them (RenderModel::rendersForParts
  // within the whole tile's time); else 1.
  std::size_t partsFor(const v1::TileTask& task, const TileWalk& walk, TimePoint now) const;
  // One walked tile: cut into parts (partsFor, splitWalk), each takes its
  // needs (needRanges), chooses its render process (the cost function's;
  // one already drawing another part of the tile only when every other that
  // could take a part costs more than the part's own drawing time more),
  // orders what that process lacks of
  // them and, for the first, the prefetch (`ahead`: the lookahead walk's cells
  // and estimated prefixes), and sends its render packet; then asks the
  // display for the next tile. One plan per packet sent, in part order; none
  // for a walk that found nothing to draw: the display gets the tile's
  // background image from here (PIXEL_FORMAT_BACKGROUND), no render a packet.
  std::vector<PacketPlan> planPackets(const v1::TileTask& task, const TileWalk& walk,
                                      std::span<const CellPrefix> ahead, TimePoint now,
                                      Outbox& out);
  // A render process's report of its workload, cache changes and rates.
  void applyReport(int sourceRank, const v1::RenderReport& report, TimePoint now);

  // A render process is gone: no packet goes to it any more.
  void renderLost(int renderRank);
  const RenderModel& model() const { return model_; }
  const PacketLayers& layers() const { return *layers_; }
  std::uint64_t tasksDone() const { return tasksDone_; }
  std::uint64_t tilesSplit() const { return tilesSplit_; }
  std::uint64_t emptyTiles() const { return emptyTiles_; }
  std::uint64_t largestTileBytes() const { return maxPacketBytes_; }
  std::string summary() const;

 private:
  PeerRanks peers_;
  int selfRank_;
  std::size_t selfIndex_;
  v1::RunSettings settings_;
  TraversalSettings traversal_;
  std::shared_ptr<const PacketLayers> layers_;
  std::vector<std::uint32_t> owners_;
  RenderModel model_;
  PacketPlan planPart(const v1::TileTask& task, const TileWalk& walk, const WalkPart& part,
                      std::uint32_t partIndex, std::uint32_t partCount,
                      std::span<const CellPrefix> ahead, std::span<const std::size_t> taken,
                      TimePoint now, Outbox& out);

  std::uint64_t tasksDone_ = 0;
  std::uint64_t tilesSplit_ = 0;
  std::uint64_t emptyTiles_ = 0;     // answered here as background
  std::uint64_t renderAvoided_ = 0;  // packets moved off a render the display suspects
  std::uint64_t partsSent_ = 0;
  std::uint64_t packetsSent_ = 0;
  std::uint64_t ordersSent_ = 0;
  std::uint64_t splatsPacked_ = 0;
  std::uint64_t cellsOrdered_ = 0;
  std::uint64_t bytesOrdered_ = 0;
  std::uint64_t bytesOrderedHeldElsewhere_ = 0;  // another render held them
  std::uint64_t maxPacketBytes_ = 0;             // largest working set of one tile
  std::uint64_t cellsPrefetched_ = 0;
  std::uint64_t bytesPrefetched_ = 0;
};

}  // namespace pointillist::traverse
