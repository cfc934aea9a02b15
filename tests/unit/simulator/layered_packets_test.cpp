// Layered packets (dataset format 4) end to end through the real cores, without
// MPI: a camera comes closer to the built-in city; for every frame the
// traversal's ranges go through the traverse's planner, the data-send's ledger
// and the render's core, and the bytes that travel are the dataset's own.
// LOD-layered packets must deliver exactly the splats the traversal asked for:
// the render can draw every range from what it received, each splat travels
// once, and nothing travels but the drawn ranges (joined across gaps of at
// most the run's gap, common/run_settings.hpp): not the culled cells a prefix
// through them holds.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstring>
#include <map>
#include <memory>

#include "common/camera.hpp"
#include "common/cell_ranges.hpp"
#include "common/ownership.hpp"
#include "datasend/core/send_ledger.hpp"
#include "render/core/render_core.hpp"
#include "test_city.hpp"
#include "traverse/core/octree_traversal.hpp"
#include "traverse/core/packet_layers.hpp"
#include "traverse/core/packet_planner.hpp"

namespace pointillist {
namespace {

using namespace std::chrono_literals;

const DatasetContent& city() {
  static const DatasetContent content = simulator::fixtures::smallCityContent(60'000, 9, 32, 2);
  return content;
}

// Top-level cell k's packet as points.bin holds it: level-splats, then points.
std::vector<std::vector<Splat>> packetsOf(const DatasetContent& content) {
  std::vector<std::vector<Splat>> packets;
  std::size_t points = 0, splats = 0;
  for (const TopLevelCell& t : content.topLevel) {
    std::vector<Splat>& packet = packets.emplace_back();
    packet.insert(
        packet.end(), content.levelSplats.begin() + static_cast<std::ptrdiff_t>(splats),
        content.levelSplats.begin() + static_cast<std::ptrdiff_t>(splats) + t.levelSplatCount);
    packet.insert(packet.end(), content.points.begin() + static_cast<std::ptrdiff_t>(points),
                  content.points.begin() + static_cast<std::ptrdiff_t>(points) + t.pointCount);
    points += t.pointCount;
    splats += t.levelSplatCount;
  }
  return packets;
}

bool sameSplats(std::span<const Splat> a, std::span<const Splat> b) {
  return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size_bytes()) == 0;
}

TEST(LayeredPackets, DeliverExactlyTheSplatsTheTraversalAskedFor) {
  const DatasetContent& content = city();
  const auto packets = packetsOf(content);
  const auto layers =
      std::make_shared<const traverse::PacketLayers>(content.cells, content.topLevel);
  // Layout 1,1,1,1: display 0, traverse 1, data-send 2, render 3.
  const PeerRanks peers = PeerRanks::contiguous(JobLayout{1, 1, 1, 1});
  const std::vector<std::uint32_t> owners = assignOwners(content.topLevel, 1);
  v1::RunSettings settings;
  settings.set_lod_pixels(1.0f);
  settings.set_size_scale(1.0f);
  settings.set_scheduler(v1::SCHEDULER_COST);
  traverse::PacketPlanner planner(peers, 1, settings, layers, owners);
  datasend::SendLedger ledger(peers, owners, 0);
  render::RenderCoreConfig config;
  config.cacheCapBytes = 1ull << 30;  // nothing is evicted: every byte counts
  render::RenderCore core(config, peers, 3, content.topLevel, owners);

  // What the render holds per cell (the bytes that travelled, and where they
  // lie), and what any frame's traversal asked for.
  std::map<std::uint32_t, std::vector<Splat>> held;
  std::map<std::uint32_t, SpanSet> arrived;
  std::map<std::uint32_t, SpanSet> asked;
  std::uint64_t bytesMoved = 0;
  std::vector<std::uint64_t> bytesPerFrame;
  std::uint64_t firstFramePacketBytes = 0;  // whole packets of the cells frame 0 draws from
  std::uint64_t firstFramePrefixBytes = 0;  // the prefixes holding its ranges
  TimePoint now = timeAfterEpoch(10.0);

  const glm::vec3 low(content.manifest.boundsMin[0], content.manifest.boundsMin[1],
                      content.manifest.boundsMin[2]);
  const glm::vec3 high(content.manifest.boundsMax[0], content.manifest.boundsMax[1],
                       content.manifest.boundsMax[2]);
  const float distances[] = {8.0f, 4.0f, 2.0f, 1.0f, 0.6f, 0.35f};
  std::uint64_t frame = 0;
  for (float distance : distances) {
    const Camera camera = cameraForBounds(low, high, 320, 200, 30.0f, 25.0f, distance);
    const traverse::TraversalResult walk =
        traverse::traverseTile(content.cells, camera, fullFrameRect(camera), planner.traversal());
    ASSERT_FALSE(walk.ranges.empty()) << "frame " << frame;
    v1::TileTask task;
    task.set_frame_id(frame);
    *task.mutable_camera() = camera;
    *task.mutable_rect() = fullFrameRect(camera);
    Outbox out;
    const traverse::PacketPlan plan =
        planner.planPackets(task, traverse::walkOf(walk), {}, now, out).front();

    // The needs are the drawn ranges, joined where a few splats apart: every
    // needed splat is drawn, or lies in such a gap.
    std::vector<CellRange> drawn;
    for (const traverse::PacketRange& range : walk.ranges)
      drawn.push_back({range.topLevel, range.offset, range.count});
    std::vector<CellRange> expected = drawn;
    normalizeCellRanges(expected, needGapSplats(settings));
    ASSERT_EQ(plan.needs, expected) << "frame " << frame;
    std::map<std::uint32_t, SpanSet> drawnSpans;
    for (const CellRange& range : drawn)
      drawnSpans[range.cell].add(range.first, static_cast<std::uint32_t>(range.end()));
    for (const CellRange& need : plan.needs) {
      drawnSpans[need.cell].forEachGap(need.first, static_cast<std::uint32_t>(need.end()),
                                       [&](std::uint32_t b, std::uint32_t e) {
                                         EXPECT_LE(e - b, needGapSplats(settings))
                                             << "cell " << need.cell << " splat " << b;
                                       });
      asked[need.cell].add(need.first, static_cast<std::uint32_t>(need.end()));
    }

    // Orders to the data-send; its ranges carry the dataset's bytes to the render.
    std::uint64_t moved = 0;
    render::RenderEffects effects;
    for (const Outgoing& outgoing : out.entries()) {
      if (outgoing.kind == MessageKind::SendOrder) {
        for (const CellRange& range : ledger.rangesToSend(outgoing.as<v1::SendOrder>())) {
          const std::span<const Splat> part =
              std::span<const Splat>(packets.at(range.cell)).subspan(range.first, range.count);
          ASSERT_EQ(core.receiveData(range.cell, range.first, range.count, 1e-3, now, effects),
                    render::DataVerdict::Store);
          std::vector<Splat>& cell = held[range.cell];
          cell.resize(packets.at(range.cell).size());
          std::copy(part.begin(), part.end(), cell.begin() + range.first);
          const auto end = static_cast<std::uint32_t>(range.end());
          ASSERT_EQ(arrived[range.cell].add(range.first, end), range.count)
              << "a splat of cell " << range.cell << " travelled twice";
          moved += range.count * sizeof(Splat);
        }
      } else if (outgoing.kind == MessageKind::RenderPacket) {
        core.receivePacket(1, outgoing.as<v1::RenderPacket>(), now, effects);
      }
    }
    bytesMoved += moved;
    bytesPerFrame.push_back(moved);
    if (frame == 0) {
      for (const CellPrefix& need : walk.needs) {
        firstFramePacketBytes += packets[need.cell].size() * sizeof(Splat);
        firstFramePrefixBytes += std::uint64_t{need.splats} * sizeof(Splat);
      }
    }
    // The render's own requests find nothing left to send: the traverse ordered it all.
    for (const Outgoing& outgoing : effects.messages.entries()) {
      if (outgoing.kind == MessageKind::SendOrder) {
        EXPECT_TRUE(ledger.rangesToSend(outgoing.as<v1::SendOrder>()).empty());
      }
    }

    // The packet is ready, and every range draws the dataset's splats from
    // what the render received.
    render::RenderEffects drawEffects;
    const auto ready = core.nextPacket(now, drawEffects);
    ASSERT_TRUE(ready) << "frame " << frame << ": data missing";
    const v1::RenderPacket& packet = ready->packet;
    for (int r = 0; r < packet.range_top_level_size(); ++r) {
      const std::uint32_t cell = packet.range_top_level(r);
      const std::uint32_t offset = packet.range_offset(r), count = packet.range_count(r);
      ASSERT_TRUE(arrived[cell].covers(offset, offset + count)) << "range beyond what arrived";
      ASSERT_TRUE(sameSplats(std::span<const Splat>(held[cell]).subspan(offset, count),
                             std::span<const Splat>(packets[cell]).subspan(offset, count)));
    }
    core.packetDrawn(*ready, walk.splats, 1e-3, now, drawEffects);
    for (const Outgoing& outgoing : drawEffects.messages.entries()) {
      if (outgoing.kind == MessageKind::RenderReport) {
        planner.applyReport(3, outgoing.as<v1::RenderReport>(), now);
      }
    }
    now += 100ms;
    ++frame;
  }

  // Nothing but the asked ranges travelled, and each splat once.
  std::uint64_t askedBytes = 0;
  for (const auto& [cell, spans] : asked) {
    EXPECT_EQ(arrived[cell], spans) << "cell " << cell;
    EXPECT_EQ(core.heldSplats(cell), spans.splats());
    askedBytes += spans.splats() * sizeof(Splat);
  }
  EXPECT_EQ(arrived.size(), asked.size());
  EXPECT_EQ(bytesMoved, askedBytes);
  EXPECT_EQ(core.dataBytesReceived(), askedBytes);
  // Not vacuous: distant frames move a small part of the packets they draw
  // from, less than the prefixes through their ranges, and coming closer adds
  // to cells already held.
  EXPECT_LT(bytesPerFrame.front() * 4, firstFramePacketBytes)
      << "the first frame moved whole packets";
  EXPECT_LT(bytesPerFrame.front() * 5, firstFramePrefixBytes * 4)
      << "the first frame moved as much as the prefixes through its ranges";
  EXPECT_GT(ledger.extensionsSent(), 0u);
}

}  // namespace
}  // namespace pointillist
