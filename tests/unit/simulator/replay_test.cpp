// Replaying a traverse's decision log through the simulator's traverse core:
// the log survives the disk, identical inputs give identical replies, and a
// reply that differs is caught and described.
#include "simulator/replay.hpp"

#include <gtest/gtest.h>

#include <unistd.h>
#include <memory>

#include <fstream>

#include "common/errors.hpp"
#include "common/ownership.hpp"
#include "common/view_options.hpp"
#include "test_city.hpp"
#include "traverse/core/packet_planner.hpp"

namespace pointillist::simulator {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;

struct SmallCity {
  DatasetContent content;
  std::vector<Camera> cameras;
};

const SmallCity& smallCity() {
  static const SmallCity city = [] {
    SmallCity made;
    made.content = simulator::fixtures::smallCityContent(20'000, 5);
    ViewOptions view;
    view.frames = 3;
    view.size = "160x90";
    made.cameras = viewCameras(view, datasetBounds(made.content.manifest));
    return made;
  }();
  return city;
}

// Plays a little job to one traverse: two renders report, tiles come in.
traverse::DecisionLog recordedLog(const fs::path& file) {
  const SmallCity& city = smallCity();
  const PeerRanks peers = PeerRanks::contiguous(JobLayout{1, 1, 1, 2});
  v1::RunSettings settings;
  settings.set_lod_pixels(1.0f);
  settings.set_size_scale(1.0f);
  settings.set_scheduler(v1::SCHEDULER_COST);
  const TimePoint origin = timeAfterEpoch(1000.0);
  traverse::PacketPlanner planner(
      peers, 1, settings,
      std::make_shared<const traverse::PacketLayers>(city.content.cells, city.content.topLevel),
      assignOwners(city.content.topLevel, 1));
  {
    traverse::DecisionLogWriter writer(
        file, traverse::decisionLogStart(peers, 1, settings, "small city"), origin);
    std::uint64_t packets = 0;
    for (std::uint32_t frame = 0; frame < city.cameras.size(); ++frame) {
      const TimePoint now = origin + frame * 30ms;
      for (int render : peers.renders) {
        v1::RenderReport report;
        report.set_workload_splats(1000u * frame);
        report.set_seconds_per_splat(1e-7);
        report.add_last_packet_from_traverse(packets);
        planner.applyReport(render, report, now);
        writer.recordReport(now, render, report);
      }
      for (std::uint32_t tile = 0; tile < 2; ++tile) {
        v1::TileTask task;
        task.set_frame_id(frame);
        task.set_tile_id(tile);
        *task.mutable_camera() = city.cameras[frame];
        *task.mutable_rect() = makeTileRect(tile * 80, 0, 80, 90);
        // Walked as the traverse role walks (its packets carry screen boxes).
        const auto walk = traverse::traverseTile(city.content.cells, task.camera(), task.rect(),
                                                 planner.traversalFor(task));
        Outbox out;
        planner.planPackets(task, traverse::walkOf(walk), {}, now + 1ms, out);
        writer.recordTask(now + 1ms, 0, task, out.entries());
        ++packets;
      }
    }
  }
  return traverse::readDecisionLog(file);
}

class Replay : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("pointillist-replay-" + std::to_string(getpid()));
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path dir_;
};

TEST_F(Replay, TheSameInputsGiveTheSameRepliesThroughTheSimulatorsCore) {
  const auto log = recordedLog(dir_ / "t.decisions");
  EXPECT_EQ(log.start.dataset(), "small city");
  EXPECT_EQ(log.start.render_ranks_size(), 2);
  ASSERT_EQ(log.decisions.size(), 3u * (2 + 2));
  const SmallCity& city = smallCity();
  const ReplayResult result = replayDecisions(log, city.content.cells, city.content.topLevel);
  EXPECT_EQ(result.tasks, 6u);
  EXPECT_EQ(result.reports, 6u);
  EXPECT_EQ(result.identical, 6u);
  EXPECT_TRUE(result.mismatches.empty());
}

TEST_F(Replay, ADifferentChoiceIsCaughtAndDescribed) {
  auto log = recordedLog(dir_ / "t.decisions");
  // As if the job had sent the third tile elsewhere.
  v1::TraverseDecision* task = nullptr;
  int tasks = 0;
  for (auto& decision : log.decisions) {
    if (decision.has_task() && ++tasks == 3) task = &decision;
  }
  ASSERT_NE(task, nullptr);
  for (auto& output : *task->mutable_outputs()) {
    if (output.has_packet()) output.set_destination(output.destination() == 3 ? 4 : 3);
  }
  const SmallCity& city = smallCity();
  const ReplayResult result = replayDecisions(log, city.content.cells, city.content.topLevel);
  ASSERT_EQ(result.mismatches.size(), 1u);
  EXPECT_NE(result.mismatches[0].difference.find("destination"), std::string::npos)
      << result.mismatches[0].difference;
  EXPECT_EQ(result.identical, 5u);
}

TEST_F(Replay, ADamagedLogIsRefusedNamingTheFile) {
  const fs::path file = dir_ / "t.decisions";
  recordedLog(file);
  fs::resize_file(file, fs::file_size(file) - 7);
  try {
    traverse::readDecisionLog(file);
    FAIL() << "a cut log was read";
  } catch (const InputError& error) {
    EXPECT_NE(std::string(error.what()).find(file.string()), std::string::npos) << error.what();
    EXPECT_NE(std::string(error.what()).find("cut short"), std::string::npos) << error.what();
  }
  std::ofstream(dir_ / "empty.decisions").close();
  EXPECT_THROW(traverse::readDecisionLog(dir_ / "empty.decisions"), InputError);
  EXPECT_THROW(traverse::readDecisionLog(dir_ / "missing.decisions"), InputError);
}

}  // namespace
}  // namespace pointillist::simulator
