// The cost function of seed 003 §4.3 and the traverse's model of render processes.
#include <gtest/gtest.h>

#include <set>

#include "common/cell_ranges.hpp"
#include "common/errors.hpp"
#include "common/splat.hpp"
#include "traverse/core/render_model.hpp"

namespace pointillist::traverse {
namespace {

// Cores are told the time; these tests need only one moment.
const RenderModel::Clock::time_point kNow{};

// Whole-packet sizes in bytes (multiples of the 32-byte splat) per cell.
using Table = std::vector<std::uint64_t>;

// The whole packets of `ids`: what a render needs or holds of them.
std::vector<CellRange> whole(const Table& table, std::initializer_list<std::uint32_t> ids) {
  std::vector<CellRange> ranges;
  for (std::uint32_t id : ids) {
    ranges.push_back({id, 0, static_cast<std::uint32_t>(table.at(id) / sizeof(Splat))});
  }
  return ranges;
}

TEST(RenderModel, PrefersTheRenderThatHasTheData) {
  const Table cells{1'000'000, 2'000'000, 512};
  RenderModel model(3);
  const auto loaded = whole(cells, {0, 1});
  model.applyReport(1, {.workloadSplats = 0, .loaded = loaded}, kNow);
  const auto needed = whole(cells, {0, 1});
  const auto choice = model.choose(needed, 1000, kNow);
  EXPECT_EQ(choice.render, 1u);
  EXPECT_EQ(choice.missingBytes, 0u);
  EXPECT_TRUE(choice.missing.empty());
}

TEST(RenderModel, PrefersAnIdleRenderWhenWorkOutweighsTheTransfer) {
  const Table cells{1024, 1024};
  RenderModel model(2);
  const auto loaded = whole(cells, {0});
  // Render 0 has the data but 10 M splats queued (2 s at 5 M/s); moving 1 KiB costs ~10 us.
  model.applyReport(0, {.workloadSplats = 10'000'000, .loaded = loaded}, kNow);
  const auto needed = whole(cells, {0});
  const auto choice = model.choose(needed, 100, kNow);
  EXPECT_EQ(choice.render, 1u);
  EXPECT_EQ(choice.missingBytes, 1024u);
  ASSERT_EQ(choice.missing.size(), 1u);
  EXPECT_EQ(choice.missing[0], (CellRange{0, 0, 32}));
}

TEST(RenderModel, PaperCostIsWorkloadTimesTsPlusMissingBytesTimesTn) {
  const Table cells{3200, 6400};
  RenderModel model(2);
  ASSERT_EQ(model.costModel(), CostModel::Paper);  // the default
  // Measured rates replace the defaults (moving average converges).
  for (int i = 0; i < 200; ++i) {
    model.applyReport(0, {.workloadSplats = 500, .secondsPerSplat = 1e-6, .secondsPerByte = 1e-5},
                      kNow);
  }
  EXPECT_NEAR(model.secondsPerSplat(), 1e-6, 1e-9);
  EXPECT_NEAR(model.secondsPerByte(), 1e-5, 1e-8);
  const auto needed = whole(cells, {0, 1});
  std::uint64_t missing = 0;
  const double cost = model.cost(0, needed, 100, &missing);
  EXPECT_EQ(missing, 9600u);
  EXPECT_NEAR(cost, (500 + 100) * 1e-6 + 9600 * 1e-5, 1e-9);
}

// Where processes outnumber a machine's cores, a render's queue counts by the
// share of a core each process has: a shorter queue elsewhere does not draw
// sooner, while moving the data costs CPU all of them share.
TEST(RenderModel, ACoreShareWeighsTheQueueAndKeepsTilesWithTheirData) {
  const Table cells{320'000, 3200};  // 10 000 splats and 100 splats
  const auto needed = whole(cells, {0});
  const auto measured = [&](RenderModel& model) {
    for (int i = 0; i < 200; ++i) {
      for (std::size_t render : {0u, 1u}) {
        model.applyReport(render,
                          {.workloadSplats = render == 0 ? 3000u : 1u,
                           .loaded = render == 0 ? std::span<const CellRange>(needed)
                                                 : std::span<const CellRange>(),
                           .secondsPerSplat = 1e-8,
                           .secondsPerByte = 1e-9},
                          kNow);
      }
    }
  };
  // Render 0 holds the cell and 3000 splats of queue (30 us); moving 320 KB
  // to the idle render 1 costs 320 us... unless the queue is much longer.
  RenderModel dedicated(2);
  measured(dedicated);
  dedicated.applyReport(0, {.workloadSplats = 100'000, .secondsPerSplat = 1e-8}, kNow);
  EXPECT_EQ(dedicated.choose(needed, 1000, kNow).render, 1u);  // 1 ms of queue > 0.32 ms
  RenderModel shared(2);
  measured(shared);
  shared.applyReport(0, {.workloadSplats = 100'000, .secondsPerSplat = 1e-8}, kNow);
  const std::vector<float> shares{0.25f, 0.25f};
  shared.setCoreShares(shares);
  EXPECT_EQ(shared.choose(needed, 1000, kNow).render, 0u);  // 0.25 ms of queue < 0.32 ms
  std::uint64_t missing = 0;
  EXPECT_NEAR(shared.cost(0, needed, 1000, &missing), (100'000 * 0.25 + 1000) * 1e-8, 1e-12);
  EXPECT_EQ(missing, 0u);
  // Shares a display would not send count as a node each.
  const std::vector<float> odd{0.0f, 2.0f};
  shared.setCoreShares(odd);
  EXPECT_EQ(shared.choose(needed, 1000, kNow).render, 1u);
}

TEST(RenderModel, OverlapCostLetsTheTransferHideBehindQueuedWork) {
  const Table cells{3200, 6400};
  RenderModel model(2, CostModel::Overlap);
  for (int i = 0; i < 200; ++i) {
    model.applyReport(0, {.workloadSplats = 500, .secondsPerSplat = 1e-6, .secondsPerByte = 1e-7},
                      kNow);
  }
  const auto needed = whole(cells, {0, 1});
  // 9.6 kB at 1e-7 s/B = 0.96 ms arrives while the 500 queued splats (0.5 ms)
  // are drawn: the transfer is the longer of the two.
  EXPECT_NEAR(model.cost(0, needed, 100, nullptr), 9600 * 1e-7 + 100 * 1e-6, 1e-9);
  // With 5000 splats queued (5 ms) the transfer is hidden entirely.
  model.applyReport(0, {.workloadSplats = 5000}, kNow);
  EXPECT_NEAR(model.cost(0, needed, 100, nullptr), (5000 + 100) * 1e-6, 1e-9);
}

TEST(RenderModel, OverlapCostSendsDataToABusyRenderWhoseQueueHidesTheTransfer) {
  // Render 0 holds the cell and has 2.5 ms queued; render 1 has 2 ms queued and
  // needs the 9.6 kB cell (0.96 ms). Paper: 2.5 ms against 2 + 0.96 ms, stay.
  // Overlap: the cell arrives while render 1 draws its queue, 2.5 against 2 ms, move.
  const Table cells{9600};
  const auto loaded = whole(cells, {0});
  const auto needed = whole(cells, {0});
  RenderModel paper(2, CostModel::Paper);
  RenderModel overlap(2, CostModel::Overlap);
  for (RenderModel* model : {&paper, &overlap}) {
    for (int i = 0; i < 200; ++i) {
      model->applyReport(0, {.secondsPerSplat = 1e-6, .secondsPerByte = 1e-7}, kNow);
    }
    model->applyReport(0, {.workloadSplats = 2500, .loaded = loaded}, kNow);
    model->applyReport(1, {.workloadSplats = 2000}, kNow);
  }
  EXPECT_EQ(paper.choose(needed, 100, kNow).render, 0u);
  const auto moved = overlap.choose(needed, 100, kNow);
  EXPECT_EQ(moved.render, 1u);
  EXPECT_EQ(moved.missingBytes, 9600u);
}

TEST(RenderModel, WorkloadCountsPacketsSentSinceTheLastReport) {
  RenderModel model(1);
  model.recordPacket(0, 1, 300, {}, kNow);
  model.recordPacket(0, 2, 200, {}, kNow);
  EXPECT_EQ(model.workload(0), 500u);
  // The render had seen packet 1 (and finished part of it) when it reported.
  model.applyReport(0, {.workloadSplats = 120, .lastPacketFromUs = 1}, kNow);
  EXPECT_EQ(model.workload(0), 320u);
  model.applyReport(0, {.workloadSplats = 0, .lastPacketFromUs = 2}, kNow);
  EXPECT_EQ(model.workload(0), 0u);
}

TEST(RenderModel, OrderedCellsCountAsPresentUntilEvicted) {
  const Table cells{128, 128};
  RenderModel model(2);
  const auto ordered = whole(cells, {1});
  model.recordPacket(1, 1, 10, ordered, kNow);
  EXPECT_EQ(model.heldSplats(1, 1), 4u);
  const auto loaded = whole(cells, {1});
  model.applyReport(1, {.loaded = loaded, .lastPacketFromUs = 1}, kNow);
  EXPECT_EQ(model.heldSplats(1, 1), 4u);
  EXPECT_EQ(model.cachedCellCount(1), 1u);
  const std::uint32_t evicted[] = {1};
  model.applyReport(1, {.evicted = evicted, .lastPacketFromUs = 1}, kNow);
  EXPECT_EQ(model.heldSplats(1, 1), 0u);
  EXPECT_EQ(model.cachedCellCount(1), 0u);
}

TEST(RenderModel, EqualCostsSpreadOverRenders) {
  RenderModel model(4);
  std::set<std::size_t> chosen;
  for (int i = 0; i < 4; ++i) chosen.insert(model.choose({}, 0, kNow).render);
  EXPECT_EQ(chosen.size(), 4u);
}

// A render lacks exactly the splats of the needed ranges it neither holds nor
// has on order, wherever in the packet they lie; what is on order stays on
// the books until a report shows it held or the cell evicted.
TEST(RenderModel, MissingBytesAreTheNeededRangesARenderNeitherHoldsNorHasOnOrder) {
  RenderModel model(2);
  const CellRange held[] = {{0, 100, 100}, {0, 300, 50}};
  model.applyReport(0, {.loaded = held}, kNow);
  // Splats 0-400 of cell 0 and 20-70 of cell 1.
  const CellRange needs[] = {{0, 0, 400}, {1, 20, 50}};
  std::uint64_t missing = 0;
  model.cost(0, needs, 10, &missing);
  EXPECT_EQ(missing, (250u + 50u) * sizeof(Splat));
  model.cost(1, needs, 10, &missing);
  EXPECT_EQ(missing, (400u + 50u) * sizeof(Splat));
  EXPECT_EQ(model.missingSplats(0, needs), 300u);
  EXPECT_EQ(model.missing(0, needs),
            (std::vector<CellRange>{{0, 0, 100}, {0, 200, 100}, {0, 350, 50}, {1, 20, 50}}));
  const CellRange covered[] = {{0, 120, 60}, {0, 310, 40}};
  EXPECT_TRUE(model.missing(0, covered).empty());
  // What is missing is ordered; a report of part of it leaves the rest on order.
  model.recordPacket(0, 1, 10, model.missing(0, needs), kNow);
  EXPECT_EQ(model.heldSplats(0, 0), 400u);
  EXPECT_TRUE(model.missing(0, needs).empty());
  const CellRange part[] = {{0, 0, 100}};
  model.applyReport(0, {.loaded = part}, kNow);
  EXPECT_EQ(model.heldSplats(0, 0), 400u);
  EXPECT_TRUE(model.missing(0, needs).empty());
  // Evicted whole, then stored again in the same report: only what came after.
  const std::uint32_t evicted[] = {0};
  const CellRange again[] = {{0, 380, 20}};
  model.applyReport(0, {.evicted = evicted, .loaded = again}, kNow);
  EXPECT_EQ(model.heldSplats(0, 0), 20u);
  EXPECT_EQ(model.missing(0, needs), (std::vector<CellRange>{{0, 0, 380}}));
  EXPECT_EQ(model.heldSplats(0, 1), 50u);  // still on order
}

}  // namespace
}  // namespace pointillist::traverse

namespace pointillist::traverse {
namespace {

TEST(RenderModel, SplatsHeldElsewhereCountWhatAnotherRenderHoldsOrHasOnOrderOnce) {
  RenderModel model(3);
  const CellRange heldByOne[] = {{0, 0, 100}, {1, 50, 50}};
  model.applyReport(1, {.loaded = heldByOne}, kNow);
  const CellRange orderedForTwo[] = {{0, 60, 80}};
  model.recordPacket(2, 1, 10, orderedForTwo, kNow);
  // Cell 0: 0-140 held elsewhere (overlap counted once), 140-200 nowhere;
  // cell 1: 50-100 elsewhere of 0-100; cell 2 nowhere.
  const CellRange ranges[] = {{0, 0, 200}, {1, 0, 100}, {2, 0, 30}};
  EXPECT_EQ(model.splatsHeldElsewhere(0, ranges), 140u + 50u);
  // A render's own holding is not elsewhere.
  EXPECT_EQ(model.splatsHeldElsewhere(1, ranges), 80u);
  EXPECT_EQ(model.splatsHeldElsewhere(2, ranges), 100u + 50u);
}

TEST(RenderModel, AStalledRenderIsAvoidedEvenWhenItHasTheData) {
  using namespace std::chrono_literals;
  const Table cells{10'000'000, 128};
  RenderModel model(2);
  const RenderModel::Clock::time_point t{};
  const auto loaded = whole(cells, {0});
  // Render 0 holds the big cell, has a little work and keeps finishing packets.
  model.applyReport(0, {.workloadSplats = 1000, .loaded = loaded, .packetsDone = 1}, t);
  const auto needed = whole(cells, {0});
  EXPECT_EQ(model.choose(needed, 10, t + 100ms).render, 0u);
  // It reports more work but finishes nothing for two seconds: suspected stalled.
  model.applyReport(0, {.workloadSplats = 2000, .loaded = {}, .packetsDone = 1}, t + 200ms);
  EXPECT_FALSE(model.suspectedStalled(0, t + 500ms));
  EXPECT_TRUE(model.suspectedStalled(0, t + 2500ms));
  EXPECT_EQ(model.choose(needed, 10, t + 2500ms).render, 1u);
  // Progress clears the suspicion.
  model.applyReport(0, {.workloadSplats = 1000, .packetsDone = 2}, t + 2600ms);
  EXPECT_FALSE(model.suspectedStalled(0, t + 2700ms));
  EXPECT_EQ(model.choose(needed, 10, t + 2700ms).render, 0u);
}

// Seed 003's cost is per process: T_s of a slower render process counts for it
// alone, so it is given proportionally less work.
TEST(RenderModel, ASlowerRenderGetsProportionallyLessWork) {
  const Table cells{1024};
  RenderModel model(2);
  const auto loaded = whole(cells, {0});
  model.applyReport(0, {.loaded = loaded, .secondsPerSplat = 4e-7}, kNow);
  model.applyReport(1, {.loaded = loaded, .secondsPerSplat = 1e-7}, kNow);
  EXPECT_DOUBLE_EQ(model.secondsPerSplat(), 2.5e-7);
  const auto needed = whole(cells, {0});
  std::size_t packets[2] = {};
  for (std::uint64_t id = 1; id <= 500; ++id) {
    const auto choice = model.choose(needed, 10'000, kNow);
    ++packets[choice.render];
    model.recordPacket(choice.render, id, 10'000, choice.missing, kNow);
  }
  // Equal finishing times: four times the packets to the four times faster one.
  EXPECT_NEAR(static_cast<double>(packets[1]) / static_cast<double>(packets[0]), 4.0, 0.1);
  EXPECT_DOUBLE_EQ(model.secondsPerSplat(0), 4e-7);  // while it has work, its own figure
  EXPECT_DOUBLE_EQ(model.secondsPerSplat(1), 1e-7);
  // A render that has not measured yet counts as the mean of those that have.
  RenderModel fresh(3);
  fresh.applyReport(0, {.secondsPerSplat = 1e-7, .secondsPerByte = 2e-9}, kNow);
  fresh.applyReport(1, {.secondsPerSplat = 3e-7, .secondsPerByte = 4e-9}, kNow);
  EXPECT_DOUBLE_EQ(fresh.secondsPerSplat(2), 2e-7);
  EXPECT_DOUBLE_EQ(fresh.secondsPerByte(2), 3e-9);
}

// One slow sample (a first draw that compiled shaders, a moment of contention)
// must not starve a process: with nothing queued it counts as the mean, gets
// work, and is measured again.
TEST(RenderModel, AnIdleRenderWithAStaleSlowFigureStillGetsWork) {
  const Table cells{1024};
  RenderModel model(2);
  const auto loaded = whole(cells, {0});
  model.applyReport(0, {.loaded = loaded, .secondsPerSplat = 1e-5}, kNow);
  model.applyReport(1, {.loaded = loaded, .secondsPerSplat = 1e-7}, kNow);
  EXPECT_DOUBLE_EQ(model.secondsPerSplat(0), model.secondsPerSplat());
  const auto needed = whole(cells, {0});
  std::size_t toSlow = 0;
  for (std::uint64_t id = 1; id <= 20; ++id) {
    const auto choice = model.choose(needed, 10'000, kNow);
    toSlow += choice.render == 0;
    model.recordPacket(choice.render, id, 10'000, {}, kNow);
    // Each packet is done before the next tile: both report an empty queue.
    model.applyReport(choice.render, {.workloadSplats = 0, .lastPacketFromUs = id}, kNow);
  }
  EXPECT_GT(toSlow, 0u);
}

// A lost render process (the display's PeerLost): never chosen again, even
// holding every cell; packets assigned to it go to the next live one; a report
// still on its way changes nothing.
TEST(RenderModel, RegionsKeepATileHomeUntilItsRenderHoldsTwoTilesMoreThanAnother) {
  const Table cells{1'000'000, 1'000'000};
  RenderModel model(3);
  // Render 0 is the region's home; render 1 holds the data the tile needs.
  model.applyReport(1, {.workloadSplats = 0, .loaded = whole(cells, {0})}, kNow);
  const auto needed = whole(cells, {0});
  const std::uint64_t tile = 10'000;
  // Home with up to two tiles' worth queued beyond the least loaded: home,
  // although the cost function would choose render 1.
  ASSERT_EQ(model.choose(needed, tile, kNow).render, 1u);
  for (const std::uint64_t queued : {std::uint64_t{0}, tile, 2 * tile}) {
    model.applyReport(0, {.workloadSplats = queued}, kNow);
    const auto choice = model.chooseNearHome(0, needed, tile, kNow);
    EXPECT_EQ(choice.render, 0u) << queued;
    EXPECT_EQ(choice.missingBytes, 1'000'000u);
  }
  // More than that while another idles: the cost function chooses.
  model.applyReport(0, {.workloadSplats = 2 * tile + 1}, kNow);
  EXPECT_EQ(model.chooseNearHome(0, needed, tile, kNow).render, 1u);
  // Measured against the least loaded, not against an empty queue.
  model.applyReport(1, {.workloadSplats = 5 * tile, .loaded = whole(cells, {0})}, kNow);
  model.applyReport(2, {.workloadSplats = 5 * tile}, kNow);
  EXPECT_EQ(model.chooseNearHome(0, needed, tile, kNow).render, 0u);
  // A retired home passes its tiles to the next live render.
  model.retire(0);
  EXPECT_NE(model.chooseNearHome(0, needed, tile, kNow).render, 0u);
}

TEST(RenderModel, ARetiredRenderIsNeverChosenAgain) {
  const Table cells{10'000'000, 128};
  RenderModel model(3);
  const auto loaded = whole(cells, {0, 1});
  model.applyReport(1, {.workloadSplats = 0, .loaded = loaded}, kNow);
  const auto needed = whole(cells, {0, 1});
  EXPECT_EQ(model.choose(needed, 10, kNow).render, 1u);
  model.retire(1);
  EXPECT_TRUE(model.retired(1));
  EXPECT_EQ(model.liveCount(), 2u);
  EXPECT_EQ(model.choose(needed, 10, kNow).missingBytes, 10'000'128u);  // nobody else has it
  for (int i = 0; i < 6; ++i) {
    const auto choice = model.choose(needed, 10, kNow);
    EXPECT_NE(choice.render, 1u);
    model.recordPacket(choice.render, static_cast<std::uint64_t>(i), 10, choice.missing, kNow);
  }
  EXPECT_EQ(model.assigned(1, needed, 10).render, 2u);
  EXPECT_EQ(model.assigned(4, needed, 10).render, 2u);  // 4 % 3 = 1: retired, so 2
  model.applyReport(1, {.workloadSplats = 0, .loaded = loaded}, kNow);
  EXPECT_NE(model.choose(needed, 10, kNow).render, 1u);
  model.retire(0);
  model.retire(2);
  EXPECT_THROW((void)model.choose(needed, 10, kNow), ProtocolError);
  EXPECT_THROW((void)model.assigned(0, needed, 10), ProtocolError);
}

}  // namespace
}  // namespace pointillist::traverse
