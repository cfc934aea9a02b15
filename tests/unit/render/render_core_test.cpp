// The render process's decisions (seed 003 §4.4-4.5), driven directly: what it
// asks data-send for and in which order, which cells it pins, what it drops,
// when it asks again, what it reports and to whom.
#include <gtest/gtest.h>

#include <algorithm>

#include "common/point_groups.hpp"
#include "common/splat.hpp"
#include "render/core/render_core.hpp"

namespace pointillist::render {
namespace {

using namespace std::chrono_literals;

// Layout 1,2,2,1: display 0, traverses 1-2, data-sends 3-4, the render 5.
const PeerRanks kPeers = PeerRanks::contiguous(JobLayout{1, 2, 2, 1});
constexpr int kTraverse = 1;
constexpr int kOtherTraverse = 2;
constexpr int kSelf = 5;
const TimePoint kStart = timeAfterEpoch(100.0);

// Every cell's layered packet: 40 level-splats, then 160 points.
constexpr std::uint32_t kCellSplats = 200;
constexpr std::uint64_t kCellBytes = kCellSplats * sizeof(Splat);

std::vector<TopLevelCell> table(std::size_t cells) {
  std::vector<TopLevelCell> topLevel(cells);
  for (std::size_t i = 0; i < cells; ++i) {
    topLevel[i].levelSplatCount = 40;
    topLevel[i].pointCount = kCellSplats - 40;
    topLevel[i].byteSize = kCellBytes;
    topLevel[i].byteOffset = i * kCellBytes;
  }
  return topLevel;
}

// Cells 0-1 belong to data-send 3, cells 2-3 to data-send 4.
const std::vector<std::uint32_t> kOwners{0, 0, 1, 1};

RenderCore makeCore(std::uint64_t capCells, std::optional<std::uint64_t> stallAfter = {}) {
  RenderCoreConfig config;
  config.cacheCapBytes = capCells * kCellBytes;
  config.cacheTimeout = 30s;
  config.stallAfterPackets = stallAfter;
  return RenderCore(config, kPeers, kSelf, table(4), kOwners);
}

// A packet drawing and needing the given ranges.
v1::RenderPacket packetOf(std::uint64_t id, const std::vector<CellRange>& ranges,
                          std::uint64_t splats = 5000, std::uint64_t frame = 7) {
  v1::RenderPacket p;
  p.set_frame_id(frame);
  p.set_tile_id(static_cast<std::uint32_t>(id));
  p.set_packet_id(id);
  p.set_traverse_rank(kTraverse);
  p.set_total_splats(splats);
  for (const CellRange& range : ranges) {
    p.add_need_top_level(range.cell);
    p.add_need_first(range.first);
    p.add_need_count(range.count);
    p.add_range_top_level(range.cell);
    p.add_range_offset(range.first);
    p.add_range_count(range.count);
  }
  p.mutable_rect()->set_width(8);
  p.mutable_rect()->set_height(4);
  return p;
}

// A packet drawing the whole of each cell (or the first `prefix` splats).
v1::RenderPacket packet(std::uint64_t id, std::vector<std::uint32_t> cells,
                        std::uint64_t splats = 5000, std::uint64_t frame = 7,
                        std::uint32_t prefix = kCellSplats) {
  std::vector<CellRange> ranges;
  for (std::uint32_t cell : cells) ranges.push_back({cell, 0, prefix});
  return packetOf(id, ranges, splats, frame);
}

// The messages of an outbox, flattened to (kind, destination) in order.
std::vector<std::pair<MessageKind, int>> sent(const Outbox& out) {
  std::vector<std::pair<MessageKind, int>> messages;
  for (const Outgoing& outgoing : out.entries()) {
    for (int destination : outgoing.destinations) messages.emplace_back(outgoing.kind, destination);
  }
  return messages;
}

std::vector<const v1::SendOrder*> orders(const Outbox& out) {
  std::vector<const v1::SendOrder*> found;
  for (const Outgoing& outgoing : out.entries()) {
    if (outgoing.kind == MessageKind::SendOrder) found.push_back(&outgoing.as<v1::SendOrder>());
  }
  return found;
}

std::vector<std::uint32_t> cellsOf(const v1::SendOrder& order) {
  return {order.range_top_level().begin(), order.range_top_level().end()};
}

std::vector<CellRange> rangesOf(const v1::SendOrder& order) {
  return rangesFromFields(order.range_top_level(), order.range_first(), order.range_count(),
                          "order");
}

std::vector<CellRange> loadedIn(const v1::RenderReport& report) {
  return rangesFromFields(report.loaded_top_level(), report.loaded_first(), report.loaded_count(),
                          "report");
}

// A whole cell's data arriving.
DataVerdict whole(RenderCore& core, std::uint32_t cell, double seconds, TimePoint now,
                  RenderEffects& effects) {
  return core.receiveData(cell, 0, kCellSplats, seconds, now, effects);
}

TEST(RenderCore, AsksTheOwningDataSendForMissingCellsOnceAndNamesItselfAsRequester) {
  RenderCore core = makeCore(4);
  RenderEffects effects;
  core.receivePacket(kTraverse, packet(1, {0, 2, 3}), kStart, effects);
  const auto asked = orders(effects.messages);
  ASSERT_EQ(asked.size(), 2u);
  EXPECT_EQ(cellsOf(*asked[0]), (std::vector<std::uint32_t>{0}));
  EXPECT_EQ(cellsOf(*asked[1]), (std::vector<std::uint32_t>{2, 3}));
  EXPECT_EQ(sent(effects.messages)[0].second, 3);
  EXPECT_EQ(sent(effects.messages)[1].second, 4);
  for (const v1::SendOrder* order : asked) {
    EXPECT_EQ(order->render_rank(), kSelf);
    EXPECT_EQ(order->requester_rank(), kSelf);
    EXPECT_EQ(order->frame_id(), 7u);
  }
  // A second packet needing the same cells asks for nothing: they are on the way.
  RenderEffects again;
  core.receivePacket(kTraverse, packet(2, {0, 3}), kStart + 1ms, again);
  EXPECT_TRUE(orders(again.messages).empty());
  EXPECT_EQ(core.misses(), 5u);
  EXPECT_EQ(core.workloadSplats(), 10'000u);
}

TEST(RenderCore, DrawsAPacketOnlyOnceAllItsDataIsHereAndStampsTheWait) {
  RenderCore core = makeCore(4);
  RenderEffects effects;
  core.receivePacket(kTraverse, packet(1, {0, 1}), kStart, effects);
  EXPECT_FALSE(core.nextPacket(kStart, effects));
  EXPECT_EQ(whole(core, 0, 1e-4, kStart + 10ms, effects), DataVerdict::Store);
  EXPECT_FALSE(core.nextPacket(kStart + 10ms, effects));
  EXPECT_EQ(whole(core, 1, 1e-4, kStart + 30ms, effects), DataVerdict::Store);
  const auto ready = core.nextPacket(kStart + 40ms, effects);
  ASSERT_TRUE(ready);
  const v1::TileImageHeader header = core.packetDrawn(*ready, 5000, 0.005, kStart + 45ms, effects);
  EXPECT_EQ(header.data_wait_us(), 30'000);
  EXPECT_EQ(header.queued_time_us(), 45'000);
  EXPECT_EQ(header.render_rank(), kSelf);
  EXPECT_EQ(header.traverse_rank(), kTraverse);
  EXPECT_EQ(header.workload_splats(), 0u);
  EXPECT_DOUBLE_EQ(core.secondsPerSplat(), 1e-6);
  // A late duplicate of cached data is ignored.
  EXPECT_EQ(whole(core, 1, 1e-4, kStart + 50ms, effects), DataVerdict::Duplicate);
  EXPECT_THROW(core.receiveData(2, 0, kCellSplats + 1, 1e-4, kStart, effects), ProtocolError);
  EXPECT_THROW(core.receiveData(2, kCellSplats, 1, 1e-4, kStart, effects), ProtocolError);
}

// Readiness is kept per packet as cells come and go: a queued packet whose
// cell is evicted (only the head packet's cells are pinned) waits again.
TEST(RenderCore, AQueuedPacketWaitsAgainWhenACellItNeedsIsEvicted) {
  RenderCore core = makeCore(2);  // room for two cells
  RenderEffects effects;
  core.receivePacket(kTraverse, packet(1, {0}), kStart, effects);     // the head
  core.receivePacket(kTraverse, packet(2, {1, 2}), kStart, effects);  // not pinned
  EXPECT_FALSE(core.nextPacket(kStart, effects));
  EXPECT_TRUE(core.pinned(0));
  EXPECT_FALSE(core.pinned(1));
  EXPECT_EQ(whole(core, 1, 0.0, kStart + 1ms, effects), DataVerdict::Store);
  EXPECT_EQ(whole(core, 2, 0.0, kStart + 2ms, effects), DataVerdict::Store);
  // The head's cell comes last and evicts the least recently used: cell 1.
  RenderEffects loaded;
  EXPECT_EQ(whole(core, 0, 0.0, kStart + 3ms, loaded), DataVerdict::Store);
  EXPECT_EQ(loaded.released, (std::vector<std::uint32_t>{1}));
  auto ready = core.nextPacket(kStart + 4ms, effects);
  ASSERT_TRUE(ready);
  EXPECT_EQ(ready->packet.packet_id(), 1u);
  core.packetDrawn(*ready, 5000, 0.01, kStart + 5ms, effects);
  EXPECT_FALSE(core.nextPacket(kStart + 6ms, effects));  // cell 1 is gone
  EXPECT_TRUE(core.pinned(1));
  EXPECT_TRUE(core.requested(1));
  EXPECT_EQ(whole(core, 1, 0.0, kStart + 7ms, effects), DataVerdict::Store);
  ready = core.nextPacket(kStart + 8ms, effects);
  ASSERT_TRUE(ready);
  EXPECT_EQ(ready->packet.packet_id(), 2u);
  EXPECT_EQ(ready->dataComplete, kStart + 2ms);  // first complete, before the eviction
  EXPECT_FALSE(core.nextPacket(kStart + 9ms, effects));
}

TEST(RenderCore, ReportsEvictionsToDataSendBeforeARequestForTheSameCell) {
  // Room for one cell: loading cell 1 evicts cell 0.
  RenderCore core = makeCore(1);
  RenderEffects effects;
  core.receivePacket(kTraverse, packet(1, {0}), kStart, effects);
  whole(core, 0, 0.0, kStart, effects);
  auto ready = core.nextPacket(kStart, effects);
  ASSERT_TRUE(ready);
  core.packetDrawn(*ready, 5000, 0.01, kStart, effects);
  core.receivePacket(kTraverse, packet(2, {1}), kStart, effects);
  RenderEffects loaded;
  EXPECT_EQ(whole(core, 1, 0.0, kStart, loaded), DataVerdict::Store);
  EXPECT_EQ(loaded.released, (std::vector<std::uint32_t>{0}));
  // Cell 0 is wanted again before the eviction was reported: the report goes
  // first, or data-send would drop the request as a duplicate.
  RenderEffects wanted;
  core.receivePacket(kTraverse, packet(3, {0}), kStart, wanted);
  const auto messages = sent(wanted.messages);
  ASSERT_GE(wanted.messages.entries().size(), 2u);
  const Outgoing& report = wanted.messages.entries()[0];
  ASSERT_EQ(report.kind, MessageKind::RenderReport);
  EXPECT_EQ(report.destinations, (std::vector<int>{1, 2, 3, 4}));
  const auto& evicted = report.as<v1::RenderReport>().evicted_cells();
  EXPECT_NE(std::find(evicted.begin(), evicted.end(), 0u), evicted.end());
  const Outgoing& request = wanted.messages.entries()[1];
  ASSERT_EQ(request.kind, MessageKind::SendOrder);
  EXPECT_EQ(request.destinations, (std::vector<int>{3}));
  EXPECT_EQ(cellsOf(request.as<v1::SendOrder>()), (std::vector<std::uint32_t>{0}));
}

TEST(RenderCore, PinsOnlyTheHeadPacketAndDropsPrefetchedDataWithNoRoomBesideIt) {
  // Room for two cells; the head packet needs both.
  RenderCore core = makeCore(2);
  RenderEffects effects;
  core.receivePacket(kTraverse, packet(1, {0, 1}), kStart, effects);
  core.receivePacket(kTraverse, packet(2, {2}), kStart, effects);
  EXPECT_FALSE(core.nextPacket(kStart, effects));
  EXPECT_TRUE(core.pinned(0));
  EXPECT_TRUE(core.pinned(1));
  EXPECT_FALSE(core.pinned(2));
  whole(core, 0, 0.0, kStart, effects);
  whole(core, 1, 0.0, kStart, effects);
  // Cell 2 arrives while the head packet's two cells fill the cap: dropped and
  // reported as evicted, so that it is sent again when it is needed.
  RenderEffects dropped;
  EXPECT_EQ(whole(core, 2, 0.0, kStart, dropped), DataVerdict::Dropped);
  EXPECT_EQ(core.droppedPrefetches(), 1u);
  EXPECT_FALSE(core.requested(2));
  auto ready = core.nextPacket(kStart + 1ms, dropped);
  ASSERT_TRUE(ready);
  EXPECT_EQ(ready->packet.packet_id(), 1u);
  // Once the head packet is drawn, packet 2 is the head: its cell is pinned
  // and asked for again, after the report that it was dropped.
  RenderEffects next;
  core.packetDrawn(*ready, 5000, 0.01, kStart + 2ms, next);
  EXPECT_FALSE(core.pinned(0));
  EXPECT_TRUE(core.pinned(2));
  const auto messages = next.messages.entries();
  ASSERT_EQ(messages.size(), 2u);
  ASSERT_EQ(messages[0].kind, MessageKind::RenderReport);
  EXPECT_EQ(messages[0].destinations, (std::vector<int>{1, 2, 3, 4}));
  EXPECT_EQ(messages[0].as<v1::RenderReport>().evicted_cells_size(), 1);
  EXPECT_EQ(messages[0].as<v1::RenderReport>().evicted_cells(0), 2u);
  ASSERT_EQ(messages[1].kind, MessageKind::SendOrder);
  EXPECT_EQ(messages[1].destinations, (std::vector<int>{4}));
  EXPECT_EQ(cellsOf(messages[1].as<v1::SendOrder>()), (std::vector<std::uint32_t>{2}));
  EXPECT_FALSE(core.nextPacket(kStart + 3ms, next));
  // Now cell 2 fits: an unpinned cell makes room for the pinned one.
  RenderEffects loaded;
  EXPECT_EQ(whole(core, 2, 0.0, kStart + 4ms, loaded), DataVerdict::Store);
  EXPECT_EQ(loaded.released.size(), 1u);
  EXPECT_LE(core.cache().bytes(), 2 * kCellBytes);
}

TEST(RenderCore, AsksAgainForDataThatIsLateAndNotBefore) {
  RenderCore core = makeCore(4);
  RenderEffects effects;
  core.nextPacket(kStart, effects);  // maintenance counts from here
  core.receivePacket(kTraverse, packet(1, {3}), kStart, effects);
  ASSERT_TRUE(core.nextMaintenance());
  EXPECT_GT(*core.nextMaintenance(), kStart + kRerequestAfter);
  RenderEffects early;
  core.nextPacket(kStart + 600ms, early);
  EXPECT_TRUE(orders(early.messages).empty());
  RenderEffects late;
  core.nextPacket(*core.nextMaintenance(), late);
  const auto asked = orders(late.messages);
  ASSERT_EQ(asked.size(), 1u);
  EXPECT_EQ(cellsOf(*asked[0]), (std::vector<std::uint32_t>{3}));
  EXPECT_EQ(sent(late.messages).back().second, 4);
}

TEST(RenderCore, ExpiresUnusedCellsAfterTheTimeoutAndReleasesTheirData) {
  RenderCoreConfig config;
  config.cacheCapBytes = 4 * kCellBytes;
  config.cacheTimeout = 2s;
  RenderCore core(config, kPeers, kSelf, table(4), kOwners);
  RenderEffects effects;
  core.nextPacket(kStart, effects);
  core.receivePacket(kTraverse, packet(1, {1}), kStart, effects);
  whole(core, 1, 0.0, kStart, effects);
  auto ready = core.nextPacket(kStart, effects);
  ASSERT_TRUE(ready);
  core.packetDrawn(*ready, 100, 0.001, kStart, effects);
  EXPECT_FALSE(core.nextPacket(kStart + 1s, effects));  // still fresh
  EXPECT_TRUE(core.cache().contains(1));
  const auto due = core.nextMaintenance();
  ASSERT_TRUE(due);
  EXPECT_GT(*due, kStart + 2s);
  RenderEffects expired;
  core.nextPacket(*due, expired);
  EXPECT_EQ(expired.released, (std::vector<std::uint32_t>{1}));
  EXPECT_FALSE(core.cache().contains(1));
  EXPECT_FALSE(core.nextMaintenance());
}

TEST(RenderCore, ReportsGoToEveryTraverseWithEachOnesLastPacketAndToDataSendOnlyWithEvictions) {
  RenderCore core = makeCore(4);
  RenderEffects effects;
  // Announces itself on its first idle moment.
  core.nextPacket(kStart, effects);
  ASSERT_EQ(effects.messages.entries().size(), 1u);
  EXPECT_EQ(effects.messages.entries()[0].destinations, (std::vector<int>{1, 2}));
  v1::RenderPacket fromOther = packet(4, {0});
  fromOther.set_traverse_rank(kOtherTraverse);
  RenderEffects more;
  core.receivePacket(kTraverse, packet(9, {0}), kStart, more);
  core.receivePacket(kOtherTraverse, fromOther, kStart, more);
  whole(core, 0, 0.0, kStart, more);
  auto ready = core.nextPacket(kStart, more);
  ASSERT_TRUE(ready);
  RenderEffects drawn;
  core.packetDrawn(*ready, 5000, 0.01, kStart, drawn);
  ASSERT_EQ(drawn.messages.entries().size(), 1u);
  const Outgoing& report = drawn.messages.entries()[0];
  EXPECT_EQ(report.destinations, (std::vector<int>{1, 2}));
  const auto& message = report.as<v1::RenderReport>();
  ASSERT_EQ(message.last_packet_from_traverse_size(), 2);
  EXPECT_EQ(message.last_packet_from_traverse(0), 9u);
  EXPECT_EQ(message.last_packet_from_traverse(1), 4u);
  EXPECT_EQ(message.packets_done(), 1u);
  EXPECT_EQ(message.workload_splats(), 5000u);
  EXPECT_EQ(loadedIn(message), (std::vector<CellRange>{{0, 0, kCellSplats}}));
  // A packet from a process that is not a traverse is a protocol error.
  EXPECT_THROW(core.receivePacket(3, packet(1, {0}), kStart, drawn), ProtocolError);
  EXPECT_THROW(core.receivePacket(kTraverse, packet(1, {4}), kStart, drawn), ProtocolError);
}

TEST(RenderCore, AStalledProcessKeepsTakingMessagesButDrawsNothing) {
  RenderCore core = makeCore(4, 1);
  RenderEffects effects;
  core.receivePacket(kTraverse, packet(1, {0}), kStart, effects);
  core.receivePacket(kTraverse, packet(2, {0}), kStart, effects);
  whole(core, 0, 0.0, kStart, effects);
  auto first = core.nextPacket(kStart, effects);
  ASSERT_TRUE(first);
  core.packetDrawn(*first, 100, 0.001, kStart, effects);
  EXPECT_TRUE(core.stalled());
  EXPECT_FALSE(core.nextPacket(kStart + 1s, effects));
  EXPECT_EQ(core.queuedPackets(), 1u);
}

// A render holds ranges of a cell's packet, wherever they lie: it asks for
// what it lacks of a packet's needs, a copy takes the room up to the last
// splat held, and a report lists the ranges stored since the last one.
TEST(RenderCore, HoldsRangesOfPacketsAndAsksOnlyForWhatItLacks) {
  RenderCore core = makeCore(4);
  RenderEffects effects;
  // A distant view draws cell 0's first layer only: 40 splats are asked for.
  core.receivePacket(kTraverse, packet(1, {0}, 40, 7, 40), kStart, effects);
  auto asked = orders(effects.messages);
  ASSERT_EQ(asked.size(), 1u);
  EXPECT_EQ(rangesOf(*asked[0]), (std::vector<CellRange>{{0, 0, 40}}));
  EXPECT_EQ(core.receiveData(0, 0, 40, 0.0, kStart + 1ms, effects), DataVerdict::Store);
  EXPECT_EQ(core.heldSplats(0), 40u);
  EXPECT_EQ(core.cache().bytes(), 40 * sizeof(Splat));
  auto ready = core.nextPacket(kStart + 1ms, effects);
  ASSERT_TRUE(ready);
  core.packetDrawn(*ready, 40, 0.001, kStart + 2ms, effects);
  // A packet needing 20-60 and 150-200: it asks for 40-60 and 150-200 only.
  RenderEffects closer;
  core.receivePacket(kTraverse, packetOf(2, {{0, 20, 40}, {0, 150, 50}}), kStart + 3ms, closer);
  EXPECT_EQ(core.misses(), 2u);
  asked = orders(closer.messages);
  ASSERT_EQ(asked.size(), 1u);
  EXPECT_EQ(rangesOf(*asked[0]), (std::vector<CellRange>{{0, 40, 20}, {0, 150, 50}}));
  // The far range first: a copy now takes room for 200 splats, and the
  // packet still waits.
  EXPECT_EQ(core.receiveData(0, 150, 50, 0.0, kStart + 4ms, closer), DataVerdict::Store);
  EXPECT_EQ(core.heldSplats(0), 90u);
  EXPECT_EQ(core.heldExtent(0), kCellSplats);
  EXPECT_EQ(core.cache().bytes(), kCellBytes);
  EXPECT_TRUE(core.requested(0));
  // Idle and waiting: the report of what came goes out.
  RenderEffects waiting;
  EXPECT_FALSE(core.nextPacket(kStart + 4ms, waiting));
  ASSERT_EQ(waiting.messages.entries().size(), 1u);
  EXPECT_EQ(loadedIn(waiting.messages.entries()[0].as<v1::RenderReport>()),
            (std::vector<CellRange>{{0, 150, 50}}));
  EXPECT_EQ(core.receiveData(0, 40, 20, 0.0, kStart + 5ms, closer), DataVerdict::Store);
  EXPECT_FALSE(core.requested(0));
  EXPECT_TRUE(core.holds(0, 0, 60));
  EXPECT_FALSE(core.holds(0, 0, 61));
  ready = core.nextPacket(kStart + 5ms, closer);
  ASSERT_TRUE(ready);
  RenderEffects drawn;
  core.packetDrawn(*ready, 90, 0.001, kStart + 6ms, drawn);
  const auto& report = drawn.messages.entries()[0].as<v1::RenderReport>();
  EXPECT_EQ(loadedIn(report), (std::vector<CellRange>{{0, 40, 20}}));
  // Data held already is a duplicate; data partly new is stored whole.
  EXPECT_EQ(core.receiveData(0, 10, 50, 0.0, kStart, drawn), DataVerdict::Duplicate);
  EXPECT_EQ(core.receiveData(0, 55, 100, 0.0, kStart, drawn), DataVerdict::Store);
  EXPECT_EQ(core.heldSplats(0), kCellSplats);
}

// A part that arrives after its cell was evicted is stored as any other:
// ranges need no gap-free start.
TEST(RenderCore, APartOfAnEvictedCellIsStoredAndReportedAfterTheEviction) {
  // Room for one cell: cell 0's first layer is evicted by cell 1 while more
  // of it is on the way.
  RenderCore core = makeCore(1);
  RenderEffects effects;
  core.receiveData(0, 0, 40, 0.0, kStart, effects);
  core.receivePacket(kTraverse, packet(1, {1}), kStart, effects);
  RenderEffects evicting;
  whole(core, 1, 0.0, kStart, evicting);
  EXPECT_EQ(evicting.released, (std::vector<std::uint32_t>{0}));
  EXPECT_EQ(core.heldSplats(0), 0u);
  auto ready = core.nextPacket(kStart, effects);
  ASSERT_TRUE(ready);
  RenderEffects drawn;
  core.packetDrawn(*ready, 100, 0.001, kStart, drawn);
  const auto& first = drawn.messages.entries()[0].as<v1::RenderReport>();
  EXPECT_EQ(first.evicted_cells_size(), 1);
  EXPECT_EQ(loadedIn(first), (std::vector<CellRange>{{1, 0, kCellSplats}}));
  // Cell 1 is no longer pinned: the late part of cell 0 makes room.
  RenderEffects late;
  EXPECT_EQ(core.receiveData(0, 40, 60, 0.0, kStart + 1ms, late), DataVerdict::Store);
  EXPECT_EQ(late.released, (std::vector<std::uint32_t>{1}));
  EXPECT_EQ(core.heldSplats(0), 60u);
  core.nextPacket(kStart + 2ms, late);  // idle: the report goes
  ASSERT_FALSE(late.messages.entries().empty());
  const auto& second = late.messages.entries().back().as<v1::RenderReport>();
  EXPECT_EQ(
      std::vector<std::uint32_t>(second.evicted_cells().begin(), second.evicted_cells().end()),
      (std::vector<std::uint32_t>{1}));
  EXPECT_EQ(loadedIn(second), (std::vector<CellRange>{{0, 40, 60}}));
}

TEST(RenderCore, RefusesPacketsWhoseRangesLieOutsideWhatTheyWaitFor) {
  RenderCore core = makeCore(4);
  RenderEffects effects;
  v1::RenderPacket beyond = packet(1, {0}, 100, 7, 40);
  beyond.set_range_count(0, 41);
  EXPECT_THROW(core.receivePacket(kTraverse, beyond, kStart, effects), ProtocolError);
  v1::RenderPacket tooLong = packet(2, {0}, 100, 7, kCellSplats + 1);
  tooLong.set_range_count(0, 1);
  EXPECT_THROW(core.receivePacket(kTraverse, tooLong, kStart, effects), ProtocolError);
  v1::RenderPacket noCounts = packet(3, {0});
  noCounts.clear_need_count();
  EXPECT_THROW(core.receivePacket(kTraverse, noCounts, kStart, effects), ProtocolError);
  v1::RenderPacket unnamed = packet(4, {0});
  unnamed.set_range_top_level(0, 2);
  EXPECT_THROW(core.receivePacket(kTraverse, unnamed, kStart, effects), ProtocolError);
  // Needs that touch, or that go backwards.
  EXPECT_THROW(
      core.receivePacket(kTraverse, packetOf(5, {{0, 0, 40}, {0, 40, 10}}), kStart, effects),
      ProtocolError);
  EXPECT_THROW(
      core.receivePacket(kTraverse, packetOf(6, {{1, 0, 40}, {0, 50, 10}}), kStart, effects),
      ProtocolError);
  // A range between two needs, or across both.
  for (const CellRange& drawn : {CellRange{0, 50, 10}, CellRange{0, 30, 80}}) {
    v1::RenderPacket between = packetOf(7, {{0, 0, 40}, {0, 100, 40}});
    between.set_range_offset(1, drawn.first);
    between.set_range_count(1, drawn.count);
    EXPECT_THROW(core.receivePacket(kTraverse, between, kStart, effects), ProtocolError);
  }
  EXPECT_EQ(core.queuedPackets(), 0u);
  // Two ranges in two needs of one cell are a packet.
  core.receivePacket(kTraverse, packetOf(8, {{0, 0, 40}, {0, 100, 40}}), kStart, effects);
  EXPECT_EQ(core.queuedPackets(), 1u);
}

// A data packet's header must describe its payload exactly: its parts' splats
// fill the payload; counts past 32 bits are refused before anything is
// multiplied or summed.
// Parts read in place from a data-send's shared segment: no payload, and
// every part inside the segment, at a place a record may start.
TEST(RenderCore, ADataPacketInSharedMemoryNamesPlacesInsideTheSegment) {
  v1::DataPacketHeader header;
  header.set_byte_size(10 * sizeof(Splat));
  header.set_record_size(sizeof(Splat));
  v1::SharedSegment& shared = *header.mutable_shared();
  shared.set_byte_size(20 * sizeof(Splat));
  v1::DataPart& first = *header.add_parts();
  first.set_top_level_cell(3);
  first.set_splat_count(4);
  first.set_shared_offset(16 * sizeof(Splat));
  v1::DataPart& second = *header.add_parts();
  second.set_top_level_cell(5);
  second.set_splat_count(6);
  second.set_shared_offset(0);
  EXPECT_NO_THROW(checkDataPacketHeader(header, 0, 3));
  EXPECT_THROW(checkDataPacketHeader(header, 10 * sizeof(Splat), 3), ProtocolError);  // bytes too
  header.mutable_parts(0)->set_shared_offset(17 * sizeof(Splat));  // ends past the segment
  EXPECT_THROW(checkDataPacketHeader(header, 0, 3), ProtocolError);
  header.mutable_parts(0)->set_shared_offset(~std::uint64_t{0} - 8);  // would wrap
  EXPECT_THROW(checkDataPacketHeader(header, 0, 3), ProtocolError);
  header.mutable_parts(0)->set_shared_offset(16 * sizeof(Splat) - 2);  // not a record's start
  EXPECT_THROW(checkDataPacketHeader(header, 0, 3), ProtocolError);
  header.mutable_parts(0)->set_shared_offset(16 * sizeof(Splat));
  header.set_byte_size(9 * sizeof(Splat));  // parts hold 10
  EXPECT_THROW(checkDataPacketHeader(header, 0, 3), ProtocolError);
  header.set_byte_size(10 * sizeof(Splat));

  // The same packets in the CPU kernel's layout: each part's whole block
  // (from splat 0 to its end) inside that segment, on a cache line.
  header.mutable_shared_groups()->set_byte_size(2 * PointGroups::blockBytes(16));
  header.mutable_parts(1)->set_shared_groups_offset(PointGroups::blockBytes(16));
  EXPECT_NO_THROW(checkDataPacketHeader(header, 0, 3));
  header.mutable_parts(1)->set_first_splat(11);  // splats 0-16: two groups from there
  EXPECT_THROW(checkDataPacketHeader(header, 0, 3), ProtocolError);
  header.mutable_parts(1)->set_first_splat(0);
  header.mutable_parts(1)->set_shared_groups_offset(PointGroups::blockBytes(16) + 4);
  EXPECT_THROW(checkDataPacketHeader(header, 0, 3), ProtocolError);  // not a block's start
  header.mutable_parts(1)->set_shared_groups_offset(PointGroups::blockBytes(16));
  header.clear_shared();  // groups without the packets themselves
  EXPECT_THROW(checkDataPacketHeader(header, 10 * sizeof(Splat), 3), ProtocolError);
}

TEST(RenderCore, ADataPacketHeaderMustDescribeItsPayload) {
  v1::DataPacketHeader header;
  header.set_byte_size(10 * sizeof(Splat));
  header.set_record_size(sizeof(Splat));
  EXPECT_THROW(checkDataPacketHeader(header, 10 * sizeof(Splat), 3), ProtocolError);  // no part
  v1::DataPart& first = *header.add_parts();
  first.set_top_level_cell(3);
  first.set_splat_count(4);
  v1::DataPart& second = *header.add_parts();
  second.set_top_level_cell(5);
  second.set_first_splat(2);
  second.set_splat_count(6);
  EXPECT_NO_THROW(checkDataPacketHeader(header, 10 * sizeof(Splat), 3));
  EXPECT_THROW(checkDataPacketHeader(header, 9 * sizeof(Splat), 3), ProtocolError);
  header.set_byte_size(9 * sizeof(Splat));
  EXPECT_THROW(checkDataPacketHeader(header, 9 * sizeof(Splat), 3), ProtocolError);  // parts: 10
  header.set_byte_size(10 * sizeof(Splat));
  header.set_record_size(16);
  EXPECT_THROW(checkDataPacketHeader(header, 10 * sizeof(Splat), 3), ProtocolError);
  header.set_record_size(sizeof(Splat));
  header.mutable_parts(1)->set_splat_count(0);
  EXPECT_THROW(checkDataPacketHeader(header, 4 * sizeof(Splat), 3), ProtocolError);
  header.mutable_parts(1)->set_splat_count(std::uint64_t{1} << 59);  // times 32 wraps to 0
  header.set_byte_size(4 * sizeof(Splat));
  EXPECT_THROW(checkDataPacketHeader(header, 4 * sizeof(Splat), 3), ProtocolError);
  header.mutable_parts(1)->set_splat_count(6);
  header.set_byte_size(10 * sizeof(Splat));
  header.mutable_parts(1)->set_first_splat(std::uint64_t{1} << 33);
  try {
    checkDataPacketHeader(header, 10 * sizeof(Splat), 3);
    FAIL() << "a first splat past 32 bits was taken";
  } catch (const ProtocolError& error) {
    EXPECT_NE(std::string(error.what()).find("top-level cell 3 from rank 3"), std::string::npos);
    EXPECT_NE(std::string(error.what()).find("cell 5 names splats"), std::string::npos);
  }
}

}  // namespace
}  // namespace pointillist::render
