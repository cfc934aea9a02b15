// libFuzzer target: what the roles do with a received MPI message, through
// their MPI-free cores (the same functions the roles call): a kind byte, a
// two-byte header length, the protobuf header, then the raw payload.
//   TileImage    display: payload check, the frame assembly, the blit
//   RenderPacket render: the packet against the dataset's packets, queueing
//   DataPacket   render: header check, then the splats into the cache
//   SendOrder    data-send: the ranges to send
//   RenderReport data-send: evictions and holdings
//   TileTask     traverse: the walk of the task's camera and rect (and its
//                lookahead camera) over a small city, then the packet plan
//   RenderReport traverse: the render model's update
// The job is 1,2,1,2 (display 0, traverses 1-2, data-send 3, renders 4-5);
// the display, render and data-send parts see 8 made-up top-level cells, the
// traverse part a real 3000-point city. ProtocolError (and the blit's UsageError) are the
// refusals a bad message should get; a crash, a sanitizer report or any
// other exception is a finding.
#include <cstddef>
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "common/errors.hpp"
#include "common/image.hpp"
#include "common/job_layout.hpp"
#include "common/ownership.hpp"
#include "common/peer_ranks.hpp"
#include "common/splat.hpp"
#include "datasend/core/send_ledger.hpp"
#include "display/core/frame_assembly.hpp"
#include "display/core/tile_parts.hpp"
#include "preprocess/dataset_builder.hpp"
#include "preprocess/generator.hpp"
#include "render/core/render_core.hpp"
#include "traverse/core/octree_traversal.hpp"
#include "traverse/core/packet_planner.hpp"

namespace {

using namespace pointillist;
using namespace std::chrono_literals;

const PeerRanks kPeers = PeerRanks::contiguous(JobLayout{1, 2, 1, 2});
const TimePoint kStart = timeAfterEpoch(10.0);

std::vector<TopLevelCell> topLevelCells() {
  std::vector<TopLevelCell> cells;
  std::uint64_t offset = 0;
  for (std::uint32_t i = 0; i < 8; ++i) {
    const std::uint32_t points = 100 + 37 * i;
    const std::uint32_t levels = 10 + i;
    const std::uint64_t bytes = std::uint64_t{points + levels} * sizeof(Splat);
    cells.push_back({i * 3, points, levels, 0, offset, bytes});
    offset += bytes;
  }
  return cells;
}

const std::vector<TopLevelCell> kCells = topLevelCells();

display::FrameAssemblyConfig assemblyConfig() {
  display::FrameAssemblyConfig c;
  for (int i = 0; i < 2; ++i) {
    c.cameras.push_back(makeCamera({static_cast<float>(i), 0, 0}, {static_cast<float>(i) + 1, 0, 0},
                                   {0, 0, 1}, 60.0f, 0.1f, 100.0f, 128, 64));
  }
  c.bounds = SceneBounds{{-50, -50, -50}, {50, 50, 50}};
  c.framesInFlight = 2;
  c.tileTimeout = 1s;
  c.plan.renders = 2;
  c.plan.tilesPerRender = 2.0;
  c.plan.minTileSize = 8;
  return c;
}

void tileImage(const v1::TileImageHeader& header, std::span<const std::byte> payload) {
  display::FrameAssembly assembly(assemblyConfig(), kPeers, kStart);
  for (int asks = 0; asks < 16; ++asks) {  // every tile out, as traverses ask
    assembly.workRequested(1);
    Outbox out;
    assembly.dispatch(kStart, out);
    if (out.empty()) break;
  }
  const std::uint64_t pixelBytes = display::tileImagePixelBytes(header, payload.size(), 4);
  const display::TileArrival arrival = assembly.tileArrived(header, kStart + 1ms);
  if (arrival == display::TileArrival::Late) return;
  std::vector<std::byte> expanded;
  const std::span<const std::byte> pixels =
      display::tileImagePixels(header, payload, pixelBytes, expanded);
  const auto* bytes = reinterpret_cast<const std::uint8_t*>(pixels.data());
  std::vector<std::uint8_t> composed;
  if (header.format() == v1::PIXEL_FORMAT_POINT_WORDS64) {  // a part of a split tile
    display::TilePartCompositor parts;
    parts.merge(header.frame_id(), header.tile_id(), header.attempt(), header.rect(),
                header.has_drawn_rect() ? header.drawn_rect() : header.rect(), pixels);
    if (arrival == display::TileArrival::Part) return;
    composed = parts.take(header.frame_id(), header.tile_id(), header.attempt(), 0xff000000u);
  }
  // A background tile leaves the frame as it is, as at the display.
  if (header.format() != v1::PIXEL_FORMAT_BACKGROUND) {
    Image frame(128, 64, {0, 0, 0, 255});
    const v1::TileRect& drawn =
        composed.empty() && header.has_drawn_rect() ? header.drawn_rect() : header.rect();
    if (drawn.width() > 0 && drawn.height() > 0)
      blit(composed.empty() ? std::span<const std::uint8_t>(bytes, pixels.size())
                            : std::span<const std::uint8_t>(composed),
           drawn.width(), drawn.height(), frame, drawn.x(), drawn.y());
  }
  (void)assembly.finishFrames(kStart + 2ms);
}

render::RenderCore renderCore() {
  return render::RenderCore({}, kPeers, 4, kCells, std::vector<std::uint32_t>(kCells.size(), 0));
}

void drainPackets(render::RenderCore& core) {
  for (int i = 0; i < 8; ++i) {
    render::RenderEffects effects;
    auto ready = core.nextPacket(kStart + std::chrono::milliseconds(10 + i), effects);
    if (!ready) break;
    (void)core.packetDrawn(*ready, 10, 0.001, kStart + std::chrono::milliseconds(10 + i), effects);
  }
}

void renderPacket(const v1::RenderPacket& packet) {
  auto core = renderCore();
  render::RenderEffects effects;
  core.receivePacket(1, packet, kStart, effects);
  drainPackets(core);
}

void dataPacket(const v1::DataPacketHeader& header, std::span<const std::byte> payload) {
  render::checkDataPacketHeader(header, payload.size(), 3);
  auto core = renderCore();
  render::RenderEffects effects;
  for (const v1::DataPart& part : header.parts()) {
    (void)core.receiveData(part.top_level_cell(), static_cast<std::uint32_t>(part.first_splat()),
                           static_cast<std::uint32_t>(part.splat_count()), 0.001, kStart, effects);
  }
  drainPackets(core);
}

void sendOrder(const v1::SendOrder& order) {
  datasend::SendLedger ledger(kPeers, std::vector<std::uint32_t>(kCells.size(), 0), 0);
  (void)ledger.rangesToSend(order);
  (void)ledger.rangesToSend(order);  // what was sent is not sent again
}

void renderReport(const v1::RenderReport& report, int source) {
  datasend::SendLedger ledger(kPeers, std::vector<std::uint32_t>(kCells.size(), 0), 0);
  ledger.applyReport(source, report);
}

// The traverse's dataset, as preprocess writes it, built once.
struct TraverseScene {
  DatasetContent content;
  std::shared_ptr<const traverse::PacketLayers> layers;
  std::vector<std::uint32_t> owners;
};

const TraverseScene& traverseScene() {
  static const TraverseScene scene = [] {
    TraverseScene s;
    auto cloud = preprocess::generateScene("city", 3000, 7);
    preprocess::PreprocessOptions options;
    options.octree.leafPoints = 64;
    options.topLevelDepth = 2;
    s.content = preprocess::buildDatasetContent(std::move(cloud.splats), options);
    finalizeDatasetContent(s.content);
    s.layers = std::make_shared<const traverse::PacketLayers>(s.content.cells, s.content.topLevel);
    s.owners = assignOwners(s.content.topLevel, 1);
    return s;
  }();
  return scene;
}

v1::RunSettings traverseRunSettings() {
  v1::RunSettings s;
  s.set_mode(v1::RENDER_MODE_POINTS);
  s.set_lod_pixels(1.0f);
  s.set_size_scale(1.0f);
  s.set_scheduler(v1::SCHEDULER_COST);
  return s;
}

traverse::PacketPlanner traversePlanner() {
  const TraverseScene& scene = traverseScene();
  return traverse::PacketPlanner(kPeers, 1, traverseRunSettings(), scene.layers, scene.owners);
}

// What the traverse role does with a TileTask.
void tileTask(const v1::TileTask& task) {
  const TraverseScene& scene = traverseScene();
  auto planner = traversePlanner();
  const traverse::CullingTable culling(scene.content.cells, planner.traversal().sizeScale);
  const traverse::TraversalSettings traversal = planner.traversalFor(task);
  const traverse::TraversalResult walk =
      traverse::traverseTile(culling, task.camera(), task.rect(), traversal);
  std::vector<CellPrefix> ahead;
  if (const auto camera = planner.lookaheadCamera(task)) {
    ahead = traverse::topLevelCellsInTile(culling, *scene.layers, *camera, task.rect(), traversal);
  }
  Outbox out;
  (void)planner.planPackets(task, traverse::walkOf(walk), ahead, kStart, out);
}

void traverseReport(const v1::RenderReport& report, int source) {
  auto planner = traversePlanner();
  planner.applyReport(source, report, kStart);
  planner.applyReport(source, report, kStart + 1ms);  // the same report again
}

template <class M>
bool parse(M& message, std::span<const std::uint8_t> bytes) {
  return message.ParseFromArray(bytes.data(), static_cast<int>(bytes.size()));
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size < 3) return 0;
  const std::size_t headerBytes =
      std::min<std::size_t>(size - 3, std::size_t{data[1]} | (std::size_t{data[2]} << 8));
  const std::span<const std::uint8_t> header(data + 3, headerBytes);
  const std::span<const std::byte> payload(
      reinterpret_cast<const std::byte*>(data + 3 + headerBytes), size - 3 - headerBytes);
  try {
    switch (data[0] % 8) {
      case 0: {
        v1::TileImageHeader message;
        if (parse(message, header)) tileImage(message, payload);
        break;
      }
      case 1: {
        v1::RenderPacket message;
        if (parse(message, header)) renderPacket(message);
        break;
      }
      case 2: {
        v1::DataPacketHeader message;
        if (parse(message, header)) dataPacket(message, payload);
        break;
      }
      case 3: {
        v1::SendOrder message;
        if (parse(message, header)) sendOrder(message);
        break;
      }
      case 4:
      case 5: {
        v1::RenderReport message;
        if (parse(message, header)) renderReport(message, 4 + data[0] % 2);
        break;
      }
      case 6: {
        v1::TileTask message;
        if (parse(message, header)) tileTask(message);
        break;
      }
      case 7: {
        v1::RenderReport message;
        if (parse(message, header)) traverseReport(message, 4 + payload.size() % 2);
        break;
      }
    }
  } catch (const ProtocolError&) {
  } catch (const UsageError&) {
  }
  return 0;
}
