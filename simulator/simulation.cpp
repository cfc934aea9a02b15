#include "simulator/simulation.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <deque>
#include <map>
#include <memory>
#include <optional>
#include <utility>

#include "common/clock.hpp"
#include "common/errors.hpp"
#include "common/image_compression.hpp"
#include "common/messages.hpp"
#include "common/ownership.hpp"
#include "common/peer_ranks.hpp"
#include "datasend/core/send_ledger.hpp"
#include "display/core/frame_assembly.hpp"
#include "render/core/render_core.hpp"
#include "traverse/core/packet_planner.hpp"

namespace pointillist::simulator {

void validateParameters(const ModelParameters& p) {
  const auto positive = [](double value, const char* name) {
    if (!(value > 0.0) || !std::isfinite(value)) {
      throw UsageError(std::string(name) + " must be a positive number");
    }
  };
  const auto nonNegative = [](double value, const char* name) {
    if (!(value >= 0.0) || !std::isfinite(value)) {
      throw UsageError(std::string(name) + " must be zero or more");
    }
  };
  positive(p.secondsPerSplat, "T_s (--seconds-per-splat)");
  nonNegative(p.packetOverheadSeconds, "the packet overhead (--packet-overhead-ms)");
  nonNegative(p.packetSecondsPerPixel, "the packet time per pixel (--packet-ns-per-pixel)");
  positive(p.bandwidthBytesPerSecond, "the bandwidth (--bandwidth-mbs)");
  nonNegative(p.displayBandwidthBytesPerSecond, "--display-bandwidth-mbs");
  nonNegative(p.latencySeconds, "the latency (--latency-us)");
  nonNegative(p.traverseSecondsPerCell, "--traverse-seconds-per-cell");
  nonNegative(p.traverseTileSeconds, "--traverse-tile-us");
  nonNegative(p.composeSecondsPerPixel, "--compose-ns-per-pixel");
  nonNegative(p.compressSecondsPerByte, "--compress-ns-per-byte");
  nonNegative(p.decompressSecondsPerByte, "--decompress-ns-per-byte");
  positive(p.cacheMegabytes, "the cache size (--cache-mb)");
  positive(p.cacheTimeoutSeconds, "the cache time-out");
  positive(p.tileTimeoutSeconds, "the tile time-out (--tile-timeout)");
  if (p.framesInFlight == 0) throw UsageError("--frames-in-flight must be at least 1");
  if (p.maxAttempts == 0) throw UsageError("--max-attempts must be at least 1");
  if (p.displayImageThreads == 0) throw UsageError("--display-image-threads must be at least 1");
}

double packetSeconds(const ModelParameters& p, const v1::RenderPacket& packet) {
  const double pixels =
      static_cast<double>(packet.rect().width()) * static_cast<double>(packet.rect().height());
  return p.packetOverheadSeconds + pixels * p.packetSecondsPerPixel +
         static_cast<double>(packet.total_splats()) * p.secondsPerSplat;
}

std::string configName(const SimulationConfig& config) {
  std::string name = display::schedulerName(config.scheduler);
  if (config.scheduler == display::SchedulerKind::Cost) {
    if (config.costModel == traverse::CostModel::Overlap) name += "/overlap";
    if (!config.balancedTiles) name += "/equal";
  }
  if (!config.tileSplit && (config.scheduler == display::SchedulerKind::Cost ||
                            config.scheduler == display::SchedulerKind::Regions)) {
    name += "/unsplit";
  } else if (config.tileSplit && config.tilePartSplats == 0 && !config.tilePartTuned &&
             (config.scheduler == display::SchedulerKind::Cost ||
              config.scheduler == display::SchedulerKind::Regions)) {
    name += "/share";
  }
  return name;
}

void validateConfig(const SimulationConfig& c) {
  if (c.renders == 0) throw UsageError("a job needs at least one render process");
  if (c.traverses == 0) throw UsageError("a job needs at least one traverse process");
  if (c.datasends == 0) throw UsageError("a job needs at least one data-send process");
  if (!(c.tilesPerRender > 0.0) || !std::isfinite(c.tilesPerRender)) {
    throw UsageError("--tiles-per-render must be a positive number");
  }
  if (c.minTileSize == 0) throw UsageError("--min-tile must be at least 1 pixel");
}

namespace {

struct Interval {
  double start;
  double end;
};

double busyShare(const std::vector<Interval>& intervals, double from, double to) {
  if (!(to > from)) return 0.0;
  double busy = 0.0;
  for (const Interval& interval : intervals) {
    busy += std::max(0.0, std::min(interval.end, to) - std::max(interval.start, from));
  }
  return busy / (to - from);
}

// A message on its way: the protocol message the core sent, shared by every
// recipient, as the MPI roles would post it.
struct Delivery {
  int source = 0;
  MessageKind kind = MessageKind::Test;
  std::shared_ptr<const google::protobuf::MessageLite> message;
  double transferSeconds = 0.0;  // data packets: the payload's time on the wire

  template <class M>
  const M& as() const {
    return static_cast<const M&>(*message);
  }
};

enum class Step : std::uint8_t {
  Deliver,       // a message reaches its process
  TraverseDone,  // a traverse process has walked its tile
  RenderIdle,    // a render process's serve loop finds no message waiting
  RenderDone,    // a render process has drawn its packet
  DisplayCheck,  // the display looks for tiles past their deadline
  TileComposed,  // the display's CPU is done with a tile
};

struct Event {
  double time = 0.0;
  std::uint64_t sequence = 0;
  Step step = Step::Deliver;
  int rank = 0;
  Delivery delivery;
};

struct Later {
  bool operator()(const Event& a, const Event& b) const {
    return a.time != b.time ? a.time > b.time : a.sequence > b.sequence;
  }
};

struct Link {
  double freeAt = 0.0;
  std::vector<Interval> busy;
};

// --- the processes: a core each, and what the model needs to time it --------

struct TraverseProcess {
  explicit TraverseProcess(traverse::PacketPlanner core) : planner(std::move(core)) {}
  traverse::PacketPlanner planner;
  bool busy = false;
  std::optional<v1::TileTask> task;
  std::deque<v1::TileTask> waiting;  // tasks that came while walking (tile tasks ahead)
  const TileWork* work = nullptr;
  const std::vector<CellPrefix>* ahead = nullptr;  // cells of the lookahead walk
  std::vector<Delivery> deferred;                  // reports that came while walking
  std::vector<Interval> busyIntervals;
};

struct RenderProcess {
  explicit RenderProcess(render::RenderCore renderCore) : core(std::move(renderCore)) {}
  render::RenderCore core;
  bool busy = false;
  bool idlePending = false;
  std::optional<double> wakeAt;  // a maintenance wake-up already scheduled
  std::deque<Delivery> inbox;    // messages that came while drawing
  std::optional<render::ReadyPacket> current;
  double currentSeconds = 0.0;  // drawing it (what the render reports)
  std::vector<Interval> busyIntervals;
};

constexpr double kSimulatedSecondsLimit = 1e5;
constexpr double kWakeSlack = 1e-6;  // wake just after a deadline, not on it

v1::RunSettings runSettings(const Scene& scene, const SimulationConfig& config) {
  v1::RunSettings settings;
  settings.set_mode(v1::RENDER_MODE_POINTS);
  settings.set_lod_pixels(scene.traversal().lodPixels);
  settings.set_size_scale(scene.traversal().sizeScale);
  settings.set_backface_cull(scene.traversal().backfaceCull);
  settings.set_scheduler(display::schedulerMessage(config.scheduler));
  settings.set_cost_model(traverse::costModelMessage(config.costModel));
  settings.set_tile_tasks_ahead(
      config.tileTasksAhead > 0
          ? config.tileTasksAhead
          : autoTileTasksAhead(config.tilesPerRender * config.renders, config.traverses));
  settings.set_no_tile_split(!config.tileSplit);
  settings.set_tile_part_splats(config.tilePartSplats);
  settings.set_tile_part_untuned(!config.tilePartTuned);
  return settings;
}

display::FrameAssemblyConfig assemblyConfig(const Scene& scene, const SimulationConfig& config,
                                            const ModelParameters& p) {
  display::FrameAssemblyConfig assembly;
  assembly.cameras = scene.cameras();
  assembly.bounds = scene.bounds();
  assembly.marginWorld = scene.marginWorld();
  assembly.framesInFlight = p.framesInFlight;
  assembly.tileTimeout =
      std::chrono::milliseconds(static_cast<long>(p.tileTimeoutSeconds * 1000.0));
  assembly.maxAttempts = p.maxAttempts;
  assembly.plan = display::TilePlanOptions{.scheduler = config.scheduler,
                                           .renders = config.renders,
                                           .tilesPerRender = config.tilesPerRender,
                                           .minTileSize = config.minTileSize,
                                           .balancedTiles = config.balancedTiles};
  assembly.prefetchFrames = config.prefetchFrames;
  assembly.run = runSettings(scene, config);
  assembly.tuneTileCount = config.tileCountTuned;
  return assembly;
}

class Simulation {
 public:
  Simulation(const Scene& scene, const SimulationConfig& config, const ModelParameters& p)
      : scene_(scene),
        config_(config),
        p_(p),
        peers_(PeerRanks::contiguous(
            JobLayout{1, config.traverses, config.datasends, config.renders})),
        owners_(assignOwners(scene.topLevel(), config.datasends)),
        assembly_(assemblyConfig(scene, config, p), peers_, timeAfterEpoch(0.0)),
        outLinks_(peers_.layout().total()),
        inLinks_(peers_.layout().total()) {
    imageThreadsFree_.assign(std::max<std::uint32_t>(p.displayImageThreads, 1), 0.0);
    const v1::RunSettings settings = runSettings(scene, config);
    traverses_.reserve(config.traverses);
    for (int rank : peers_.traverses) {
      traverses_.emplace_back(
          traverse::PacketPlanner(peers_, rank, settings, scene.layers(), owners_));
    }
    for (std::uint32_t s = 0; s < config.datasends; ++s) ledgers_.emplace_back(peers_, owners_, s);
    render::RenderCoreConfig core;
    core.cacheCapBytes = static_cast<std::uint64_t>(p.cacheMegabytes * 1024.0 * 1024.0);
    core.cacheTimeout =
        std::chrono::milliseconds(static_cast<long>(p.cacheTimeoutSeconds * 1000.0));
    renders_.reserve(config.renders);
    for (std::uint32_t r = 0; r < config.renders; ++r) {
      render::RenderCoreConfig own = core;
      if (config.stalledRender == r) own.stallAfterPackets = config.stallAfterPackets;
      renders_.push_back(RenderProcess{
          render::RenderCore(own, peers_, peers_.renders[r], scene.topLevel(), owners_)});
    }
    display::RunStats& stats = assembly_.stats();
    stats.dataset = scene.name();
    stats.width = scene.width();
    stats.height = scene.height();
    stats.mode = "simulated";
    stats.loopFrames = scene.loopFrames();
  }

  SimulationResult run() {
    // Start-up: every traverse asks for work, every render reports once.
    for (TraverseProcess& traverse : traverses_) {
      Outbox out;
      traverse.planner.startWork(out);
      send(0.0, rankOf(traverse), out);
    }
    for (std::uint32_t r = 0; r < config_.renders; ++r) wakeRender(0.0, r);

    const std::size_t frameCount = scene_.cameras().size();
    while (!events_.empty() && !assembly_.done()) {
      std::pop_heap(events_.begin(), events_.end(), Later{});
      Event event = std::move(events_.back());
      events_.pop_back();
      ++eventCount_;
      if (event.time > kSimulatedSecondsLimit) {
        throw Error("simulation ran past " + std::to_string(kSimulatedSecondsLimit) +
                    " simulated seconds with " + std::to_string(framesDone()) + " of " +
                    std::to_string(frameCount) + " frames done");
      }
      handle(std::move(event));
    }
    if (!assembly_.done()) {
      throw Error("simulation stalled: no event left with " + std::to_string(framesDone()) +
                  " of " + std::to_string(frameCount) + " frames done (" +
                  peers_.layout().toString() + ", " + configName(config_) + ")");
    }
    return result();
  }

 private:
  // --- events and network ---------------------------------------------------

  std::size_t framesDone() const { return assembly_.stats().frameCount(); }

  void schedule(double time, Step step, int rank, Delivery delivery = {}) {
    events_.push_back(Event{time, ++sequence_, step, rank, std::move(delivery)});
    std::push_heap(events_.begin(), events_.end(), Later{});
  }

  double control(double now) const { return now + p_.latencySeconds; }

  double linkBandwidth(int rank) const {
    return rank == peers_.display && p_.displayBandwidthBytesPerSecond > 0.0
               ? p_.displayBandwidthBytesPerSecond
               : p_.bandwidthBytesPerSecond;
  }

  // Bulk bytes leave on the sender's outgoing link, first come first served,
  // and enter on the receiver's incoming link, which also serves one message
  // at a time; the switch buffers between the two, so a busy receiver does not
  // hold up the sender's other messages. Returns the arrival time.
  double bulk(double now, int from, int to, std::uint64_t bytes) {
    Link& out = outLinks_[static_cast<std::size_t>(from)];
    Link& in = inLinks_[static_cast<std::size_t>(to)];
    const double sending = static_cast<double>(bytes) / linkBandwidth(from);
    const double receiving = static_cast<double>(bytes) / linkBandwidth(to);
    const double sent = std::max(now, out.freeAt) + sending;
    out.busy.push_back({sent - sending, sent});
    out.freeAt = sent;
    const double received = std::max(sent, in.freeAt + receiving);
    in.busy.push_back({received - receiving, received});
    in.freeAt = received;
    return received + p_.latencySeconds;
  }

  // Sends what a core put in its outbox: control messages take the latency;
  // render packets also take their modelled bytes on the links.
  void send(double now, int from, Outbox& out, std::uint64_t packetBytes = 0) {
    for (Outgoing& outgoing : out.take()) {
      for (int to : outgoing.destinations) {
        const double arrival = outgoing.kind == MessageKind::RenderPacket
                                   ? bulk(now, from, to, packetBytes)
                                   : control(now);
        schedule(arrival, Step::Deliver, to, Delivery{from, outgoing.kind, outgoing.message});
      }
    }
  }

  int rankOf(const TraverseProcess& traverse) const {
    return peers_.traverses[static_cast<std::size_t>(&traverse - traverses_.data())];
  }

  FrameTrace& trace(std::uint64_t frame) {
    FrameTrace& t = traces_[frame];
    t.frame = frame;
    return t;
  }

  // Which process a rank is: ranks are contiguous (PeerRanks::contiguous).
  struct Seat {
    v1::Role role = v1::ROLE_DISPLAY;
    std::size_t index = 0;
  };
  Seat seatOf(int rank) const {
    if (rank == peers_.display) return {v1::ROLE_DISPLAY, 0};
    std::size_t index = static_cast<std::size_t>(rank - 1);
    if (index < traverses_.size()) return {v1::ROLE_TRAVERSE, index};
    index -= traverses_.size();
    if (index < ledgers_.size()) return {v1::ROLE_DATASEND, index};
    return {v1::ROLE_RENDER, index - ledgers_.size()};
  }

  void handle(Event&& event) {
    const double now = event.time;
    const Seat seat = seatOf(event.rank);
    const auto render = static_cast<std::uint32_t>(seat.index);
    switch (event.step) {
      case Step::Deliver:
        if (seat.role == v1::ROLE_DISPLAY) {
          displayMessage(now, event.delivery);
        } else if (seat.role == v1::ROLE_TRAVERSE) {
          traverseMessage(now, traverses_[seat.index], std::move(event.delivery));
        } else if (seat.role == v1::ROLE_DATASEND) {
          datasendMessage(now, seat.index, event.delivery);
        } else {
          RenderProcess& process = renders_.at(render);
          if (process.busy) {
            process.inbox.push_back(std::move(event.delivery));
          } else {
            renderMessage(now, process, event.delivery);
            wakeRender(now, render);
          }
        }
        break;
      case Step::TraverseDone:
        traverseDone(now, traverses_[seat.index]);
        break;
      case Step::RenderIdle: {
        RenderProcess& process = renders_.at(render);
        process.idlePending = false;
        if (process.wakeAt && *process.wakeAt <= now) process.wakeAt.reset();
        if (!process.busy) idleStep(now, render);
        break;
      }
      case Step::RenderDone:
        renderDone(now, render);
        break;
      case Step::DisplayCheck:
        checkPending_ = false;
        dispatch(now);
        finishFrames(now);
        break;
      case Step::TileComposed:
        tileComposed(now, event.delivery);
        break;
    }
  }

  // --- display: FrameAssembly -------------------------------------------------

  void displayMessage(double now, const Delivery& delivery) {
    switch (delivery.kind) {
      case MessageKind::WorkRequest:
        assembly_.workRequested(delivery.source, delivery.as<v1::WorkRequest>());
        dispatch(now);
        break;
      case MessageKind::TileImage: {
        // The display handles a tile on its one CPU, tiles in arrival order:
        // it expands a compressed image, then takes the tile and blits it (a
        // part is merged by the minimum at about the same cost per pixel; a
        // background tile leaves the blank image as it is). The tile counts
        // as arrived, and its frame may finish, once that is done: a CPU
        // that falls behind holds the frames.
        const auto& header = delivery.as<v1::TileImageHeader>();
        const v1::TileRect& sent = header.has_drawn_rect() ? header.drawn_rect() : header.rect();
        const double pixels = header.format() == v1::PIXEL_FORMAT_BACKGROUND
                                  ? 0.0
                                  : static_cast<double>(sent.width()) * sent.height();
        double ready = now;
        if (header.uncompressed_bytes() != 0) {
          // Expanded on the first free of the image threads.
          const auto lane = std::min_element(imageThreadsFree_.begin(), imageThreadsFree_.end());
          const double begin = std::max(now, *lane);
          *lane = begin +
                  static_cast<double>(header.uncompressed_bytes()) * p_.decompressSecondsPerByte;
          imageThreadsBusy_.push_back({begin, *lane});
          ready = *lane;
        }
        const double start = std::max(ready, displayCpuFree_);
        displayCpuFree_ = start + pixels * p_.composeSecondsPerPixel;
        displayCpu_.push_back({start, displayCpuFree_});
        schedule(displayCpuFree_, Step::TileComposed, peers_.display, delivery);
        break;
      }
      default:
        throw Error(std::string("internal error: the display got a ") +
                    messageKindName(delivery.kind));
    }
  }

  void dispatch(double now) {
    Outbox out;
    assembly_.dispatch(timeAfterEpoch(now), out);
    send(now, peers_.display, out);
    // Spans when tiles wait for a traverse to ask (request round trips, or
    // traverses busy walking).
    if (assembly_.tilesWaitForRequests()) {
      if (!requestWaitSince_) requestWaitSince_ = now;
    } else if (requestWaitSince_) {
      requestWait_.push_back({*requestWaitSince_, now});
      requestWaitSince_.reset();
    }
    // Wake at the earliest deadline of a tile that is out, to re-issue it.
    if (const auto deadline = assembly_.nextDeadline(); deadline && !checkPending_) {
      checkPending_ = true;
      schedule(std::max(now, secondsSinceEpoch(*deadline)) + kWakeSlack, Step::DisplayCheck,
               peers_.display);
    }
  }

  void tileComposed(double now, const Delivery& delivery) {
    const auto& header = delivery.as<v1::TileImageHeader>();
    const display::TileArrival arrival = assembly_.tileArrived(header, timeAfterEpoch(now));
    if (arrival == display::TileArrival::Complete) ++trace(header.frame_id()).tilesComposed;
    if (arrival != display::TileArrival::Late) finishFrames(now);
  }

  void finishFrames(double now) {
    const auto finished = assembly_.finishFrames(timeAfterEpoch(now));
    for (const display::FinishedFrame& frame : finished) {
      trace(frame.record.frame).tilesPlanned = frame.record.tiles;
      completionOrder_.push_back(frame.record.frame);
    }
    if (!finished.empty()) dispatch(now);  // frames that entered the window
  }

  // --- traverse: PacketPlanner -------------------------------------------------

  void traverseMessage(double now, TraverseProcess& traverse, Delivery delivery) {
    switch (delivery.kind) {
      case MessageKind::TileTask:
        if (traverse.busy) {
          traverse.waiting.push_back(delivery.as<v1::TileTask>());
        } else {
          startWalk(now, traverse, delivery.as<v1::TileTask>());
        }
        break;
      case MessageKind::RenderReport:
        // The choice sees the reports that arrived before the task, as in the
        // runtime, where reports wait in MPI while the traverse walks the tree.
        if (traverse.busy) {
          traverse.deferred.push_back(std::move(delivery));
        } else {
          traverse.planner.applyReport(delivery.source, delivery.as<v1::RenderReport>(),
                                       timeAfterEpoch(now));
        }
        break;
      default:
        throw Error(std::string("internal error: a traverse process got a ") +
                    messageKindName(delivery.kind));
    }
  }

  void startWalk(double now, TraverseProcess& traverse, const v1::TileTask& task) {
    traverse.busy = true;
    traverse.work = &scene_.tileWork(task.frame_id(), task.rect());
    traverse.ahead =
        traverse.planner.lookaheadCamera(task)
            ? &scene_.cellsInTile(task.frame_id() + config_.prefetchFrames, task.rect())
            : nullptr;
    traverse.task = task;
    // The prefetch walk stops at the top-level cells: one cell per cell found.
    const double cells = static_cast<double>(traverse.work->cellsVisited) +
                         (traverse.ahead ? static_cast<double>(traverse.ahead->size()) : 0.0);
    const double seconds = p_.traverseTileSeconds + p_.traverseSecondsPerCell * cells;
    traverse.busyIntervals.push_back({now, now + seconds});
    schedule(now + seconds, Step::TraverseDone, rankOf(traverse));
  }

  void traverseDone(double now, TraverseProcess& traverse) {
    const v1::TileTask& task = *traverse.task;
    const TileWork& work = *traverse.work;
    Outbox out;
    const std::vector<traverse::PacketPlan> plans = traverse.planner.planPackets(
        task, traverse::TileWalk{work.needs, work.splats, work.ranges, work.boxes},
        traverse.ahead != nullptr ? std::span<const CellPrefix>(*traverse.ahead)
                                  : std::span<const CellPrefix>(),
        timeAfterEpoch(now), out);
    // No plan: the walk found nothing and the traverse sent the display the
    // tile's background itself.
    if (plans.empty()) ++trace(task.frame_id()).backgroundTiles;
    if (plans.size() > 1)
      trace(task.frame_id()).extraParts += static_cast<std::uint32_t>(plans.size() - 1);
    for (const traverse::PacketPlan& plan : plans) {
      trace(task.frame_id()).bytesOrdered += plan.choice.missingBytes + plan.prefetchBytes;
      trace(task.frame_id()).bytesPrefetched += plan.prefetchBytes;
    }
    // A render packet carries the camera and three numbers per drawn range
    // and per needed one (about as many); a split tile's parts share them.
    const std::uint64_t packetBytes =
        160 + 24ull * work.ranges.size() / std::max<std::size_t>(1, plans.size());
    send(now, rankOf(traverse), out, packetBytes);
    traverse.busy = false;
    traverse.task.reset();
    traverse.work = nullptr;
    traverse.ahead = nullptr;
    for (const Delivery& report : std::exchange(traverse.deferred, {})) {
      traverse.planner.applyReport(report.source, report.as<v1::RenderReport>(),
                                   timeAfterEpoch(now));
    }
    if (!traverse.waiting.empty()) {
      const v1::TileTask next = std::move(traverse.waiting.front());
      traverse.waiting.pop_front();
      startWalk(now, traverse, next);
    }
  }

  // --- data-send: SendLedger ---------------------------------------------------

  void datasendMessage(double now, std::size_t s, const Delivery& delivery) {
    datasend::SendLedger& ledger = ledgers_[s];
    switch (delivery.kind) {
      case MessageKind::SendOrder: {
        const auto& order = delivery.as<v1::SendOrder>();
        const std::vector<CellRange> ranges = ledger.rangesToSend(order);
        for (const std::span<const CellRange> group : datasend::dataPacketGroups(ranges)) {
          std::uint64_t bytes = 0;
          v1::DataPacketHeader header;
          header.set_record_size(sizeof(Splat));
          header.set_datasend_rank(peers_.datasends[s]);
          for (const CellRange& range : group) {
            v1::DataPart& part = *header.add_parts();
            part.set_top_level_cell(range.cell);
            part.set_first_splat(range.first);
            part.set_splat_count(range.count);
            bytes += std::uint64_t{range.count} * sizeof(Splat);
          }
          header.set_byte_size(bytes);
          const double arrival = bulk(now, peers_.datasends[s], order.render_rank(), bytes);
          schedule(arrival, Step::Deliver, order.render_rank(),
                   Delivery{peers_.datasends[s], MessageKind::DataPacket,
                            std::make_shared<const v1::DataPacketHeader>(std::move(header)),
                            static_cast<double>(bytes) / p_.bandwidthBytesPerSecond});
          trace(order.frame_id()).bytesMoved += bytes;
          bytesMoved_ += bytes;
        }
        break;
      }
      case MessageKind::RenderReport:
        ledger.applyReport(delivery.source, delivery.as<v1::RenderReport>());
        break;
      default:
        throw Error(std::string("internal error: a data-send process got a ") +
                    messageKindName(delivery.kind));
    }
  }

  // --- render: RenderCore --------------------------------------------------------

  void wakeRender(double now, std::uint32_t r) {
    RenderProcess& process = renders_[r];
    if (process.idlePending || process.busy) return;
    process.idlePending = true;
    schedule(now, Step::RenderIdle, peers_.renders[r]);
  }

  void renderMessage(double now, RenderProcess& process, const Delivery& delivery) {
    render::RenderEffects effects;
    switch (delivery.kind) {
      case MessageKind::RenderPacket:
        process.core.receivePacket(delivery.source, delivery.as<v1::RenderPacket>(),
                                   timeAfterEpoch(now), effects);
        break;
      case MessageKind::DataPacket: {
        const auto& header = delivery.as<v1::DataPacketHeader>();
        const double secondsPerByte =
            delivery.transferSeconds /
            static_cast<double>(std::max<std::uint64_t>(header.byte_size(), 1));
        for (const v1::DataPart& part : header.parts()) {
          process.core.receiveData(
              part.top_level_cell(), static_cast<std::uint32_t>(part.first_splat()),
              static_cast<std::uint32_t>(part.splat_count()),
              secondsPerByte * static_cast<double>(part.splat_count() * sizeof(Splat)),
              timeAfterEpoch(now), effects);
        }
        break;
      }
      default:
        throw Error(std::string("internal error: a render process got a ") +
                    messageKindName(delivery.kind));
    }
    send(now, process.core.selfRank(), effects.messages);
  }

  // The serve loop's idle moment: the core hands out a ready packet, which
  // takes the modelled time to draw, or the process sleeps until its next
  // maintenance (or a message).
  void idleStep(double now, std::uint32_t r) {
    RenderProcess& process = renders_[r];
    render::RenderEffects effects;
    auto ready = process.core.nextPacket(timeAfterEpoch(now), effects);
    send(now, peers_.renders[r], effects.messages);
    if (ready) {
      process.busy = true;
      process.currentSeconds = packetSeconds(p_, ready->packet);
      // Then compressing its image, before it goes.
      const double busy =
          process.currentSeconds +
          static_cast<double>(imageOf(ready->packet).compressedFrom) * p_.compressSecondsPerByte;
      process.current = std::move(ready);
      process.busyIntervals.push_back({now, now + busy});
      schedule(now + busy, Step::RenderDone, peers_.renders[r]);
      return;
    }
    if (const auto due = process.core.nextMaintenance()) {
      const double at = std::max(now, secondsSinceEpoch(*due));
      if (!process.wakeAt || at < *process.wakeAt) {
        process.wakeAt = at;
        schedule(at, Step::RenderIdle, peers_.renders[r]);
      }
    }
  }

  // What a render sends for `packet`: its box, runs and zstd frame.
  struct TileImage {
    std::optional<v1::TileRect> drawnRect;
    std::uint64_t runsBytes = 0;       // as runs (0: the box itself)
    std::uint64_t compressedFrom = 0;  // compressed from these bytes (0: not)
    std::uint64_t bytes = 0;           // the payload
  };

  TileImage imageOf(const v1::RenderPacket& packet) const {
    TileImage image;
    // A part of a split tile goes as 8-byte words (depth and colour). A tile
    // goes as the box it drew in, taken to be the box of its cells the
    // traverse gave, unless it carries depth.
    const bool part = packet.part_count() > 1;
    if (packet.has_screen_box() &&
        !(packet.has_frame_settings() && packet.frame_settings().tile_depth()))
      image.drawnRect = packet.screen_box();
    const v1::TileRect& sent = image.drawnRect ? *image.drawnRect : packet.rect();
    const std::uint64_t pixelBytes = part ? 8 : 4;
    image.bytes = std::uint64_t{sent.width()} * sent.height() * pixelBytes;
    if (image.drawnRect) {
      // As runs where fewer bytes (common/pixel_runs.hpp). Where the scene
      // draws its frames, a whole tile's runs are those of its box in the
      // frame; a part's are at most the box's lit pixels and one a splat.
      // Otherwise a point lights about one pixel (the city at 4K: 1.01 lit
      // pixels a splat), and a run of 8 bytes of counts comes every 200 lit
      // pixels there; 64 here.
      const std::uint64_t area = std::uint64_t{sent.width()} * sent.height();
      std::uint64_t lit = std::min<std::uint64_t>(area, packet.total_splats());
      std::uint64_t runCount = (lit + 63) / 64;
      if (scene_.hasLitPixels()) {
        const LitRuns inBox = scene_.litRuns(packet.frame_id(), sent);
        lit = part ? std::min(lit, inBox.lit) : inBox.lit;
        runCount = part ? std::min(inBox.runs, lit + 1) : inBox.runs;
      }
      const std::uint64_t runs = lit * pixelBytes + 8 * runCount;
      if (runs < image.bytes) {
        image.runsBytes = runs;
        image.bytes = runs;
      }
    }
    // As the render does (compressImageBytes): worth it from a small size,
    // kept where smaller.
    if (p_.compressImages && image.bytes >= kMinCompressedPayload) {
      const double ratio = scene_.imageCompression(packet.frame_id(), part);
      const auto packed = static_cast<std::uint64_t>(
          std::ceil(static_cast<double>(image.bytes) / std::max(ratio, 1.0)));
      if (packed < image.bytes) {
        image.compressedFrom = image.bytes;
        image.bytes = packed;
      }
    }
    return image;
  }

  void renderDone(double now, std::uint32_t r) {
    RenderProcess& process = renders_[r];
    const render::ReadyPacket ready = std::move(*process.current);
    process.current.reset();
    const v1::RenderPacket& packet = ready.packet;
    render::RenderEffects effects;
    v1::TileImageHeader drawn = process.core.packetDrawn(
        ready, packet.total_splats(), process.currentSeconds, timeAfterEpoch(now), effects);
    const TileImage image = imageOf(packet);
    if (image.drawnRect) *drawn.mutable_drawn_rect() = *image.drawnRect;
    if (image.runsBytes != 0) drawn.set_runs_bytes(image.runsBytes);
    if (image.compressedFrom != 0) {
      drawn.set_uncompressed_bytes(image.compressedFrom);
      drawn.set_compressed_bytes(image.bytes);
    }
    std::uint64_t imageBytes = image.bytes;
    imageBytes += 128;
    auto header = std::make_shared<const v1::TileImageHeader>(std::move(drawn));
    ++trace(packet.frame_id()).packetsRendered;
    ++packetsRendered_;
    schedule(bulk(now, peers_.renders[r], peers_.display, imageBytes), Step::Deliver,
             peers_.display, Delivery{peers_.renders[r], MessageKind::TileImage, header});
    send(now, peers_.renders[r], effects.messages);
    process.busy = false;
    // The serve loop drains what came while drawing, then idles again.
    while (!process.inbox.empty()) {
      const Delivery delivery = std::move(process.inbox.front());
      process.inbox.pop_front();
      renderMessage(now, process, delivery);
    }
    idleStep(now, r);
  }

  // --- results -------------------------------------------------------------

  SimulationResult result() {
    SimulationResult out;
    out.config = config_;
    out.stats = std::move(assembly_.stats());
    display::RunStats& stats = out.stats;
    stats.totalSeconds = stats.frames.empty() ? 0.0 : stats.frames.back().endSeconds;
    for (display::FrameRecord& record : stats.frames) {
      record.bytesOrdered = trace(record.frame).bytesMoved;
      record.bytesPrefetched = trace(record.frame).bytesPrefetched;
    }
    stats.recountFrames();
    out.figures = stats.keyFigures();
    // The display's tile layout took wall time here, not simulated time: kept
    // out of the statistics, which are the same from run to run.
    out.planMsPerFrame = out.figures.planMsPerFrame;
    out.figures.planMsPerFrame = 0.0;
    stats.planSeconds = 0.0;
    for (std::uint64_t frame : completionOrder_) out.frames.push_back(trace(frame));

    const std::size_t steadyFrom = out.figures.steadyFrom;
    const double from = steadyFrom == 0 ? 0.0 : stats.frames[steadyFrom - 1].endSeconds;
    const double to = stats.totalSeconds;
    double latency = 0.0, tiles = 0.0;
    for (std::size_t i = 0; i < stats.frames.size(); ++i) {
      tiles += static_cast<double>(stats.frames[i].tiles);
      if (i >= steadyFrom) latency += stats.frames[i].endSeconds - stats.frames[i].startSeconds;
    }
    const std::size_t steadyFrames =
        stats.frames.size() - std::min(stats.frames.size(), steadyFrom);
    out.meanFrameLatency = steadyFrames > 0 ? latency / static_cast<double>(steadyFrames) : 0.0;
    out.tilesPerFrame =
        stats.frames.empty() ? 0.0 : tiles / static_cast<double>(stats.frames.size());

    Utilisation& u = out.utilisation;
    for (const RenderProcess& render : renders_) {
      const double share = busyShare(render.busyIntervals, from, to);
      u.renderMean += share / static_cast<double>(renders_.size());
      u.renderMax = std::max(u.renderMax, share);
      out.droppedPrefetches += render.core.droppedPrefetches();
    }
    for (const datasend::SendLedger& ledger : ledgers_) {
      out.duplicateOrders += ledger.duplicatesSkipped();
    }
    for (const TraverseProcess& traverse : traverses_) {
      const double share = busyShare(traverse.busyIntervals, from, to);
      u.traverseMean += share / static_cast<double>(traverses_.size());
      u.traverseMax = std::max(u.traverseMax, share);
    }
    for (std::size_t rank = 1; rank < outLinks_.size(); ++rank) {
      u.networkMax = std::max({u.networkMax, busyShare(outLinks_[rank].busy, from, to),
                               busyShare(inLinks_[rank].busy, from, to)});
    }
    u.displayLink = busyShare(inLinks_[0].busy, from, to);
    u.displayCpu = std::max(
        busyShare(displayCpu_, from, to),
        busyShare(imageThreadsBusy_, from, to) / static_cast<double>(imageThreadsFree_.size()));
    if (requestWaitSince_) requestWait_.push_back({*requestWaitSince_, to});
    u.requestWait = busyShare(requestWait_, from, to);
    const std::pair<const char*, double> candidates[] = {
        {"render", u.renderMax},
        {"traverse", u.traverseMax},
        {"network", u.networkMax},
        {"display", std::max(u.displayLink, u.displayCpu)}};
    for (const auto& [name, share] : candidates) {
      if (share > out.bottleneckUtilisation) {
        out.bottleneck = name;
        out.bottleneckUtilisation = share;
      }
    }
    // Tiles wait for requests while the traverses are not busy: each waits a
    // request's round trip between tiles (too few --tile-tasks-ahead).
    if (u.requestWait > 0.5 && u.traverseMax < 0.9 && u.requestWait > out.bottleneckUtilisation) {
      out.bottleneck = "requests";
      out.bottleneckUtilisation = u.requestWait;
    }
    // Nothing near saturation: the frames in flight wait on round trips.
    if (out.bottleneckUtilisation < 0.5) out.bottleneck = "latency";

    out.packetsRendered = packetsRendered_;
    out.bytesMoved = bytesMoved_;
    out.events = eventCount_;
    return out;
  }

  const Scene& scene_;
  SimulationConfig config_;
  ModelParameters p_;
  PeerRanks peers_;
  std::vector<std::uint32_t> owners_;

  std::vector<Event> events_;  // a heap ordered by (time, sequence)
  std::uint64_t sequence_ = 0;
  std::uint64_t eventCount_ = 0;

  display::FrameAssembly assembly_;
  bool checkPending_ = false;
  double displayCpuFree_ = 0.0;
  std::vector<Interval> displayCpu_;
  std::vector<double> imageThreadsFree_;    // when each image thread is free
  std::vector<Interval> imageThreadsBusy_;  // all of them
  std::optional<double> requestWaitSince_;
  std::vector<Interval> requestWait_;  // tiles waiting for a traverse's request
  std::vector<std::uint64_t> completionOrder_;
  std::map<std::uint64_t, FrameTrace> traces_;

  std::vector<Link> outLinks_;  // by rank
  std::vector<Link> inLinks_;
  std::vector<TraverseProcess> traverses_;
  std::vector<datasend::SendLedger> ledgers_;
  std::vector<RenderProcess> renders_;

  std::uint64_t packetsRendered_ = 0;
  std::uint64_t bytesMoved_ = 0;
};

}  // namespace

SimulationResult simulate(const Scene& scene, const SimulationConfig& config,
                          const ModelParameters& parameters) {
  validateConfig(config);
  validateParameters(parameters);
  Simulation simulation(scene, config, parameters);
  return simulation.run();
}

}  // namespace pointillist::simulator
