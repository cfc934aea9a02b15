// The display's decisions (seed 003 §4.2), driven directly: tiles to idle
// traverse processes, re-issue of late tiles, frames in order, feedback to
// the tile planner only from frames that fully came back.
#include "display/core/frame_assembly.hpp"
#include "display/core/tile_parts.hpp"
#include "display/core/tiling.hpp"

#include <algorithm>
#include <cstring>
#include <map>

#include <gtest/gtest.h>

#include "common/image.hpp"
#include "common/image_compression.hpp"
#include "common/pixel_runs.hpp"
#include "tile_cover.hpp"

namespace pointillist::display {
namespace {

using namespace std::chrono_literals;

// Layout 1,2,1,2: display 0, traverses 1-2, data-send 3, renders 4-5.
const PeerRanks kPeers = PeerRanks::contiguous(JobLayout{1, 2, 1, 2});
const TimePoint kStart = timeAfterEpoch(10.0);

// The eye sits inside the data's box, so every frame's box of interest is
// the whole 128x64 frame.
Camera camera(float x) {
  return makeCamera({x, 0, 0}, {x + 1, 0, 0}, {0, 0, 1}, 60.0f, 0.1f, 100.0f, 128, 64);
}

FrameAssemblyConfig config(std::size_t frames, std::uint32_t maxAttempts = 3,
                           SchedulerKind scheduler = SchedulerKind::Cost) {
  FrameAssemblyConfig c;
  for (std::size_t i = 0; i < frames; ++i) c.cameras.push_back(camera(static_cast<float>(i)));
  c.bounds = SceneBounds{{-50, -50, -50}, {50, 50, 50}};
  c.framesInFlight = 1;
  c.tileTimeout = 1s;
  c.maxAttempts = maxAttempts;
  c.plan.scheduler = scheduler;
  c.plan.renders = 2;
  c.plan.tilesPerRender = 2.0;
  c.plan.minTileSize = 8;
  return c;
}

std::vector<v1::TileTask> tasksIn(const Outbox& out) {
  std::vector<v1::TileTask> tasks;
  for (const Outgoing& outgoing : out.entries()) {
    EXPECT_EQ(outgoing.kind, MessageKind::TileTask);
    tasks.push_back(outgoing.as<v1::TileTask>());
  }
  return tasks;
}

// Hands every waiting tile out (one traverse asking as often as needed).
std::vector<v1::TileTask> takeAll(FrameAssembly& assembly, TimePoint now) {
  std::vector<v1::TileTask> tasks;
  while (true) {
    assembly.workRequested(1);
    Outbox out;
    assembly.dispatch(now, out);
    const auto more = tasksIn(out);
    if (more.empty()) return tasks;
    tasks.insert(tasks.end(), more.begin(), more.end());
  }
}

v1::TileImageHeader tile(const v1::TileTask& task, std::uint64_t splats, int render = 4) {
  v1::TileImageHeader header;
  header.set_frame_id(task.frame_id());
  header.set_tile_id(task.tile_id());
  *header.mutable_rect() = task.rect();
  header.set_attempt(task.attempt());
  header.set_render_rank(render);
  header.set_splats_rendered(splats);
  header.set_render_time_us(static_cast<std::int64_t>(splats / 10));
  return header;
}

// The traverse's word that a task went to `render` (an index among renders).
v1::WorkRequest placed(const v1::TileTask& task, std::uint32_t render) {
  v1::WorkRequest request;
  v1::TilePlacement* placement = request.add_placements();
  placement->set_frame_id(task.frame_id());
  placement->set_tile_id(task.tile_id());
  placement->set_attempt(task.attempt());
  placement->set_render(render);
  return request;
}

std::vector<std::tuple<std::uint32_t, std::uint32_t, std::uint32_t, std::uint32_t>> rects(
    const std::vector<v1::TileTask>& tasks) {
  std::vector<std::tuple<std::uint32_t, std::uint32_t, std::uint32_t, std::uint32_t>> result;
  for (const auto& task : tasks) {
    result.emplace_back(task.rect().x(), task.rect().y(), task.rect().width(),
                        task.rect().height());
  }
  return result;
}

TEST(FrameAssembly, HandsTilesOnlyToTraversesThatAskedAndStampsThem) {
  FrameAssembly assembly(config(1), kPeers, kStart);
  Outbox none;
  assembly.dispatch(kStart, none);
  EXPECT_TRUE(none.empty());
  assembly.workRequested(2);
  Outbox out;
  assembly.dispatch(kStart + 5ms, out);
  ASSERT_EQ(out.entries().size(), 1u);
  EXPECT_EQ(out.entries()[0].destinations, (std::vector<int>{2}));
  const auto& task = out.entries()[0].as<v1::TileTask>();
  EXPECT_EQ(task.frame_id(), 0u);
  EXPECT_EQ(task.attempt(), 0u);
  EXPECT_EQ(task.timestamp_ns(),
            std::chrono::duration_cast<std::chrono::nanoseconds>((kStart + 5ms).time_since_epoch())
                .count());
  EXPECT_FALSE(task.has_lookahead_camera());
  EXPECT_EQ(assembly.idleTraverses(), 0u);
  EXPECT_THROW(assembly.workRequested(3), ProtocolError);  // a data-send process
}

TEST(FrameAssembly, RegionTilesGoToTheirOwnRenderInEveryFrameEvenWhenPlannedAhead) {
  auto c = config(5, 3, SchedulerKind::Regions);
  c.framesInFlight = 2;  // a frame is planned before the one ahead of it is handed out
  FrameAssembly assembly(c, kPeers, kStart);
  std::map<std::uint64_t, std::vector<std::uint32_t>> homes;
  std::map<std::uint64_t, std::uint64_t> renderOnePixels;
  for (int round = 0; round < 10 && !assembly.done(); ++round) {
    for (const auto& task : takeAll(assembly, kStart)) {
      homes[task.frame_id()].push_back(task.assigned_render());
      if (task.assigned_render() == 1) {
        renderOnePixels[task.frame_id()] =
            std::uint64_t{task.rect().width()} * task.rect().height();
      }
      // Render 1's region measures three times the work of render 0's.
      const std::uint64_t splats = task.assigned_render() == 1 ? 3000 : 1000;
      EXPECT_EQ(
          assembly.tileArrived(tile(task, splats, kPeers.renders[task.assigned_render()]), kStart),
          TileArrival::Complete);
    }
    assembly.finishFrames(kStart);
  }
  ASSERT_TRUE(assembly.done());
  ASSERT_EQ(homes.size(), 5u);
  for (auto& [frame, renders] : homes) {
    std::sort(renders.begin(), renders.end());
    EXPECT_EQ(renders, (std::vector<std::uint32_t>{0, 1})) << "frame " << frame;
  }
  // Unmeasured, the frame is halved; once measured, the heavier region shrinks.
  EXPECT_EQ(renderOnePixels[0], 128u * 64u / 2u);
  EXPECT_LT(renderOnePixels[4], 128u * 64u / 3u);
}

TEST(FrameAssembly, ReissuesALateTileAndCountsTheLateCopyWithoutComposingIt) {
  FrameAssembly assembly(config(1), kPeers, kStart);
  const auto first = takeAll(assembly, kStart);
  ASSERT_EQ(first.size(), 4u);
  EXPECT_EQ(assembly.tileProgress(0), std::make_pair(0u, 4u));
  for (std::size_t i = 1; i < first.size(); ++i) {
    EXPECT_EQ(assembly.tileArrived(tile(first[i], 100), kStart + 100ms), TileArrival::Complete);
    EXPECT_EQ(assembly.tileProgress(0), std::make_pair(static_cast<std::uint32_t>(i), 4u));
  }
  EXPECT_TRUE(assembly.finishFrames(kStart + 100ms).empty());
  ASSERT_TRUE(assembly.nextDeadline());
  EXPECT_EQ(*assembly.nextDeadline(), kStart + 1s);
  // Not yet due.
  assembly.workRequested(1);
  Outbox early;
  EXPECT_EQ(assembly.dispatch(kStart + 900ms, early), 0u);
  EXPECT_TRUE(early.empty());
  // Past its deadline the tile goes out again, attempt 1.
  Outbox late;
  EXPECT_EQ(assembly.dispatch(kStart + 1100ms, late), 1u);
  const auto again = tasksIn(late);
  ASSERT_EQ(again.size(), 1u);
  EXPECT_EQ(again[0].tile_id(), first[0].tile_id());
  EXPECT_EQ(again[0].attempt(), 1u);
  EXPECT_EQ(assembly.tileArrived(tile(again[0], 100), kStart + 1200ms), TileArrival::Complete);
  EXPECT_EQ(assembly.tileProgress(0), std::make_pair(4u, 4u));
  const auto finished = assembly.finishFrames(kStart + 1200ms);
  ASSERT_EQ(finished.size(), 1u);
  EXPECT_EQ(finished[0].record.reissuedTiles, 1u);
  EXPECT_EQ(finished[0].record.failedTiles, 0u);
  EXPECT_TRUE(finished[0].failedTiles.empty());
  EXPECT_DOUBLE_EQ(finished[0].record.startSeconds, 0.0);
  EXPECT_DOUBLE_EQ(finished[0].record.endSeconds, 1.2);
  // The first attempt turns up after all: counted, not composed.
  EXPECT_EQ(assembly.tileArrived(tile(first[0], 100), kStart + 1300ms), TileArrival::Late);
  EXPECT_EQ(assembly.stats().lateTiles, 1u);
  EXPECT_EQ(assembly.tileProgress(0), std::make_pair(0u, 0u));  // out of the window
  EXPECT_TRUE(assembly.done());
}

// The traverse says where each tile went; a render holding an overdue tile
// is named in every task handed out until it answers again.
TEST(FrameAssembly, TasksAvoidARenderHoldingAnOverdueTileUntilItAnswers) {
  FrameAssembly assembly(config(2), kPeers, kStart);
  const auto first = takeAll(assembly, kStart);
  ASSERT_EQ(first.size(), 4u);
  for (const v1::TileTask& task : first) EXPECT_EQ(task.avoid_renders_size(), 0);
  v1::WorkRequest placed;
  for (std::size_t i = 0; i < first.size(); ++i) {
    v1::TilePlacement* placement = placed.add_placements();
    placement->set_frame_id(first[i].frame_id());
    placement->set_tile_id(first[i].tile_id());
    placement->set_attempt(first[i].attempt());
    placement->set_render(i == 0 ? 1 : 0);
  }
  assembly.workRequested(1, placed);
  for (std::size_t i = 1; i < first.size(); ++i) {
    EXPECT_EQ(assembly.tileArrived(tile(first[i], 100, 4), kStart + 100ms), TileArrival::Complete);
  }
  Outbox late;
  EXPECT_EQ(assembly.dispatch(kStart + 1100ms, late), 1u);
  const auto again = tasksIn(late);
  ASSERT_EQ(again.size(), 1u);
  EXPECT_EQ(again[0].attempt(), 1u);
  EXPECT_EQ(
      std::vector<std::uint32_t>(again[0].avoid_renders().begin(), again[0].avoid_renders().end()),
      (std::vector<std::uint32_t>{1}));
  EXPECT_EQ(assembly.stats().avoidingTasks, 1u);
  EXPECT_EQ(assembly.tileArrived(tile(again[0], 100, 4), kStart + 1200ms), TileArrival::Complete);
  ASSERT_EQ(assembly.finishFrames(kStart + 1200ms).size(), 1u);
  // Still silent: the next frame's tasks avoid it.
  auto next = takeAll(assembly, kStart + 1200ms);
  ASSERT_FALSE(next.empty());
  EXPECT_EQ(next[0].avoid_renders_size(), 1);
  // The late copy from render 1 (rank 5) clears it: later tasks avoid no one.
  EXPECT_EQ(assembly.tileArrived(tile(first[0], 100, 5), kStart + 1300ms), TileArrival::Late);
  for (const v1::TileTask& task : next) {
    EXPECT_EQ(assembly.tileArrived(tile(task, 100, 4), kStart + 1300ms), TileArrival::Complete);
  }
  ASSERT_EQ(assembly.finishFrames(kStart + 1300ms).size(), 1u);
  assembly.appendCamera(camera(2.0f));
  next = takeAll(assembly, kStart + 1300ms);
  ASSERT_FALSE(next.empty());
  for (const v1::TileTask& task : next) EXPECT_EQ(task.avoid_renders_size(), 0);
  EXPECT_NE(assembly.stats().summary().find("handed out avoiding a silent render"),
            std::string::npos);
  // A placement on a render that does not exist is a protocol error.
  v1::WorkRequest stranger;
  stranger.add_placements()->set_render(2);
  EXPECT_THROW(assembly.workRequested(1, stranger), ProtocolError);
}

TEST(FrameAssembly, GivesATileUpAfterMaxAttemptsAndDoesNotResplitFromThatFrame) {
  using Rects = decltype(rects({}));
  const auto run = [](bool lose) -> std::pair<Rects, Rects> {
    FrameAssembly assembly(config(2, 1), kPeers, kStart);
    const auto frame0 = takeAll(assembly, kStart);
    // All the work sits in the first tile.
    // The first tile went to render 1 (rank 5).
    assembly.workRequested(1, placed(frame0[0], 1));
    for (std::size_t i = 0; i < frame0.size(); ++i) {
      if (lose && i == 0) continue;
      assembly.tileArrived(tile(frame0[i], i == 0 ? 1'000'000 : 10), kStart + 10ms);
    }
    Outbox out;
    assembly.dispatch(kStart + 2s, out);  // the lost tile is given up
    const auto finished = assembly.finishFrames(kStart + 2s);
    EXPECT_EQ(finished.size(), 1u);
    if (lose && !finished.empty()) {
      EXPECT_EQ(finished[0].record.failedTiles, 1u);
      EXPECT_EQ(finished[0].failedTiles.size(), 1u);
      EXPECT_EQ(finished[0].failedTileRenders, std::vector<int>{5});
      if (!finished[0].failedTiles.empty()) {
        EXPECT_EQ(finished[0].failedTiles[0].x(), frame0[0].rect().x());
      }
    }
    return {rects(frame0), rects(takeAll(assembly, kStart + 2s))};
  };
  const auto [measured0, measured1] = run(false);
  EXPECT_NE(measured0, measured1) << "a complete frame's work re-sizes the next frame's tiles";
  const auto [failed0, failed1] = run(true);
  EXPECT_EQ(failed0, measured0);
  EXPECT_EQ(failed1, failed0) << "a frame with a lost tile measured nothing for it";
}

TEST(FrameAssembly, FinishesFramesInOrderAndLetsTheNextOneIn) {
  FrameAssemblyConfig c = config(3);
  c.framesInFlight = 2;
  c.prefetchFrames = 2;
  FrameAssembly assembly(c, kPeers, kStart);
  const auto tasks = takeAll(assembly, kStart);
  ASSERT_EQ(tasks.size(), 8u);                    // frames 0 and 1
  EXPECT_TRUE(tasks[0].has_lookahead_camera());   // frame 0 looks at frame 2
  EXPECT_FALSE(tasks[4].has_lookahead_camera());  // frame 3 does not exist
  // Frame 1 comes back first: nothing finishes until frame 0 has.
  for (std::size_t i = 4; i < 8; ++i) assembly.tileArrived(tile(tasks[i], 10, 5), kStart + 1ms);
  EXPECT_TRUE(assembly.finishFrames(kStart + 1ms).empty());
  for (std::size_t i = 0; i < 4; ++i) assembly.tileArrived(tile(tasks[i], 10, 4), kStart + 2ms);
  const auto finished = assembly.finishFrames(kStart + 2ms);
  ASSERT_EQ(finished.size(), 2u);
  EXPECT_EQ(finished[0].record.frame, 0u);
  EXPECT_EQ(finished[1].record.frame, 1u);
  EXPECT_EQ(finished[0].record.splatsPerRender.at(4), 40u);
  EXPECT_EQ(finished[0].record.splatsPerRender.at(5), 0u);  // every render listed
  EXPECT_EQ(assembly.stats().frames.size(), 2u);
  EXPECT_FALSE(assembly.done());
  EXPECT_EQ(takeAll(assembly, kStart + 3ms).size(), 4u);  // frame 2 entered the window
  EXPECT_THROW(assembly.tileArrived(tile(tasks[0], 1, 3), kStart), ProtocolError);
}

// A render process is lost: the tiles it holds go out again at once, and so
// does one a traverse places on it after that; a tile held by the other
// render keeps its deadline; the frame completes from the others, a late copy
// from the lost one is not composed, and the run's statistics name it.
TEST(FrameAssembly, ALostRenderProcessesTilesGoOutAgainAtOnce) {
  FrameAssembly assembly(config(2), kPeers, kStart);
  const auto first = takeAll(assembly, kStart);
  ASSERT_EQ(first.size(), 4u);
  // Tiles 0 and 1 came back from render 4, which also holds tile 3; render 5
  // held tile 2 and died; tile 3's traverse had not yet said where it went.
  assembly.workRequested(1, placed(first[0], 0));
  assembly.workRequested(1, placed(first[1], 0));
  assembly.workRequested(1, placed(first[2], 1));
  EXPECT_EQ(assembly.tileArrived(tile(first[0], 100, 4), kStart + 10ms), TileArrival::Complete);
  EXPECT_EQ(assembly.tileArrived(tile(first[1], 100, 4), kStart + 10ms), TileArrival::Complete);
  EXPECT_EQ(assembly.renderLost(5, kStart + 200ms, "no word from it for 5.0 s"), 1u);
  EXPECT_EQ(assembly.planner().liveRenders(), 1u);
  // Long before the tile's deadline, it is handed out again.
  auto again = takeAll(assembly, kStart + 200ms);
  ASSERT_EQ(again.size(), 1u);
  EXPECT_EQ(again[0].tile_id(), first[2].tile_id());
  // Tile 3 turns out to have gone to the lost render as well: it goes back.
  assembly.workRequested(1, placed(first[3], 1));
  const auto more = takeAll(assembly, kStart + 210ms);
  ASSERT_EQ(more.size(), 1u);
  EXPECT_EQ(more[0].tile_id(), first[3].tile_id());
  again.push_back(more[0]);
  for (const auto& task : again) {
    EXPECT_EQ(task.attempt(), 1u);
    EXPECT_EQ(assembly.tileArrived(tile(task, 100, 4), kStart + 300ms), TileArrival::Complete);
  }
  const auto finished = assembly.finishFrames(kStart + 300ms);
  ASSERT_EQ(finished.size(), 1u);
  EXPECT_EQ(finished[0].record.reissuedTiles, 2u);
  EXPECT_EQ(finished[0].record.failedTiles, 0u);
  EXPECT_EQ(assembly.tileArrived(tile(first[2], 100, 5), kStart + 350ms), TileArrival::Late);
  ASSERT_EQ(assembly.stats().lost.size(), 1u);
  const LostProcess& lost = assembly.stats().lost[0];
  EXPECT_EQ(lost.role, "render");
  EXPECT_EQ(lost.rank, 5);
  EXPECT_DOUBLE_EQ(lost.seconds, 0.2);
  EXPECT_TRUE(lost.jobWentOn);
  EXPECT_NE(assembly.stats().summary().find("lost: render rank 5 at 0.20 s (no word from it for "
                                            "5.0 s); the job went on without it"),
            std::string::npos);
  EXPECT_NE(assembly.stats().toJson().find("\"lost_processes\": [{\"role\": \"render\", "
                                           "\"rank\": 5"),
            std::string::npos);
  // The next frame is planned for the one render left, and nothing is re-issued twice.
  const auto next = takeAll(assembly, kStart + 400ms);
  EXPECT_EQ(next.size(), 2u);  // tilesPerRender 2 x 1 render
  EXPECT_THROW(assembly.renderLost(4, kStart + 500ms, "gone"), UsageError);
}

// A tile image's payload is its RGBA8 pixels, and as many bytes again of
// depth when its header says so; anything else is refused.
TEST(FrameAssembly, ATileImagePayloadMustMatchItsRectAndDepth) {
  v1::TileImageHeader header;
  header.mutable_rect()->set_width(16);
  header.mutable_rect()->set_height(8);
  header.set_format(v1::PIXEL_FORMAT_RGBA8);
  EXPECT_EQ(tileImagePixelBytes(header, 16 * 8 * 4, 4), 512u);
  EXPECT_THROW(tileImagePixelBytes(header, 511, 4), ProtocolError);
  header.set_depth(v1::DEPTH_FORMAT_EYE_FLOAT32);
  EXPECT_EQ(tileImagePixelBytes(header, 1024, 4), 512u);
  EXPECT_THROW(tileImagePixelBytes(header, 512, 4), ProtocolError);
  header.set_depth(static_cast<v1::DepthFormat>(7));
  EXPECT_THROW(tileImagePixelBytes(header, 1024, 4), ProtocolError);
  header.set_depth(v1::DEPTH_FORMAT_NONE);
  header.mutable_rect()->set_width(0xFFFFFFFFu);  // 32-bit sides do not wrap in 64 bits
  header.mutable_rect()->set_height(0xFFFFFFFFu);
  EXPECT_THROW(tileImagePixelBytes(header, 0, 4), ProtocolError);
}

// A compressed tile image (compressed_bytes) is one zstd frame of what the
// other fields describe; the display expands it before anything else reads it.
TEST(FrameAssembly, ACompressedTileImageExpandsToWhatItsHeaderDescribes) {
  v1::TileImageHeader header;
  *header.mutable_rect() = makeTileRect(100, 40, 32, 16);
  header.set_format(v1::PIXEL_FORMAT_RGBA8);
  std::vector<std::uint8_t> pixels(32 * 16 * 4);
  for (std::size_t i = 0; i < pixels.size(); ++i) pixels[i] = static_cast<std::uint8_t>(i / 64);
  const std::vector<std::byte> frame = compressImageBytes(std::as_bytes(std::span(pixels)), 1);
  ASSERT_FALSE(frame.empty());
  std::vector<std::byte> storage;
  const std::vector<std::byte> plain(std::as_bytes(std::span(pixels)).begin(),
                                     std::as_bytes(std::span(pixels)).end());
  EXPECT_EQ(tileImagePayload(header, plain, storage, 4).size(), plain.size())
      << "not compressed: as it is";
  header.set_compressed_bytes(frame.size());
  header.set_uncompressed_bytes(pixels.size());
  EXPECT_EQ(tileImageBytes(header), frame.size()) << "what crossed the link";
  const std::span<const std::byte> payload = tileImagePayload(header, frame, storage, 4);
  ASSERT_EQ(payload.size(), pixels.size());
  EXPECT_EQ(std::memcmp(payload.data(), pixels.data(), pixels.size()), 0);
  EXPECT_EQ(tileImagePixelBytes(header, payload.size(), 4), pixels.size());
  std::vector<std::byte> longer = frame;
  longer.push_back(std::byte{0});
  EXPECT_THROW(tileImagePayload(header, longer, storage, 4), ProtocolError)
      << "more bytes than the header says";
  header.set_uncompressed_bytes(32 * 16 * 8 + 1);
  EXPECT_THROW(tileImagePayload(header, frame, storage, 4), ProtocolError)
      << "more than the rect could carry: refused before allocating";
  header.set_uncompressed_bytes(pixels.size() - 4);
  EXPECT_THROW(tileImagePayload(header, frame, storage, 4), ProtocolError)
      << "another size than the frame's";
  header.set_compressed_bytes(0);
  EXPECT_THROW(tileImagePayload(header, frame, storage, 4), ProtocolError)
      << "an expanded size without compression";
}

// A part of a split tile sends the point words of the box it drew in: the
// payload is that box's, and the box must lie in the tile.
TEST(FrameAssembly, APartSendsTheWordsOfTheBoxItDrewIn) {
  v1::TileImageHeader header;
  *header.mutable_rect() = makeTileRect(100, 40, 16, 8);
  header.set_format(v1::PIXEL_FORMAT_POINT_WORDS64);
  header.set_part_count(2);
  EXPECT_EQ(tileImagePixelBytes(header, 16 * 8 * 8, 4), 1024u) << "no box: the whole tile";
  *header.mutable_drawn_rect() = makeTileRect(103, 42, 5, 3);
  EXPECT_EQ(tileImagePixelBytes(header, 5 * 3 * 8, 4), 120u);
  EXPECT_THROW(tileImagePixelBytes(header, 1024, 4), ProtocolError);
  *header.mutable_drawn_rect() = makeTileRect(0, 0, 0, 0);
  EXPECT_EQ(tileImagePixelBytes(header, 0, 4), 0u) << "a part that drew nothing";
  // A whole tile sends its box of RGBA8 pixels, never with depth.
  header.set_format(v1::PIXEL_FORMAT_RGBA8);
  header.set_part_count(0);
  *header.mutable_drawn_rect() = makeTileRect(103, 42, 5, 3);
  EXPECT_EQ(tileImagePixelBytes(header, 5 * 3 * 4, 4), 60u);
  EXPECT_EQ(tileImageBytes(header), 60u);
  EXPECT_THROW(tileImagePixelBytes(header, 16 * 8 * 4, 4), ProtocolError);
  *header.mutable_drawn_rect() = makeTileRect(99, 42, 5, 3);
  EXPECT_THROW(tileImagePixelBytes(header, 5 * 3 * 4, 4), ProtocolError) << "left of its tile";
  *header.mutable_drawn_rect() = makeTileRect(103, 42, 5, 7);
  EXPECT_THROW(tileImagePixelBytes(header, 5 * 7 * 4, 4), ProtocolError) << "above its tile";
  *header.mutable_drawn_rect() = makeTileRect(103, 42, 5, 3);
  header.set_depth(v1::DEPTH_FORMAT_EYE_FLOAT32);
  EXPECT_THROW(tileImagePixelBytes(header, 5 * 3 * 8, 4), ProtocolError) << "boxed with depth";
  header.clear_drawn_rect();
  EXPECT_EQ(tileImagePixelBytes(header, 16 * 8 * 8, 4), 512u);
  EXPECT_EQ(tileImageBytes(header), 1024u);

  // As runs: the payload is the runs, expanded to the box with the
  // background where they skip; they must cover the box.
  header.set_depth(v1::DEPTH_FORMAT_NONE);
  *header.mutable_drawn_rect() = makeTileRect(103, 42, 5, 3);
  std::vector<std::uint8_t> box(5 * 3 * 4);
  for (std::size_t i = 0; i < box.size(); i += 4) {
    std::copy(kFrameBackground.begin(), kFrameBackground.end(),
              box.begin() + static_cast<std::ptrdiff_t>(i));
  }
  box[4 * 7] = 200;  // pixel (2,1) of the box
  const std::vector<std::byte> runs =
      encodePixelRuns(std::as_bytes(std::span(box)), 4, 5, PixelBox{0, 0, 5, 3},
                      std::as_bytes(std::span(kFrameBackground)));
  header.set_runs_bytes(runs.size());
  EXPECT_EQ(tileImagePixelBytes(header, runs.size(), 4), runs.size());
  EXPECT_EQ(tileImageBytes(header), runs.size());
  EXPECT_THROW(tileImagePixelBytes(header, runs.size() + 1, 4), ProtocolError);
  std::vector<std::byte> storage;
  const std::span<const std::byte> pixels = tileImagePixels(header, runs, runs.size(), storage);
  ASSERT_EQ(pixels.size(), box.size());
  EXPECT_EQ(std::memcmp(pixels.data(), box.data(), box.size()), 0);
  *header.mutable_drawn_rect() = makeTileRect(103, 42, 5, 4);
  EXPECT_THROW(tileImagePixels(header, runs, runs.size(), storage), ProtocolError)
      << "runs that do not cover the box";
  header.clear_drawn_rect();
  EXPECT_THROW(tileImagePixelBytes(header, runs.size(), 4), ProtocolError) << "runs without a box";

  // Composed: the box's words at their place, the rest of the tile untouched.
  const TileRect rect = header.rect();
  TilePartCompositor parts;
  std::vector<std::uint64_t> words(5 * 3, 0);
  for (std::size_t i = 0; i < words.size(); ++i) words[i] = 0xff0000ffu + (i << 8);
  parts.merge(1, 2, 0, rect, makeTileRect(103, 42, 5, 3), std::as_bytes(std::span(words)));
  parts.merge(1, 2, 0, rect, makeTileRect(0, 0, 0, 0), {});
  EXPECT_THROW(
      parts.merge(1, 2, 0, rect, makeTileRect(112, 42, 5, 3), std::as_bytes(std::span(words))),
      ProtocolError)
      << "reaches past the tile's right side";
  EXPECT_THROW(
      parts.merge(1, 2, 0, rect, makeTileRect(103, 39, 5, 3), std::as_bytes(std::span(words))),
      ProtocolError)
      << "starts below the tile";
  EXPECT_THROW(
      parts.merge(1, 2, 0, rect, makeTileRect(103, 42, 5, 2), std::as_bytes(std::span(words))),
      ProtocolError)
      << "more words than the box";
  const std::vector<std::uint8_t> rgba = parts.take(1, 2, 0, 0xff000000u);
  ASSERT_EQ(rgba.size(), 16u * 8u * 4u);
  for (std::uint32_t y = 0; y < 8; ++y) {
    for (std::uint32_t x = 0; x < 16; ++x) {
      const std::size_t at = (y * 16 + x) * 4;
      const bool inBox = x >= 3 && x < 8 && y >= 2 && y < 5;
      const std::uint32_t expected =
          inBox ? static_cast<std::uint32_t>(words[(y - 2) * 5 + (x - 3)]) : 0xff000000u;
      const std::uint32_t got = rgba[at] | rgba[at + 1] << 8 | rgba[at + 2] << 16 |
                                static_cast<std::uint32_t>(rgba[at + 3]) << 24;
      EXPECT_EQ(got, expected) << x << "," << y;
    }
  }
}

// Serve mode: each client's frame carries its own mode and level of detail to
// its tiles; a scheduler named by a frame holds from that frame on, and the
// run's own scheduler needs no override.
TEST(FrameAssembly, ServedFramesCarryTheirSettingsAndSchedulerToTheirTiles) {
  FrameAssembly assembly(config(0), kPeers, kStart);
  const auto serve = [&](float x, const v1::FrameSettings& settings) {
    assembly.appendCamera(camera(x), settings);
    const auto tasks = takeAll(assembly, kStart);
    EXPECT_FALSE(tasks.empty());
    for (const auto& task : tasks) assembly.tileArrived(tile(task, 100), kStart);
    EXPECT_EQ(assembly.finishFrames(kStart).size(), 1u);
    return tasks;
  };

  for (const auto& task : serve(0, {})) EXPECT_FALSE(task.has_frame_settings());

  v1::FrameSettings splats;
  splats.set_mode(v1::RENDER_MODE_SPLATS);
  splats.set_lod_pixels(2.0f);
  for (const auto& task : serve(1, splats)) {
    EXPECT_EQ(task.frame_settings().mode(), v1::RENDER_MODE_SPLATS);
    EXPECT_EQ(task.frame_settings().lod_pixels(), 2.0f);
    EXPECT_FALSE(task.frame_settings().has_scheduler());
  }

  v1::FrameSettings roundRobin;
  roundRobin.set_scheduler(v1::SCHEDULER_ROUND_ROBIN);
  const auto dealt = serve(2, roundRobin);
  ASSERT_GE(dealt.size(), 2u);
  for (std::size_t i = 0; i < dealt.size(); ++i) {
    EXPECT_EQ(dealt[i].frame_settings().scheduler(), v1::SCHEDULER_ROUND_ROBIN);
    EXPECT_EQ(dealt[i].frame_settings().mode(), v1::RENDER_MODE_UNSPECIFIED);
    EXPECT_EQ(dealt[i].assigned_render(), (dealt[0].assigned_render() + i) % 2) << "tile " << i;
  }
  // A frame naming no scheduler keeps the one in force.
  for (const auto& task : serve(3, {})) {
    EXPECT_EQ(task.frame_settings().scheduler(), v1::SCHEDULER_ROUND_ROBIN);
  }
  v1::FrameSettings cost;
  cost.set_scheduler(v1::SCHEDULER_COST);
  for (const auto& task : serve(4, cost)) {
    EXPECT_FALSE(task.frame_settings().has_scheduler()) << "the run's scheduler needs no override";
  }
}

}  // namespace
}  // namespace pointillist::display

namespace pointillist::display {
namespace {

// Serve mode's render cache orders a frame's tiles: the regions it could not
// fill go out first; the feedback still follows the plan's order.
TEST(FrameAssembly, ATilePriorityOrdersTheTilesHandedOut) {
  FrameAssembly plain(config(0), kPeers, kStart);
  plain.appendCamera(camera(0.0f));
  const auto planned = takeAll(plain, kStart);
  ASSERT_EQ(planned.size(), 4u);

  FrameAssembly prioritized(config(0), kPeers, kStart);
  // Right before left, top before bottom.
  prioritized.appendCamera(camera(0.0f), {}, [](const TileRect& rect) {
    return static_cast<double>(rect.x()) * 1000.0 + rect.y();
  });
  const auto ordered = takeAll(prioritized, kStart);
  ASSERT_EQ(ordered.size(), planned.size());
  for (std::size_t i = 1; i < ordered.size(); ++i) {
    const auto& before = ordered[i - 1].rect();
    const auto& after = ordered[i].rect();
    EXPECT_GE(before.x() * 1000.0 + before.y(), after.x() * 1000.0 + after.y());
  }
  // The same tiles, each once, under the plan's tile ids.
  auto sortedPlanned = rects(planned), sortedOrdered = rects(ordered);
  std::sort(sortedPlanned.begin(), sortedPlanned.end());
  std::sort(sortedOrdered.begin(), sortedOrdered.end());
  EXPECT_EQ(sortedPlanned, sortedOrdered);
  for (const auto& task : ordered) {
    EXPECT_EQ(rects({planned[task.tile_id()]}), rects({task}));
  }
  for (const auto& task : ordered) {
    EXPECT_EQ(prioritized.tileArrived(tile(task, 100), kStart + 10ms), TileArrival::Complete);
  }
  EXPECT_EQ(prioritized.finishFrames(kStart + 10ms).size(), 1u);
}

TEST(FrameScheduler, RefusesATileOrderThatIsNotAPermutation) {
  FrameScheduler scheduler(1, std::chrono::seconds(1), 3);
  const std::vector<TileRect> tiles{makeTileRect(0, 0, 8, 8), makeTileRect(8, 0, 8, 8)};
  EXPECT_THROW(scheduler.addFrame(0, camera(0.0f), tiles, {0, 0}), UsageError);
  EXPECT_THROW(scheduler.addFrame(0, camera(0.0f), tiles, {1}), UsageError);
  scheduler.addFrame(0, camera(0.0f), tiles, {1, 0});
  EXPECT_EQ(scheduler.nextTask(FrameScheduler::Clock::now())->tile, 1u);
  EXPECT_EQ(scheduler.nextTask(FrameScheduler::Clock::now())->tile, 0u);
}

}  // namespace
}  // namespace pointillist::display

namespace pointillist::display {
namespace {

v1::TileImageHeader part(const v1::TileTask& task, std::uint32_t index, std::uint32_t count,
                         std::uint64_t splats, int render) {
  v1::TileImageHeader header = tile(task, splats, render);
  header.set_format(v1::PIXEL_FORMAT_POINT_WORDS64);
  header.set_part_index(index);
  header.set_part_count(count);
  header.set_render_time_us(static_cast<std::int64_t>(splats));
  return header;
}

// A split tile (docs/scheduling.md §9) is in when every part of one attempt
// is: each part counts as its own render's work, a copy or a part of an
// attempt that lost is only counted, and the planner learns the tile's sum.
TEST(FrameAssembly, ASplitTileIsInWhenEveryPartOfOneAttemptIs) {
  FrameAssembly assembly(config(2), kPeers, kStart);
  const auto tasks = takeAll(assembly, kStart);
  ASSERT_EQ(tasks.size(), 4u);
  for (std::size_t i = 1; i < 4; ++i) {
    EXPECT_EQ(assembly.tileArrived(tile(tasks[i], 100), kStart + 1ms), TileArrival::Complete);
  }
  EXPECT_EQ(assembly.tileArrived(part(tasks[0], 1, 3, 400, 5), kStart + 2ms), TileArrival::Part);
  EXPECT_EQ(assembly.tileArrived(part(tasks[0], 1, 3, 400, 5), kStart + 2ms), TileArrival::Late)
      << "a copy of a part";
  EXPECT_EQ(assembly.tileArrived(part(tasks[0], 0, 3, 500, 4), kStart + 3ms), TileArrival::Part);
  EXPECT_TRUE(assembly.finishFrames(kStart + 3ms).empty()) << "a part is still out";
  EXPECT_THROW(assembly.tileArrived(part(tasks[0], 3, 3, 1, 4), kStart), ProtocolError);
  EXPECT_EQ(assembly.tileArrived(part(tasks[0], 2, 3, 600, 4), kStart + 4ms),
            TileArrival::Complete);
  EXPECT_EQ(assembly.tileArrived(part(tasks[0], 2, 3, 600, 4), kStart + 4ms), TileArrival::Late);
  const auto finished = assembly.finishFrames(kStart + 4ms);
  ASSERT_EQ(finished.size(), 1u);
  const FrameRecord& record = finished[0].record;
  EXPECT_EQ(record.splats, 300u + 1500u);
  EXPECT_EQ(record.splatsPerRender.at(4), 300u + 500u + 600u);
  EXPECT_EQ(record.splatsPerRender.at(5), 400u);
  EXPECT_EQ(assembly.stats().splitTiles, 1u);
  EXPECT_EQ(assembly.stats().tileParts, 3u);
  EXPECT_EQ(assembly.stats().lateTiles, 2u);
}

v1::TileImageHeader background(const v1::TileTask& task, int traverse = 1) {
  v1::TileImageHeader header;
  header.set_frame_id(task.frame_id());
  header.set_tile_id(task.tile_id());
  *header.mutable_rect() = task.rect();
  header.set_attempt(task.attempt());
  header.set_format(v1::PIXEL_FORMAT_BACKGROUND);
  header.set_render_rank(-1);
  header.set_traverse_rank(traverse);
  return header;
}

// A traverse that found nothing in a tile answers it: the tile is in, no
// render did any work for it, and only a traverse may say so.
TEST(FrameAssembly, ABackgroundTileFromATraverseIsInAndNoRendersWork) {
  FrameAssembly assembly(config(1), kPeers, kStart);
  const auto tasks = takeAll(assembly, kStart);
  ASSERT_EQ(tasks.size(), 4u);
  EXPECT_THROW(assembly.tileArrived(background(tasks[0], 4), kStart), ProtocolError)
      << "a render is not a traverse";
  v1::TileImageHeader asPart = background(tasks[0]);
  asPart.set_part_count(2);
  EXPECT_THROW(assembly.tileArrived(asPart, kStart), ProtocolError);
  EXPECT_EQ(assembly.tileArrived(background(tasks[0], 2), kStart + 1ms), TileArrival::Complete);
  EXPECT_EQ(assembly.tileArrived(background(tasks[0], 2), kStart + 1ms), TileArrival::Late);
  EXPECT_EQ(assembly.tileProgress(0), std::make_pair(1u, 4u));
  for (std::size_t i = 1; i < 4; ++i) {
    EXPECT_EQ(assembly.tileArrived(tile(tasks[i], 100), kStart + 2ms), TileArrival::Complete);
  }
  const auto finished = assembly.finishFrames(kStart + 2ms);
  ASSERT_EQ(finished.size(), 1u);
  EXPECT_EQ(finished[0].record.splats, 300u);
  EXPECT_EQ(finished[0].record.splatsPerRender.at(4), 300u);
  EXPECT_EQ(finished[0].record.splatsPerRender.at(5), 0u);
  EXPECT_EQ(finished[0].record.failedTiles, 0u);
  EXPECT_EQ(assembly.stats().backgroundTiles, 1u);
  EXPECT_EQ(assembly.stats().lateTiles, 1u);

  // It carries nothing: no pixels, no depth, no part.
  v1::TileImageHeader header = background(tasks[0]);
  EXPECT_EQ(tileImagePixelBytes(header, 0, 1), 0u);
  EXPECT_THROW(tileImagePixelBytes(header, 4, 1), ProtocolError);
  header.set_depth(v1::DEPTH_FORMAT_EYE_FLOAT32);
  EXPECT_THROW(tileImagePixelBytes(header, 0, 1), ProtocolError);
}

TEST(FrameAssembly, ARetriedSplitTileTakesTheAttemptThatCompletesFirst) {
  FrameAssemblyConfig c = config(1);
  FrameAssembly assembly(c, kPeers, kStart);
  const auto tasks = takeAll(assembly, kStart);
  ASSERT_EQ(tasks.size(), 4u);
  for (std::size_t i = 1; i < 4; ++i) assembly.tileArrived(tile(tasks[i], 100), kStart);
  // The first attempt's part 0 arrives, then the tile times out.
  EXPECT_EQ(assembly.tileArrived(part(tasks[0], 0, 2, 10, 4), kStart), TileArrival::Part);
  const auto retried = takeAll(assembly, kStart + 2s);
  ASSERT_EQ(retried.size(), 1u);
  EXPECT_EQ(retried[0].attempt(), 1u);
  // The retry is split three ways; its parts never complete the first attempt.
  EXPECT_EQ(assembly.tileArrived(part(retried[0], 0, 3, 10, 5), kStart + 2s), TileArrival::Part);
  EXPECT_EQ(assembly.tileArrived(part(retried[0], 1, 3, 10, 5), kStart + 2s), TileArrival::Part);
  EXPECT_EQ(assembly.tileArrived(part(tasks[0], 1, 2, 10, 4), kStart + 2s), TileArrival::Complete)
      << "the first attempt's last part completes it";
  EXPECT_EQ(assembly.tileArrived(part(retried[0], 2, 3, 10, 5), kStart + 2s), TileArrival::Late);
  EXPECT_EQ(assembly.finishFrames(kStart + 2s).size(), 1u);
  EXPECT_TRUE(assembly.done());
}

TEST(FrameAssembly, TasksAskForSplitsFromLastFramesWorkAndOnlyWhereComposingIsExact) {
  const auto partSplats = [](FrameAssemblyConfig c) {
    FrameAssembly assembly(c, kPeers, kStart);
    std::vector<std::uint64_t> perFrame;
    for (std::size_t frame = 0; frame < c.cameras.size(); ++frame) {
      const auto tasks = takeAll(assembly, kStart);
      perFrame.push_back(tasks.empty() ? 0 : tasks[0].part_splats());
      for (const auto& task : tasks) assembly.tileArrived(tile(task, 20'000), kStart);
      assembly.finishFrames(kStart);
    }
    return perFrame;
  };
  // Tiles of at most 64 px a side cannot be halved: the frame is two 64 x 64
  // tiles. Before a measured frame, a splat per pixel (128 x 64) over the
  // two renders, at least the floor; then the two tiles' 40k over two renders.
  const auto unsplittable = [](FrameAssemblyConfig c) {
    c.plan.minTileSize = 64;
    return c;
  };
  EXPECT_EQ(partSplats(unsplittable(config(2))), (std::vector<std::uint64_t>{4096, 20'000}));
  EXPECT_EQ(partSplats(unsplittable(config(2, 3, SchedulerKind::Regions))),
            (std::vector<std::uint64_t>{4096, 20'000}));
  // Tiles the next plan can still halve are not split by their data.
  EXPECT_EQ(partSplats(config(2)), (std::vector<std::uint64_t>{0, 0}));
  // A part size the run fixes holds for every tile.
  FrameAssemblyConfig fixed = config(2);
  fixed.run.set_tile_part_splats(3000);
  EXPECT_EQ(partSplats(fixed), (std::vector<std::uint64_t>{3000, 3000}));
  FrameAssemblyConfig off = unsplittable(config(2));
  off.run.set_no_tile_split(true);
  EXPECT_EQ(partSplats(off), (std::vector<std::uint64_t>{0, 0}));
  FrameAssemblyConfig gl = unsplittable(config(2));
  gl.run.set_renderer(v1::RENDERER_GL);
  EXPECT_EQ(partSplats(gl), (std::vector<std::uint64_t>{0, 0}));
  EXPECT_EQ(partSplats(unsplittable(config(2, 3, SchedulerKind::RoundRobin))),
            (std::vector<std::uint64_t>{0, 0}));
}

// The display tunes the part size on the frame rate it sees: frames whose
// parts are twice as large come in twice as fast here, so after the warm-up
// and a trial of each, the tasks ask for parts of twice the share (x4 is no
// faster: x8 is tried once more before it settles).
TEST(FrameAssembly, TasksAskForTheTunedPartSizeWhereLargerPartsMakeFramesFaster) {
  const auto run = [](FrameAssemblyConfig c) {
    c.plan.minTileSize = 64;  // two 64 x 64 tiles a frame, too small to halve
    c.partTuning.warmupFrames = 1;
    c.partTuning.trialFrames = 3;
    c.partTuning.settleFrames = 0;
    FrameAssembly assembly(c, kPeers, kStart);
    std::vector<std::uint64_t> perFrame;
    TimePoint now = kStart;
    for (std::size_t frame = 0; frame < c.cameras.size(); ++frame) {
      const auto tasks = takeAll(assembly, now);
      const std::uint64_t size = tasks.empty() ? 0 : tasks[0].part_splats();
      perFrame.push_back(size);
      now += size >= 40'000 ? 5ms : 10ms;
      for (const auto& task : tasks) {
        assembly.tileArrived(part(task, 0, 2, 10'000, 4), now);
        assembly.tileArrived(part(task, 1, 2, 10'000, 5), now);
      }
      assembly.finishFrames(now);
    }
    return std::make_pair(perFrame, assembly.stats().partSizeTuning);
  };
  const auto [sizes, tuning] = run(config(24));
  // Frame 0 unmeasured (4096); the share is then 40k splats over two renders:
  // x1, x2, x1 again (x2 kept), x4, x2 again (no faster: x8 once more), x2.
  EXPECT_EQ(sizes, (std::vector<std::uint64_t>{4096,    20'000, 20'000, 20'000, 40'000,  40'000,
                                               40'000,  20'000, 20'000, 20'000, 80'000,  80'000,
                                               80'000,  40'000, 40'000, 40'000, 160'000, 160'000,
                                               160'000, 40'000, 40'000, 40'000, 40'000,  40'000}));
  EXPECT_NE(tuning.find("sized x2 by the frame rate (x1 100.0, x2 200.0, x4 200.0, x8 200.0 "
                        "frames/s; 7 trials)"),
            std::string::npos)
      << tuning;
  // Not tuned: share, a fixed size, or where the caller says (serve mode).
  FrameAssemblyConfig share = config(24);
  share.run.set_tile_part_untuned(true);
  EXPECT_EQ(run(share).first.back(), 20'000u);
  FrameAssemblyConfig served = config(24);
  served.tunePartSize = false;
  EXPECT_EQ(run(served).first.back(), 20'000u);
  EXPECT_TRUE(run(served).second.empty());
  EXPECT_FALSE(FrameAssembly(served, kPeers, kStart).tunesPartSize());
  EXPECT_TRUE(FrameAssembly(config(1), kPeers, kStart).tunesPartSize());
  FrameAssemblyConfig fixed = config(1);
  fixed.run.set_tile_part_splats(3000);
  EXPECT_FALSE(FrameAssembly(fixed, kPeers, kStart).tunesPartSize());
  EXPECT_FALSE(
      FrameAssembly(config(1, 3, SchedulerKind::RoundRobin), kPeers, kStart).tunesPartSize());
}

// The cost scheduler's tile count is tuned the same way: frames of fewer
// tiles come faster here (as where the traverse processes walk every tile),
// so after a trial of each the frames are planned with a quarter of the
// tiles (x8 is no faster), still covering the box of interest once.
TEST(FrameAssembly, FramesArePlannedWithFewerTilesWhereThatMakesThemFaster) {
  // Each tile takes its render `splats` / 10 us (the tile helper).
  // `traversesLate`: tiles wait that long for a traverse to ask each frame.
  const auto run = [](FrameAssemblyConfig c, std::uint64_t splats = 100,
                      const PeerRanks& peers = kPeers,
                      std::chrono::milliseconds traversesLate = 0ms) {
    c.plan.tilesPerRender = 8.0;  // 16 tiles a frame
    c.tileTuning.warmupFrames = 1;
    c.tileTuning.trialFrames = 3;
    c.tileTuning.settleFrames = 0;
    c.tunePartSize = false;
    FrameAssembly assembly(c, peers, kStart);
    std::vector<std::size_t> perFrame;
    TimePoint now = kStart;
    for (std::size_t frame = 0; frame < c.cameras.size(); ++frame) {
      std::vector<v1::TileTask> tasks;
      if (traversesLate > 0ms) {
        Outbox out;
        assembly.dispatch(now, out);  // the request left over from the last frame
        tasks = tasksIn(out);
        now += traversesLate;
      }
      const auto more = takeAll(assembly, now);
      tasks.insert(tasks.end(), more.begin(), more.end());
      perFrame.push_back(tasks.size());
      std::vector<TileRect> rects;
      for (const auto& task : tasks) rects.push_back(task.rect());
      if (const auto area =
              boxOfInterest(c.cameras[frame], c.bounds.min, c.bounds.max, c.marginWorld)) {
        expectExactCover(*area, rects);
      }
      now += tasks.size() > 4 ? 10ms : 5ms;
      for (const auto& task : tasks) assembly.tileArrived(tile(task, splats), now);
      assembly.finishFrames(now);
    }
    return std::make_pair(perFrame, assembly.stats());
  };
  const auto [tiles, stats] = run(config(24));
  // x1, x2 (no faster: x4 once more), x1 again, x4, x1 again (x4 kept), x8,
  // x4 again (x8 no faster), x4.
  EXPECT_EQ(tiles, (std::vector<std::size_t>{16, 16, 16, 16, 8, 8, 8, 16, 16, 16, 4, 4,
                                             4,  16, 16, 16, 2, 2, 2, 4,  4,  4,  4, 4}));
  EXPECT_EQ(stats.tilesPerRenderTuned, 2.0);
  EXPECT_NE(stats.tileCountTuning.find("2 per render process by the frame rate (8: 100.0, 4: "
                                       "100.0, 2: 200.0, 1: 200.0 frames/s; 7 trials)"),
            std::string::npos)
      << stats.tileCountTuning;
  EXPECT_NE(stats.summary().find("tiles: 2 per render process"), std::string::npos);
  // Renders busy for most of a frame: fewer tiles would leave those that
  // keep one over half busy, so no trial goes below the tile count given.
  const auto busy = run(config(24), 4000).first;  // 16 tiles of 0.4 ms: 3.2 ms of 10 per render
  EXPECT_EQ(std::count(busy.begin(), busy.end(), 16u), 24) << ::testing::PrintToString(busy);
  // 1.6 ms of 10 per render: one level (half the tiles) may be tried, no further.
  const auto third = run(config(24), 2000).first;
  EXPECT_EQ(*std::min_element(third.begin(), third.end()), 8u) << ::testing::PrintToString(third);
  // Uneven work: of four renders, one draws every tile, 5.6 ms of 10. The
  // mean share (0.14) would let one level through, but twice the busiest
  // render's work would fill the frame: no trial.
  const PeerRanks fourRenders = PeerRanks::contiguous(JobLayout{1, 2, 1, 4});
  const auto uneven = run(config(24), 3500, fourRenders).first;
  EXPECT_EQ(std::count(uneven.begin(), uneven.end(), 16u), 24) << ::testing::PrintToString(uneven);
  // At 3 ms of 10 the busiest allows one level, not the two the mean would.
  const auto lighter = run(config(24), 1875, fourRenders).first;
  EXPECT_EQ(*std::min_element(lighter.begin(), lighter.end()), 8u)
      << ::testing::PrintToString(lighter);
  // The same uneven work where tiles wait for the traverses most of the
  // time (12 ms of 22): fewer tiles are fewer walks, so the mean decides
  // (0.06: two levels).
  const auto [traverseHeld, heldStats] = run(config(24), 3500, fourRenders, 12ms);
  EXPECT_EQ(*std::min_element(traverseHeld.begin(), traverseHeld.end()), 4u)
      << ::testing::PrintToString(traverseHeld);
  // The run's statistics count the wait: 12 ms in every frame that had tiles.
  EXPECT_GE(heldStats.requestWaitSeconds, 23 * 0.012 - 1e-9);
  EXPECT_LE(heldStats.requestWaitSeconds, 24 * 0.012 + 1e-9);
  EXPECT_EQ(stats.requestWaitSeconds, 0.0);
  // The display times its own tile layout, and the summary says it.
  EXPECT_GT(stats.planSeconds, 0.0);
  EXPECT_GT(stats.keyFigures().planMsPerFrame, 0.0);
  EXPECT_NE(stats.summary().find("tiles: laid out in "), std::string::npos);
  // Waiting a little (3 ms of 13) leaves the busiest render's cap in force:
  // at 7.2 ms of 13 no trial, where the mean (0.14) would allow one level.
  const auto shortWait = run(config(24), 4500, fourRenders, 3ms).first;
  EXPECT_EQ(std::count(shortWait.begin(), shortWait.end(), 16u), 24)
      << ::testing::PrintToString(shortWait);
  // Not tuned where the run gives the tile count, nor for other schedulers.
  FrameAssemblyConfig given = config(24);
  given.tuneTileCount = false;
  EXPECT_EQ(run(given).first.back(), 16u);
  EXPECT_FALSE(FrameAssembly(given, kPeers, kStart).tunesTileCount());
  EXPECT_TRUE(FrameAssembly(config(1), kPeers, kStart).tunesTileCount());
  EXPECT_FALSE(
      FrameAssembly(config(1, 3, SchedulerKind::Regions), kPeers, kStart).tunesTileCount());
}

}  // namespace
}  // namespace pointillist::display
