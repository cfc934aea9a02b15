// The cost function of seed 003 §4.3 and the traverse's model of render processes.
#include <gtest/gtest.h>

#include <set>

#include "traverse/core/render_model.hpp"

namespace pointillist::traverse {
namespace {

// Cores are told the time; these tests need only one moment.
const RenderModel::Clock::time_point kNow{};

std::vector<TopLevelCell> table(std::initializer_list<std::uint64_t> bytes) {
  std::vector<TopLevelCell> cells;
  std::uint64_t offset = 0;
  for (std::uint64_t size : bytes) {
    TopLevelCell cell{};
    cell.byteOffset = offset;
    cell.byteSize = size;
    offset += size;
    cells.push_back(cell);
  }
  return cells;
}

TEST(RenderModel, PrefersTheRenderThatHasTheData) {
  const auto cells = table({1'000'000, 2'000'000, 500});
  RenderModel model(3, cells);
  const std::uint32_t loaded[] = {0, 1};
  model.applyReport(1, {.workloadSplats = 0, .loaded = loaded}, kNow);
  const std::uint32_t needed[] = {0, 1};
  const auto choice = model.choose(needed, 1000, kNow);
  EXPECT_EQ(choice.render, 1u);
  EXPECT_EQ(choice.missingBytes, 0u);
  EXPECT_TRUE(choice.missingCells.empty());
}

TEST(RenderModel, PrefersAnIdleRenderWhenWorkOutweighsTheTransfer) {
  const auto cells = table({1000, 1000});
  RenderModel model(2, cells);
  const std::uint32_t loaded[] = {0};
  // Render 0 has the data but 10 M splats queued (2 s at 5 M/s); moving 1 kB costs ~10 us.
  model.applyReport(0, {.workloadSplats = 10'000'000, .loaded = loaded}, kNow);
  const std::uint32_t needed[] = {0};
  const auto choice = model.choose(needed, 100, kNow);
  EXPECT_EQ(choice.render, 1u);
  EXPECT_EQ(choice.missingBytes, 1000u);
  ASSERT_EQ(choice.missingCells.size(), 1u);
  EXPECT_EQ(choice.missingCells[0], 0u);
}

TEST(RenderModel, PaperCostIsWorkloadTimesTsPlusMissingBytesTimesTn) {
  const auto cells = table({4000, 6000});
  RenderModel model(2, cells);
  ASSERT_EQ(model.costModel(), CostModel::Paper);  // the default
  // Measured rates replace the defaults (moving average converges).
  for (int i = 0; i < 200; ++i) {
    model.applyReport(0, {.workloadSplats = 500, .secondsPerSplat = 1e-6, .secondsPerByte = 1e-5},
                      kNow);
  }
  EXPECT_NEAR(model.secondsPerSplat(), 1e-6, 1e-9);
  EXPECT_NEAR(model.secondsPerByte(), 1e-5, 1e-8);
  const std::uint32_t needed[] = {0, 1};
  std::uint64_t missing = 0;
  const double cost = model.cost(0, needed, 100, &missing);
  EXPECT_EQ(missing, 10'000u);
  EXPECT_NEAR(cost, (500 + 100) * 1e-6 + 10'000 * 1e-5, 1e-9);
}

TEST(RenderModel, OverlapCostLetsTheTransferHideBehindQueuedWork) {
  const auto cells = table({4000, 6000});
  RenderModel model(2, cells, CostModel::Overlap);
  for (int i = 0; i < 200; ++i) {
    model.applyReport(0, {.workloadSplats = 500, .secondsPerSplat = 1e-6, .secondsPerByte = 1e-7},
                      kNow);
  }
  const std::uint32_t needed[] = {0, 1};
  // 10 kB at 1e-7 s/B = 1 ms arrives while the 500 queued splats (0.5 ms) are
  // drawn: the transfer is the longer of the two.
  EXPECT_NEAR(model.cost(0, needed, 100, nullptr), 10'000 * 1e-7 + 100 * 1e-6, 1e-9);
  // With 5000 splats queued (5 ms) the transfer is hidden entirely.
  model.applyReport(0, {.workloadSplats = 5000}, kNow);
  EXPECT_NEAR(model.cost(0, needed, 100, nullptr), (5000 + 100) * 1e-6, 1e-9);
}

TEST(RenderModel, OverlapCostSendsDataToABusyRenderWhoseQueueHidesTheTransfer) {
  // Render 0 holds the cell and has 2.5 ms queued; render 1 has 2 ms queued and
  // needs the 10 kB cell (1 ms). Paper: 2.5 ms against 2 + 1 = 3 ms, stay.
  // Overlap: the cell arrives while render 1 draws its queue, 2.5 against 2 ms, move.
  const auto cells = table({10'000});
  const std::uint32_t loaded[] = {0};
  const std::uint32_t needed[] = {0};
  RenderModel paper(2, cells, CostModel::Paper);
  RenderModel overlap(2, cells, CostModel::Overlap);
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
  EXPECT_EQ(moved.missingBytes, 10'000u);
}

TEST(RenderModel, WorkloadCountsPacketsSentSinceTheLastReport) {
  const auto cells = table({100});
  RenderModel model(1, cells);
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
  const auto cells = table({100, 100});
  RenderModel model(2, cells);
  const std::uint32_t ordered[] = {1};
  model.recordPacket(1, 1, 10, ordered, kNow);
  EXPECT_TRUE(model.hasCell(1, 1));
  const std::uint32_t loaded[] = {1};
  model.applyReport(1, {.loaded = loaded, .lastPacketFromUs = 1}, kNow);
  EXPECT_TRUE(model.hasCell(1, 1));
  EXPECT_EQ(model.cachedCellCount(1), 1u);
  const std::uint32_t evicted[] = {1};
  model.applyReport(1, {.evicted = evicted, .lastPacketFromUs = 1}, kNow);
  EXPECT_FALSE(model.hasCell(1, 1));
  EXPECT_EQ(model.cachedCellCount(1), 0u);
}

TEST(RenderModel, EqualCostsSpreadOverRenders) {
  const auto cells = table({100});
  RenderModel model(4, cells);
  std::set<std::size_t> chosen;
  for (int i = 0; i < 4; ++i) chosen.insert(model.choose({}, 0, kNow).render);
  EXPECT_EQ(chosen.size(), 4u);
}

}  // namespace
}  // namespace pointillist::traverse

namespace pointillist::traverse {
namespace {

TEST(RenderModel, AStalledRenderIsAvoidedEvenWhenItHasTheData) {
  using namespace std::chrono_literals;
  const auto cells = table({10'000'000, 100});
  RenderModel model(2, cells);
  const RenderModel::Clock::time_point t{};
  const std::uint32_t loaded[] = {0};
  // Render 0 holds the big cell, has a little work and keeps finishing packets.
  model.applyReport(0, {.workloadSplats = 1000, .loaded = loaded, .packetsDone = 1}, t);
  const std::uint32_t needed[] = {0};
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
  const auto cells = table({1000});
  RenderModel model(2, cells);
  const std::uint32_t loaded[] = {0};
  model.applyReport(0, {.loaded = loaded, .secondsPerSplat = 4e-7}, kNow);
  model.applyReport(1, {.loaded = loaded, .secondsPerSplat = 1e-7}, kNow);
  EXPECT_DOUBLE_EQ(model.secondsPerSplat(), 2.5e-7);
  const std::uint32_t needed[] = {0};
  std::size_t packets[2] = {};
  for (std::uint64_t id = 1; id <= 500; ++id) {
    const auto choice = model.choose(needed, 10'000, kNow);
    ++packets[choice.render];
    model.recordPacket(choice.render, id, 10'000, choice.missingCells, kNow);
  }
  // Equal finishing times: four times the packets to the four times faster one.
  EXPECT_NEAR(static_cast<double>(packets[1]) / static_cast<double>(packets[0]), 4.0, 0.1);
  EXPECT_DOUBLE_EQ(model.secondsPerSplat(0), 4e-7);  // while it has work, its own figure
  EXPECT_DOUBLE_EQ(model.secondsPerSplat(1), 1e-7);
  // A render that has not measured yet counts as the mean of those that have.
  RenderModel fresh(3, cells);
  fresh.applyReport(0, {.secondsPerSplat = 1e-7, .secondsPerByte = 2e-9}, kNow);
  fresh.applyReport(1, {.secondsPerSplat = 3e-7, .secondsPerByte = 4e-9}, kNow);
  EXPECT_DOUBLE_EQ(fresh.secondsPerSplat(2), 2e-7);
  EXPECT_DOUBLE_EQ(fresh.secondsPerByte(2), 3e-9);
}

// One slow sample (a first draw that compiled shaders, a moment of contention)
// must not starve a process: with nothing queued it counts as the mean, gets
// work, and is measured again.
TEST(RenderModel, AnIdleRenderWithAStaleSlowFigureStillGetsWork) {
  const auto cells = table({1000});
  RenderModel model(2, cells);
  const std::uint32_t loaded[] = {0};
  model.applyReport(0, {.loaded = loaded, .secondsPerSplat = 1e-5}, kNow);
  model.applyReport(1, {.loaded = loaded, .secondsPerSplat = 1e-7}, kNow);
  EXPECT_DOUBLE_EQ(model.secondsPerSplat(0), model.secondsPerSplat());
  const std::uint32_t needed[] = {0};
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

}  // namespace
}  // namespace pointillist::traverse
