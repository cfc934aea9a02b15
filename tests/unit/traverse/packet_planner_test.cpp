// The traverse process's decisions (seed 003 §4.3), driven directly: where a
// walked tile goes, what is ordered from whom, what is ordered ahead, and
// how reports (and their absence) change the next choice.
#include <gtest/gtest.h>

#include <algorithm>

#include "traverse/core/packet_planner.hpp"

namespace pointillist::traverse {
namespace {

using namespace std::chrono_literals;

// Layout 1,1,2,2: display 0, the traverse 1, data-sends 2-3, renders 4-5.
const PeerRanks kPeers = PeerRanks::contiguous(JobLayout{1, 1, 2, 2});
constexpr int kSelf = 1;
constexpr int kRender0 = 4;
constexpr int kRender1 = 5;
const TimePoint kStart = timeAfterEpoch(50.0);

std::vector<TopLevelCell> table() {
  std::vector<TopLevelCell> topLevel(6);
  for (std::size_t i = 0; i < topLevel.size(); ++i) {
    topLevel[i].byteSize = 1'000'000 * (i + 1);
    topLevel[i].byteOffset = i * 10'000'000;
  }
  return topLevel;
}

// Cells 0-2 belong to data-send 2, cells 3-5 to data-send 3.
const std::vector<std::uint32_t> kOwners{0, 0, 0, 1, 1, 1};

v1::RunSettings settings(v1::Scheduler scheduler = v1::SCHEDULER_COST) {
  v1::RunSettings s;
  s.set_mode(v1::RENDER_MODE_POINTS);
  s.set_lod_pixels(1.0f);
  s.set_size_scale(1.0f);
  s.set_scheduler(scheduler);
  return s;
}

PacketPlanner planner(v1::Scheduler scheduler = v1::SCHEDULER_COST) {
  return PacketPlanner(kPeers, kSelf, settings(scheduler), table(), kOwners);
}

v1::TileTask task(std::uint64_t frame, std::uint32_t tile) {
  v1::TileTask t;
  t.set_frame_id(frame);
  t.set_tile_id(tile);
  t.mutable_rect()->set_width(64);
  t.mutable_rect()->set_height(64);
  t.mutable_camera()->set_image_width(640);
  t.mutable_camera()->set_image_height(480);
  return t;
}

struct Walk {
  explicit Walk(std::vector<std::uint32_t> topLevel, std::uint64_t count = 10'000,
                std::vector<PacketRange> drawn = {})
      : cells(std::move(topLevel)), splats(count), ranges(std::move(drawn)) {}
  std::vector<std::uint32_t> cells;
  std::uint64_t splats;
  std::vector<PacketRange> ranges;
  TileWalk view() const { return {cells, splats, ranges}; }
};

v1::RenderReport report(std::uint64_t workload, std::vector<std::uint32_t> loaded = {},
                        std::uint64_t packetsDone = 0, std::uint64_t lastPacket = 0) {
  v1::RenderReport r;
  r.set_workload_splats(workload);
  for (std::uint32_t cell : loaded) r.add_loaded_cells(cell);
  r.set_packets_done(packetsDone);
  r.add_last_packet_from_traverse(lastPacket);
  r.set_seconds_per_splat(1e-7);
  r.set_seconds_per_byte(1e-8);
  return r;
}

const v1::RenderPacket& packetIn(const Outbox& out, int* destination = nullptr) {
  for (const Outgoing& outgoing : out.entries()) {
    if (outgoing.kind == MessageKind::RenderPacket) {
      if (destination != nullptr) *destination = outgoing.destinations.at(0);
      return outgoing.as<v1::RenderPacket>();
    }
  }
  throw std::runtime_error("no render packet in the outbox");
}

std::vector<std::pair<int, std::vector<std::uint32_t>>> ordersIn(const Outbox& out) {
  std::vector<std::pair<int, std::vector<std::uint32_t>>> orders;
  for (const Outgoing& outgoing : out.entries()) {
    if (outgoing.kind != MessageKind::SendOrder) continue;
    const auto& order = outgoing.as<v1::SendOrder>();
    orders.emplace_back(
        outgoing.destinations.at(0),
        std::vector<std::uint32_t>(order.top_level_cells().begin(), order.top_level_cells().end()));
  }
  return orders;
}

TEST(PacketPlanner, SendsThePacketToTheRenderHoldingTheDataAndOrdersTheRestFromTheirOwners) {
  PacketPlanner p = planner();
  p.applyReport(kRender1, report(0, {0, 4}), kStart);
  Outbox out;
  const Walk walk({0, 1, 4, 5}, 10'000, {{0, 0, 10}, {5, 3, 7}});
  const PacketPlan plan = p.planPacket(task(3, 2), walk.view(), {}, kStart, out);
  EXPECT_EQ(plan.renderRank, kRender1);
  EXPECT_EQ(plan.choice.missingCells, (std::vector<std::uint32_t>{1, 5}));
  EXPECT_EQ(ordersIn(out),
            (std::vector<std::pair<int, std::vector<std::uint32_t>>>{{2, {1}}, {3, {5}}}));
  for (const Outgoing& outgoing : out.entries()) {
    if (outgoing.kind != MessageKind::SendOrder) continue;
    EXPECT_EQ(outgoing.as<v1::SendOrder>().render_rank(), kRender1);
    EXPECT_EQ(outgoing.as<v1::SendOrder>().requester_rank(), kSelf);
    EXPECT_EQ(outgoing.as<v1::SendOrder>().frame_id(), 3u);
  }
  int destination = 0;
  const v1::RenderPacket& packet = packetIn(out, &destination);
  EXPECT_EQ(destination, kRender1);
  EXPECT_EQ(packet.frame_id(), 3u);
  EXPECT_EQ(packet.tile_id(), 2u);
  EXPECT_EQ(packet.traverse_rank(), kSelf);
  EXPECT_EQ(packet.packet_id(), 1u);
  EXPECT_EQ(packet.total_splats(), 10'000u);
  EXPECT_EQ(packet.ordered_bytes(), 2'000'000u + 6'000'000u);
  EXPECT_EQ(packet.range_offset_size(), 2);
  EXPECT_EQ(packet.range_top_level(1), 5u);
  // The orders leave before the packet, and the display hears it may send more.
  EXPECT_EQ(out.entries().back().kind, MessageKind::WorkRequest);
  EXPECT_EQ(out.entries().back().destinations, (std::vector<int>{0}));
}

TEST(PacketPlanner, OrderedCellsCountAsPresentUntilAReportSaysOtherwise) {
  PacketPlanner p = planner();
  Outbox first;
  const Walk walk({2});
  const PacketPlan plan = p.planPacket(task(0, 0), walk.view(), {}, kStart, first);
  ASSERT_EQ(ordersIn(first).size(), 1u);
  // The same cells again: the same render wins (no bytes to move) and
  // nothing is ordered twice.
  Outbox second;
  const PacketPlan again = p.planPacket(task(0, 1), walk.view(), {}, kStart, second);
  EXPECT_EQ(again.renderRank, plan.renderRank);
  EXPECT_TRUE(ordersIn(second).empty());
  // The render reports the cell evicted: it must be ordered again.
  v1::RenderReport evicted = report(0, {}, 2, 2);
  evicted.add_evicted_cells(2);
  p.applyReport(plan.renderRank, evicted, kStart + 1ms);
  EXPECT_FALSE(p.model().hasCell(static_cast<std::size_t>(plan.renderRank - kRender0), 2));
}

TEST(PacketPlanner, AvoidsARenderThatHasStoppedFinishingWork) {
  PacketPlanner p = planner();
  // Render 0 holds every cell; render 1 holds none.
  p.applyReport(kRender0, report(0, {0, 1, 2, 3, 4, 5}, 0, 0), kStart);
  p.applyReport(kRender1, report(0), kStart);
  const Walk walk({1}, 1000);
  Outbox out;
  EXPECT_EQ(p.planPacket(task(0, 0), walk.view(), {}, kStart, out).renderRank, kRender0);
  // It acknowledges the packet but never finishes one.
  p.applyReport(kRender0, report(1000, {}, 0, 1), kStart + 100ms);
  EXPECT_EQ(p.planPacket(task(0, 1), walk.view(), {}, kStart + 200ms, out).renderRank, kRender0);
  // After a second with work and no progress it is suspected stalled: the
  // work goes to render 1, although the data has to move.
  const PacketPlan moved = p.planPacket(task(1, 0), walk.view(), {}, kStart + 2s, out);
  EXPECT_EQ(moved.renderRank, kRender1);
  EXPECT_EQ(moved.choice.missingCells, (std::vector<std::uint32_t>{1}));
  // Progress clears the suspicion.
  p.applyReport(kRender0, report(0, {}, 3, 3), kStart + 2100ms);
  EXPECT_EQ(p.planPacket(task(1, 1), Walk({3}, 1000).view(), {}, kStart + 2200ms, out).renderRank,
            kRender0);
}

TEST(PacketPlanner, PrefetchesWhatTheRectNeedsLaterWithinTheBudgetWithoutDuplicates) {
  PacketPlanner p = planner();
  v1::TileTask withLookahead = task(0, 0);
  *withLookahead.mutable_lookahead_camera() = withLookahead.camera();
  ASSERT_TRUE(p.lookaheadCamera(withLookahead));
  EXPECT_FALSE(p.lookaheadCamera(task(0, 0)));
  Outbox out;
  // Cell 1 is needed now; 1 (again), 2 and 3 later. The 8 MiB budget takes
  // 2 (3 MB) and 3 (4 MB), not 5 (6 MB more).
  const std::uint32_t ahead[] = {1, 2, 3, 5};
  const PacketPlan plan = p.planPacket(withLookahead, Walk({1}).view(), ahead, kStart, out);
  EXPECT_EQ(plan.prefetchCells, (std::vector<std::uint32_t>{2, 3}));
  EXPECT_EQ(plan.prefetchBytes, 7'000'000u);
  EXPECT_EQ(ordersIn(out),
            (std::vector<std::pair<int, std::vector<std::uint32_t>>>{{2, {1, 2}}, {3, {3}}}));
  EXPECT_EQ(packetIn(out).prefetch_bytes(), 7'000'000u);
  // A planner of another scheduler does not prefetch.
  EXPECT_FALSE(planner(v1::SCHEDULER_ROUND_ROBIN).lookaheadCamera(withLookahead));
}

TEST(PacketPlanner, OtherSchedulersTakeTheDisplaysChoice) {
  PacketPlanner p = planner(v1::SCHEDULER_STATIC);
  p.applyReport(kRender0, report(0, {0}), kStart);
  v1::TileTask assigned = task(0, 0);
  assigned.set_assigned_render(1);
  Outbox out;
  const PacketPlan plan = p.planPacket(assigned, Walk({0}).view(), {}, kStart, out);
  EXPECT_EQ(plan.renderRank, kRender1);
  EXPECT_EQ(ordersIn(out), (std::vector<std::pair<int, std::vector<std::uint32_t>>>{{2, {0}}}));
}

TEST(PacketPlanner, RefusesStrangersAndCellsOutsideTheDataset) {
  PacketPlanner p = planner();
  EXPECT_THROW(p.applyReport(2, report(0), kStart), ProtocolError);
  Outbox out;
  EXPECT_THROW(p.planPacket(task(0, 0), Walk({6}).view(), {}, kStart, out), ProtocolError);
}

TEST(PacketPlanner, TraversalSettingsComeFromTheRunSettings) {
  v1::RunSettings s = settings();
  s.set_lod_pixels(2.5f);
  s.set_size_scale(0.0f);  // unset: 1
  s.set_backface_cull(true);
  const TraversalSettings traversal = traversalSettings(s);
  EXPECT_EQ(traversal.lodPixels, 2.5f);
  EXPECT_EQ(traversal.sizeScale, 1.0f);
  EXPECT_TRUE(traversal.backfaceCull);
}

// Eye-dome lighting draws tiles grown by a halo: the traverse culls for it.
TEST(PacketPlanner, EyeDomeLightingGrowsTheCullingMargin) {
  v1::RunSettings s = settings();
  const float plain = traversalSettings(s).marginPixels;
  s.set_edl(true);
  s.set_edl_strength(1.0f);
  s.set_edl_radius(2.5f);
  EXPECT_EQ(traversalSettings(s).marginPixels, plain + 3.0f);
  s.set_edl_radius(1.4f);
  EXPECT_EQ(traversalSettings(s).marginPixels, plain + 2.0f);
}

}  // namespace
}  // namespace pointillist::traverse
