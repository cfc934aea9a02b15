// The traverse process's decisions (seed 003 §4.3), driven directly: where a
// walked tile goes, what is ordered from whom, what is ordered ahead, and
// how reports (and their absence) change the next choice.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <random>

#include "common/cell_ranges.hpp"
#include "common/splat.hpp"

#include "traverse/core/decision_log.hpp"
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

// Cell i's layered packet: 1000 level-splats of level 2, 4000 of level 1, then
// its points, 31'250 * (i + 1) splats in all (1 MB * (i + 1)).
constexpr std::uint32_t kSplatsPerMegabyte = 31'250;

std::uint32_t wholeCell(std::uint32_t cell) {
  return kSplatsPerMegabyte * (cell + 1);
}

std::shared_ptr<const PacketLayers> layers() {
  std::vector<TopLevelCell> topLevel(6);
  std::vector<OctreeCell> cells;
  for (std::uint32_t i = 0; i < topLevel.size(); ++i) {
    topLevel[i].levelSplatCount = 5000;
    topLevel[i].pointCount = wholeCell(i) - 5000;
    OctreeCell coarse{};
    coarse.topLevel = i;
    coarse.level = 2;
    coarse.splatsCount = 1000;
    coarse.maxSplatRadius = 0.4f;
    OctreeCell finer = coarse;
    finer.level = 1;
    finer.splatsOffset = 1000;
    finer.splatsCount = 4000;
    finer.maxSplatRadius = 0.1f;
    cells.push_back(coarse);
    cells.push_back(finer);
  }
  return std::make_shared<const PacketLayers>(cells, topLevel);
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
  return PacketPlanner(kPeers, kSelf, settings(scheduler), layers(), kOwners);
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

std::vector<CellRange> whole(std::vector<std::uint32_t> cells) {
  std::vector<CellRange> ranges;
  for (std::uint32_t cell : cells) ranges.push_back({cell, 0, wholeCell(cell)});
  return ranges;
}

std::vector<CellPrefix> wholePrefixes(std::vector<std::uint32_t> cells) {
  std::vector<CellPrefix> prefixes;
  for (std::uint32_t cell : cells) prefixes.push_back({cell, wholeCell(cell)});
  return prefixes;
}

// A walk drawing the whole of each cell, or the given ranges (sorted by cell
// and splat), as traverseTile would give it: each cell drawn from with the
// prefix that holds its ranges.
struct Walk {
  explicit Walk(std::vector<std::uint32_t> topLevel, std::uint64_t count = 10'000)
      : needs(wholePrefixes(topLevel)), splats(count) {
    for (std::uint32_t cell : topLevel) ranges.push_back({cell, 0, wholeCell(cell)});
  }
  static Walk drawing(std::vector<PacketRange> drawn, std::uint64_t count = 10) {
    Walk walk({}, count);
    walk.ranges = std::move(drawn);
    for (const PacketRange& range : walk.ranges) {
      if (walk.needs.empty() || walk.needs.back().cell != range.topLevel)
        walk.needs.push_back({range.topLevel, 0});
      walk.needs.back().splats = std::max(walk.needs.back().splats, range.offset + range.count);
    }
    return walk;
  }
  std::vector<CellPrefix> needs;
  std::uint64_t splats;
  std::vector<PacketRange> ranges;
  TileWalk view() const { return {needs, splats, ranges, {}}; }
};

v1::RenderReport report(std::uint64_t workload, std::vector<std::uint32_t> loaded = {},
                        std::uint64_t packetsDone = 0, std::uint64_t lastPacket = 0) {
  v1::RenderReport r;
  r.set_workload_splats(workload);
  for (std::uint32_t cell : loaded) {
    r.add_loaded_top_level(cell);
    r.add_loaded_first(0);
    r.add_loaded_count(wholeCell(cell));
  }
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
        std::vector<std::uint32_t>(order.range_top_level().begin(), order.range_top_level().end()));
  }
  return orders;
}

TEST(PacketPlanner, SendsThePacketToTheRenderHoldingTheDataAndOrdersTheRestFromTheirOwners) {
  PacketPlanner p = planner();
  p.applyReport(kRender1, report(0, {0, 4}), kStart);
  Outbox out;
  const Walk walk({0, 1, 4, 5});
  const PacketPlan plan = p.planPackets(task(3, 2), walk.view(), {}, kStart, out).front();
  EXPECT_EQ(plan.renderRank, kRender1);
  EXPECT_EQ(plan.choice.missing, whole({1, 5}));
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
  EXPECT_EQ(packet.range_offset_size(), 4);
  EXPECT_EQ(packet.range_top_level(3), 5u);
  EXPECT_EQ(packet.need_top_level_size(), 4);
  EXPECT_EQ(packet.need_count(1), wholeCell(1));
  // The orders leave before the packet, and the display hears it may send more.
  EXPECT_EQ(out.entries().back().kind, MessageKind::WorkRequest);
  EXPECT_EQ(out.entries().back().destinations, (std::vector<int>{0}));
}

TEST(PacketPlanner, OrderedCellsCountAsPresentUntilAReportSaysOtherwise) {
  PacketPlanner p = planner();
  Outbox first;
  const Walk walk({2});
  const PacketPlan plan = p.planPackets(task(0, 0), walk.view(), {}, kStart, first).front();
  ASSERT_EQ(ordersIn(first).size(), 1u);
  // The same cells again: the same render wins (no bytes to move) and
  // nothing is ordered twice.
  Outbox second;
  const PacketPlan again = p.planPackets(task(0, 1), walk.view(), {}, kStart, second).front();
  EXPECT_EQ(again.renderRank, plan.renderRank);
  EXPECT_TRUE(ordersIn(second).empty());
  // The render reports the cell evicted: it must be ordered again.
  v1::RenderReport evicted = report(0, {}, 2, 2);
  evicted.add_evicted_cells(2);
  p.applyReport(plan.renderRank, evicted, kStart + 1ms);
  EXPECT_EQ(p.model().heldSplats(static_cast<std::size_t>(plan.renderRank - kRender0), 2), 0u);
}

TEST(PacketPlanner, AvoidsARenderThatHasStoppedFinishingWork) {
  PacketPlanner p = planner();
  // Render 0 holds every cell; render 1 holds none.
  p.applyReport(kRender0, report(0, {0, 1, 2, 3, 4, 5}, 0, 0), kStart);
  p.applyReport(kRender1, report(0), kStart);
  const Walk walk({1}, 1000);
  Outbox out;
  EXPECT_EQ(p.planPackets(task(0, 0), walk.view(), {}, kStart, out).front().renderRank, kRender0);
  // It acknowledges the packet but never finishes one.
  p.applyReport(kRender0, report(1000, {}, 0, 1), kStart + 100ms);
  EXPECT_EQ(p.planPackets(task(0, 1), walk.view(), {}, kStart + 200ms, out).front().renderRank,
            kRender0);
  // After a second with work and no progress it is suspected stalled: the
  // work goes to render 1, although the data has to move.
  const PacketPlan moved = p.planPackets(task(1, 0), walk.view(), {}, kStart + 2s, out).front();
  EXPECT_EQ(moved.renderRank, kRender1);
  EXPECT_EQ(moved.choice.missing, whole({1}));
  // Progress clears the suspicion.
  p.applyReport(kRender0, report(0, {}, 3, 3), kStart + 2100ms);
  EXPECT_EQ(p.planPackets(task(1, 1), Walk({3}, 1000).view(), {}, kStart + 2200ms, out)
                .front()
                .renderRank,
            kRender0);
}

// A render the display suspects (it holds an overdue tile) gets no packet,
// whichever scheduler chose it, unless every live render is suspected; the
// work request tells the display where the tile went.
TEST(PacketPlanner, SendsNoPacketToARenderTheDisplaySuspectsAndSaysWhereTheTileWent) {
  for (const v1::Scheduler scheduler :
       {v1::SCHEDULER_COST, v1::SCHEDULER_REGIONS, v1::SCHEDULER_STATIC}) {
    SCOPED_TRACE(v1::Scheduler_Name(scheduler));
    PacketPlanner p = planner(scheduler);
    p.applyReport(kRender0, report(0, {0, 1, 2, 3, 4, 5}), kStart);  // holds every cell
    p.applyReport(kRender1, report(0), kStart);
    v1::TileTask suspected = task(4, 2);
    suspected.set_attempt(1);
    suspected.set_assigned_render(0);
    suspected.add_avoid_renders(0);
    Outbox out;
    const PacketPlan plan =
        p.planPackets(suspected, Walk({1}, 1000).view(), {}, kStart, out).front();
    EXPECT_EQ(plan.renderRank, kRender1);
    EXPECT_EQ(plan.choice.missing, whole({1}));
    const auto& request = out.entries().back();
    ASSERT_EQ(request.kind, MessageKind::WorkRequest);
    const auto& placements = request.as<v1::WorkRequest>().placements();
    ASSERT_EQ(placements.size(), 1);
    EXPECT_EQ(placements[0].frame_id(), 4u);
    EXPECT_EQ(placements[0].tile_id(), 2u);
    EXPECT_EQ(placements[0].attempt(), 1u);
    EXPECT_EQ(placements[0].render(), 1u);
    // Every render suspected: the choice stands.
    suspected.add_avoid_renders(1);
    Outbox all;
    EXPECT_EQ(p.planPackets(suspected, Walk({1}, 1000).view(), {}, kStart, all).front().renderRank,
              kRender0);
    EXPECT_NE(p.summary().find("avoided_suspects=1 "), std::string::npos) << p.summary();
  }
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
  const auto ahead = wholePrefixes({1, 2, 3, 5});
  const PacketPlan plan =
      p.planPackets(withLookahead, Walk({1}).view(), ahead, kStart, out).front();
  EXPECT_EQ(plan.prefetch, whole({2, 3}));
  EXPECT_EQ(plan.prefetchBytes, 7'000'000u);
  EXPECT_EQ(ordersIn(out),
            (std::vector<std::pair<int, std::vector<std::uint32_t>>>{{2, {1, 2}}, {3, {3}}}));
  EXPECT_EQ(packetIn(out).prefetch_bytes(), 7'000'000u);
  // A planner of another scheduler does not prefetch.
  EXPECT_FALSE(planner(v1::SCHEDULER_ROUND_ROBIN).lookaheadCamera(withLookahead));
}

std::vector<CellRange> rangesIn(const Outbox& out) {
  std::vector<CellRange> ranges;
  for (const Outgoing& outgoing : out.entries()) {
    if (outgoing.kind != MessageKind::SendOrder) continue;
    const auto& order = outgoing.as<v1::SendOrder>();
    for (int i = 0; i < order.range_top_level_size(); ++i)
      ranges.push_back({order.range_top_level(i), order.range_first(i), order.range_count(i)});
  }
  return ranges;
}

std::vector<CellRange> needsOf(const v1::RenderPacket& packet) {
  return rangesFromFields(packet.need_top_level(), packet.need_first(), packet.need_count(),
                          "packet");
}

// A tile needs the ranges it draws wherever they lie in the packet's layers
// (not a prefix through them), the packet waits for those, and only what the
// render lacks of them is ordered and counted in the cost.
TEST(PacketPlanner, NeedsTheDrawnRangesAndOrdersOnlyWhatTheRenderLacksOfThem) {
  PacketPlanner p = planner();
  v1::RenderReport coarse = report(0);
  coarse.add_loaded_top_level(0);
  coarse.add_loaded_first(0);
  coarse.add_loaded_count(1000);
  p.applyReport(kRender0, coarse, kStart);
  p.applyReport(kRender1, report(0), kStart);
  Outbox out;
  // Splats 200-700 of cell 0 lie in the first 1000, which render 0 holds.
  PacketPlan plan =
      p.planPackets(task(0, 0), Walk::drawing({{0, 200, 500}}).view(), {}, kStart, out).front();
  EXPECT_EQ(plan.renderRank, kRender0);
  EXPECT_EQ(plan.needs, (std::vector<CellRange>{{0, 200, 500}}));
  EXPECT_TRUE(ordersIn(out).empty());
  EXPECT_EQ(needsOf(packetIn(out)), plan.needs);
  // Two ranges, one reaching past the held 1000 and one in the points: the
  // order names what lies beyond 1000 of the first and all of the second,
  // and nothing between them.
  Outbox closer;
  plan = p.planPackets(task(0, 1), Walk::drawing({{0, 800, 400}, {0, 6000, 100}}).view(), {},
                       kStart, closer)
             .front();
  EXPECT_EQ(plan.renderRank, kRender0);
  EXPECT_EQ(plan.needs, (std::vector<CellRange>{{0, 800, 400}, {0, 6000, 100}}));
  EXPECT_EQ(rangesIn(closer), (std::vector<CellRange>{{0, 1000, 200}, {0, 6000, 100}}));
  EXPECT_EQ(packetIn(closer).ordered_bytes(), 300u * sizeof(Splat));
  EXPECT_EQ(packetIn(closer).ordered_bytes_held_elsewhere(), 0u);  // render 1 holds none
  EXPECT_EQ(needsOf(packetIn(closer)), plan.needs);
  // Ranges a few splats apart are needed as one; farther apart, apart.
  Outbox gaps;
  plan = p.planPackets(task(0, 2),
                       Walk::drawing({{0, 2000, 10},
                                      {0, 2010 + kNeedGapSplatsCopied, 10},
                                      {0, 3000, 10},
                                      {0, 3011 + kNeedGapSplatsCopied, 5}})
                           .view(),
                       {}, kStart, gaps)
             .front();
  EXPECT_EQ(plan.needs, (std::vector<CellRange>{{0, 2000, 20 + kNeedGapSplatsCopied},
                                                {0, 3000, 10},
                                                {0, 3011 + kNeedGapSplatsCopied, 5}}));
  // A need beyond the packet is refused.
  EXPECT_THROW(
      p.planPackets(task(0, 3), Walk::drawing({{0, wholeCell(0), 1}}).view(), {}, kStart, out),
      ProtocolError);
}

TEST(PacketPlanner, OtherSchedulersTakeTheDisplaysChoice) {
  PacketPlanner p = planner(v1::SCHEDULER_STATIC);
  p.applyReport(kRender0, report(0, {0}), kStart);
  v1::TileTask assigned = task(0, 0);
  assigned.set_assigned_render(1);
  Outbox out;
  const PacketPlan plan = p.planPackets(assigned, Walk({0}).view(), {}, kStart, out).front();
  EXPECT_EQ(plan.renderRank, kRender1);
  EXPECT_EQ(ordersIn(out), (std::vector<std::pair<int, std::vector<std::uint32_t>>>{{2, {0}}}));
}

// A served frame's settings: its scheduler decides for its tile, its level
// of detail sets the walk, and the render packet carries them on (the mode).
TEST(PacketPlanner, AServedFramesSettingsOverrideTheRunsForItsTile) {
  PacketPlanner p = planner(v1::SCHEDULER_COST);
  // The cost function would pick render 0, which holds cell 0.
  p.applyReport(kRender0, report(0, {0}), kStart);
  v1::TileTask served = task(0, 0);
  served.set_assigned_render(1);
  served.mutable_frame_settings()->set_scheduler(v1::SCHEDULER_STATIC);
  served.mutable_frame_settings()->set_mode(v1::RENDER_MODE_SPLATS);
  served.mutable_frame_settings()->set_lod_pixels(3.0f);
  EXPECT_EQ(p.schedulerFor(served), v1::SCHEDULER_STATIC);
  EXPECT_EQ(p.traversalFor(served).lodPixels, 3.0f);
  EXPECT_EQ(p.traversalFor(task(0, 1)).lodPixels, 1.0f) << "a plain task walks at the run's";
  Outbox out;
  int destination = -1;
  const PacketPlan plan = p.planPackets(served, Walk({0}).view(), {}, kStart, out).front();
  EXPECT_EQ(plan.renderRank, kRender1) << "the frame's scheduler took the display's choice";
  const v1::RenderPacket& packet = packetIn(out, &destination);
  EXPECT_EQ(destination, kRender1);
  EXPECT_EQ(packet.frame_settings().mode(), v1::RENDER_MODE_SPLATS);
  EXPECT_EQ(packet.frame_settings().lod_pixels(), 3.0f);

  Outbox plainOut;
  p.planPackets(task(0, 2), Walk({0}).view(), {}, kStart, plainOut);
  EXPECT_FALSE(packetIn(plainOut).has_frame_settings());
}

TEST(PacketPlanner, RefusesStrangersAndCellsOutsideTheDataset) {
  PacketPlanner p = planner();
  EXPECT_THROW(p.applyReport(2, report(0), kStart), ProtocolError);
  Outbox out;
  EXPECT_THROW(p.planPackets(task(0, 0), Walk({6}).view(), {}, kStart, out), ProtocolError);
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

namespace pointillist::traverse {
namespace {

// A walk over cells 0..n-1 drawing `drawn[i]` splats of cell i, as two ranges
// per cell (a level-splat run and a point run).
struct SplitCase {
  explicit SplitCase(std::vector<std::uint32_t> drawnPerCell) : drawn(std::move(drawnPerCell)) {
    for (std::uint32_t cell = 0; cell < drawn.size(); ++cell) {
      needs.push_back({cell, 5000 + drawn[cell]});
      ranges.push_back({cell, 0, drawn[cell] / 2});
      ranges.push_back({cell, 5000, drawn[cell] - drawn[cell] / 2});
      splats += drawn[cell];
    }
  }
  TileWalk withRanges() const { return {needs, splats, ranges, {}}; }
  std::vector<std::uint32_t> drawn;
  std::vector<CellPrefix> needs;
  std::vector<PacketRange> ranges;
  std::uint64_t splats = 0;
};

TEST(SplitWalk, PartsAreRunsOfWholeCellsCoveringTheWalkOnceNearEqualShares) {
  std::mt19937 rng(5);
  for (int trial = 0; trial < 200; ++trial) {
    std::vector<std::uint32_t> drawn(1 + rng() % 40);
    for (std::uint32_t& d : drawn)
      d = static_cast<std::uint32_t>(2 + rng() % (trial % 2 == 0 ? 3000 : 300));
    const SplitCase walk(drawn);
    const std::size_t asked = 1 + rng() % 12;
    const std::vector<WalkPart> parts = splitWalk(walk.withRanges(), asked);
    ASSERT_FALSE(parts.empty());
    EXPECT_EQ(parts.size(), std::min(asked, drawn.size()));
    const std::uint32_t largest = *std::max_element(drawn.begin(), drawn.end());
    const double share = static_cast<double>(walk.splats) / static_cast<double>(parts.size());
    std::size_t need = 0, range = 0;
    std::uint64_t splats = 0;
    for (const WalkPart& part : parts) {
      EXPECT_EQ(part.firstNeed, need);  // contiguous, in order, nothing left out
      EXPECT_EQ(part.firstRange, range);
      EXPECT_LT(part.firstNeed, part.endNeed);
      EXPECT_GT(part.splats, 0u);
      std::uint64_t counted = 0;
      for (std::size_t r = part.firstRange; r < part.endRange; ++r) {
        counted += walk.ranges[r].count;
        EXPECT_GE(walk.ranges[r].topLevel, walk.needs[part.firstNeed].cell);
        EXPECT_LE(walk.ranges[r].topLevel, walk.needs[part.endNeed - 1].cell);
      }
      EXPECT_EQ(counted, part.splats);
      // A cut is never further from its share than the cell it falls in.
      EXPECT_LE(std::abs(static_cast<double>(part.splats) - share), 2.0 * largest + 1.0);
      need = part.endNeed;
      range = part.endRange;
      splats += part.splats;
    }
    EXPECT_EQ(need, walk.needs.size());
    EXPECT_EQ(range, walk.ranges.size());
    EXPECT_EQ(splats, walk.splats);
  }
  // Equal cells cut exactly.
  const std::vector<WalkPart> even = splitWalk(SplitCase({10, 10, 10, 10, 10, 10}).withRanges(), 3);
  ASSERT_EQ(even.size(), 3u);
  for (const WalkPart& part : even) EXPECT_EQ(part.splats, 20u);
  EXPECT_EQ(splitWalk(SplitCase({500}).withRanges(), 4).size(), 1u);
}

TEST(SplitWalk, RangesOfACellTheWalkDoesNotNeedAreRefused) {
  SplitCase walk({10, 10});
  walk.ranges.push_back({7, 0, 3});
  EXPECT_THROW(splitWalk(walk.withRanges(), 2), ProtocolError);
  // Needs without any ranges: nothing to say what is drawn.
  walk.ranges.clear();
  EXPECT_THROW(splitWalk(walk.withRanges(), 2), ProtocolError);
}

v1::TileTask splitTask(std::uint64_t partSplats) {
  v1::TileTask t = task(2, 5);
  t.set_part_splats(partSplats);
  return t;
}

std::vector<std::pair<int, v1::RenderPacket>> packetsIn(const Outbox& out) {
  std::vector<std::pair<int, v1::RenderPacket>> packets;
  for (const Outgoing& outgoing : out.entries()) {
    if (outgoing.kind == MessageKind::RenderPacket) {
      packets.emplace_back(outgoing.destinations.at(0), outgoing.as<v1::RenderPacket>());
    }
  }
  return packets;
}

TEST(PacketPlanner, AHeavyTileIsSplitByItsCellsAndThePartsGoWhereTheirDataIs) {
  PacketPlanner p = planner();
  // Render 1 holds cells 3-5, render 0 cells 0-2.
  p.applyReport(kRender0, report(0, {0, 1, 2}), kStart);
  p.applyReport(kRender1, report(0, {3, 4, 5}), kStart);
  const SplitCase walk({3000, 3000, 3000, 3000, 3000, 3000});
  Outbox out;
  const std::vector<PacketPlan> plans =
      p.planPackets(splitTask(8000), walk.withRanges(), {}, kStart, out);
  ASSERT_EQ(plans.size(), 2u);  // 18000 / 8000 parts, as many as live renders
  const auto packets = packetsIn(out);
  ASSERT_EQ(packets.size(), 2u);
  EXPECT_EQ(packets[0].first, kRender0);
  EXPECT_EQ(packets[1].first, kRender1);
  std::uint64_t splats = 0;
  for (std::uint32_t i = 0; i < 2; ++i) {
    const v1::RenderPacket& packet = packets[i].second;
    EXPECT_EQ(packet.part_index(), i);
    EXPECT_EQ(packet.part_count(), 2u);
    EXPECT_EQ(packet.tile_id(), 5u);
    EXPECT_EQ(packet.total_splats(), 9000u);
    EXPECT_EQ(packet.ordered_bytes(), 0u);  // each part's cells are where it went
    for (int r = 0; r < packet.range_top_level_size(); ++r) {
      EXPECT_EQ(packet.range_top_level(r) / 3, i) << "part " << i << " draws only its own cells";
      splats += packet.range_count(r);
    }
    EXPECT_EQ(plans[i].partIndex, i);
    EXPECT_EQ(plans[i].partCount, 2u);
  }
  EXPECT_EQ(splats, walk.splats);
  EXPECT_TRUE(ordersIn(out).empty());
  // One tile done, one more asked for.
  EXPECT_EQ(std::count_if(out.entries().begin(), out.entries().end(),
                          [](const Outgoing& o) { return o.kind == MessageKind::WorkRequest; }),
            1);
  EXPECT_EQ(p.tasksDone(), 1u);
  EXPECT_EQ(p.tilesSplit(), 1u);
}

// Each part's packet carries the box its cells draw in, inside the tile: the
// image the part sends is no bigger (the simulator sends that much).
TEST(PacketPlanner, APartCarriesTheBoxOfItsCellsInsideItsTile) {
  PacketPlanner p = planner();
  p.applyReport(kRender0, report(0, {0, 1, 2}), kStart);
  p.applyReport(kRender1, report(0, {3, 4, 5}), kStart);
  SplitCase split({3000, 3000, 3000, 3000, 3000, 3000});
  // The tile is (0,0) 64x64; cells 0-2 draw on its left, 3-5 reach past its top.
  const std::vector<ScreenBox> boxes = {{2.5f, 1.0f, 10.0f, 20.0f},   {5.0f, 8.0f, 20.2f, 12.0f},
                                        {9.0f, 3.0f, 12.0f, 4.0f},    {40.0f, 30.0f, 50.0f, 90.0f},
                                        {33.0f, 40.0f, 34.0f, 41.0f}, {}};
  TileWalk walk = split.withRanges();
  walk.needBoxes = boxes;
  Outbox out;
  ASSERT_EQ(p.planPackets(splitTask(8000), walk, {}, kStart, out).size(), 2u);
  const auto packets = packetsIn(out);
  ASSERT_EQ(packets.size(), 2u);
  const v1::TileRect& left = packets[0].second.screen_box();
  EXPECT_EQ(left.x(), 2u);
  EXPECT_EQ(left.y(), 1u);
  EXPECT_EQ(left.width(), 19u);  // to 20.2, rounded up
  EXPECT_EQ(left.height(), 19u);
  const v1::TileRect& right = packets[1].second.screen_box();
  EXPECT_EQ(right.x(), 33u);
  EXPECT_EQ(right.y(), 30u);
  EXPECT_EQ(right.width(), 17u);
  EXPECT_EQ(right.height(), 34u) << "clipped at the tile's top";

  // Without boxes (a walk that made none) a part carries none: its whole tile.
  PacketPlanner q = planner();
  q.applyReport(kRender0, report(0, {0, 1, 2}), kStart);
  q.applyReport(kRender1, report(0, {3, 4, 5}), kStart);
  Outbox plain;
  ASSERT_EQ(q.planPackets(splitTask(8000), split.withRanges(), {}, kStart, plain).size(), 2u);
  for (const auto& [rank, packet] : packetsIn(plain)) EXPECT_FALSE(packet.has_screen_box());
}

TEST(PacketPlanner, ATileIsSplitOnlyWhereComposingItsPartsIsExact) {
  const SplitCase walk({3000, 3000, 3000, 3000, 3000, 3000});
  const auto partsSent = [&](const v1::RunSettings& run, const v1::TileTask& t) {
    PacketPlanner p(kPeers, kSelf, run, layers(), kOwners);
    Outbox out;
    return p.planPackets(t, walk.withRanges(), {}, kStart, out).size();
  };
  EXPECT_EQ(partsSent(settings(), splitTask(8000)), 2u);
  EXPECT_EQ(partsSent(settings(v1::SCHEDULER_REGIONS), splitTask(8000)), 2u);
  EXPECT_EQ(partsSent(settings(), splitTask(0)), 1u) << "the display did not ask";
  EXPECT_EQ(partsSent(settings(), splitTask(9001)), 1u) << "less than two parts' worth";
  EXPECT_EQ(partsSent(settings(v1::SCHEDULER_ROUND_ROBIN), splitTask(8000)), 1u);
  v1::RunSettings gl = settings();
  gl.set_renderer(v1::RENDERER_GL);
  EXPECT_EQ(partsSent(gl, splitTask(8000)), 1u) << "GL's depth ties depend on order";
  v1::RunSettings edl = settings();
  edl.set_edl(true);
  EXPECT_EQ(partsSent(edl, splitTask(8000)), 1u) << "EDL shades from neighbours' depth";
  v1::TileTask depth = splitTask(8000);
  depth.mutable_frame_settings()->set_tile_depth(true);
  EXPECT_EQ(partsSent(settings(), depth), 1u) << "the render cache wants eye-space depth";
  v1::TileTask splats = splitTask(8000);
  splats.mutable_frame_settings()->set_mode(v1::RENDER_MODE_SPLATS);
  EXPECT_EQ(partsSent(settings(), splats), 1u) << "blended splats do not compose by a minimum";
}

// A walk that found nothing costs no render a packet: the display gets the
// tile's background from the traverse, and the decision log keeps it.
TEST(PacketPlanner, AnEmptyWalkIsAnsweredAsBackgroundWithoutARenderPacket) {
  for (const v1::Scheduler scheduler :
       {v1::SCHEDULER_COST, v1::SCHEDULER_REGIONS, v1::SCHEDULER_STATIC}) {
    PacketPlanner p = planner(scheduler);
    v1::TileTask empty = task(7, 3);
    empty.set_attempt(2);
    empty.mutable_rect()->set_x(128);
    empty.set_assigned_render(1);
    Outbox out;
    EXPECT_TRUE(p.planPackets(empty, Walk({}, 0).view(), {}, kStart, out).empty());
    ASSERT_EQ(out.entries().size(), 2u);
    const Outgoing& answer = out.entries().front();
    ASSERT_EQ(answer.kind, MessageKind::TileImage);
    EXPECT_EQ(answer.destinations, (std::vector<int>{kPeers.display}));
    const auto& header = answer.as<v1::TileImageHeader>();
    EXPECT_EQ(header.format(), v1::PIXEL_FORMAT_BACKGROUND);
    EXPECT_EQ(header.frame_id(), 7u);
    EXPECT_EQ(header.tile_id(), 3u);
    EXPECT_EQ(header.attempt(), 2u);
    EXPECT_EQ(header.rect().x(), 128u);
    EXPECT_EQ(header.rect().width(), 64u);
    EXPECT_EQ(header.traverse_rank(), kSelf);
    EXPECT_EQ(header.render_rank(), -1);
    EXPECT_EQ(out.entries().back().kind, MessageKind::WorkRequest);
    EXPECT_EQ(p.emptyTiles(), 1u);
    EXPECT_EQ(p.tasksDone(), 1u);
    const auto outputs = decisionOutputs(out.entries());
    ASSERT_EQ(outputs.size(), 2u);
    EXPECT_TRUE(outputs.front().has_tile_image());
    EXPECT_EQ(outputs.front().tile_image().tile_id(), 3u);

    // A walk with something to draw still goes to a render.
    Outbox drawn;
    EXPECT_EQ(p.planPackets(task(7, 4), Walk({0}, 1).view(), {}, kStart, drawn).size(), 1u);
    EXPECT_NO_THROW(packetIn(drawn));
    EXPECT_EQ(p.emptyTiles(), 1u);
  }
}

}  // namespace
}  // namespace pointillist::traverse
