#include "simulator/simulation.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <deque>
#include <map>
#include <memory>
#include <optional>
#include <unordered_set>
#include <variant>

#include "common/errors.hpp"
#include "common/image.hpp"
#include "common/ownership.hpp"
#include "common/rate_estimates.hpp"
#include "display/frame_scheduler.hpp"
#include "display/tiling.hpp"
#include "render/cell_cache.hpp"
#include "traverse/render_model.hpp"

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
  positive(p.bandwidthBytesPerSecond, "the bandwidth (--bandwidth-mbs)");
  nonNegative(p.latencySeconds, "the latency (--latency-us)");
  nonNegative(p.traverseSecondsPerCell, "--traverse-seconds-per-cell");
  nonNegative(p.traverseTileSeconds, "--traverse-tile-us");
  nonNegative(p.composeSecondsPerPixel, "--compose-ns-per-pixel");
  positive(p.cacheMegabytes, "the cache size (--cache-mb)");
  positive(p.cacheTimeoutSeconds, "the cache time-out");
  positive(p.tileTimeoutSeconds, "the tile time-out (--tile-timeout)");
  if (p.framesInFlight == 0) throw UsageError("--frames-in-flight must be at least 1");
  if (p.maxAttempts == 0) throw UsageError("--max-attempts must be at least 1");
}

std::string configName(const SimulationConfig& config) {
  std::string name = display::schedulerName(config.scheduler);
  if (config.scheduler == display::SchedulerKind::Cost) {
    if (config.costModel == traverse::CostModel::Overlap) name += "/overlap";
    if (!config.balancedTiles) name += "/equal";
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

using Clock = std::chrono::steady_clock;

Clock::time_point toTime(double seconds) {
  return Clock::time_point{} +
         std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(seconds));
}

double toSeconds(Clock::time_point time) {
  return std::chrono::duration<double>(time.time_since_epoch()).count();
}

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

// --- messages -------------------------------------------------------------

struct TaskMessage {
  std::uint64_t frame = 0;
  std::uint32_t tile = 0;
  std::uint32_t attempt = 0;
  TileRect rect;
  std::optional<std::uint32_t> assigned;
  std::optional<std::uint64_t> lookaheadFrame;  // cost scheduler: prefetch for this frame
  double dispatched = 0.0;
};

struct OrderMessage {
  std::uint32_t render = 0;
  std::vector<std::uint32_t> cells;
  std::uint64_t frame = 0;  // whose data this is, for the bytes per frame
};

struct DataMessage {
  std::uint32_t cell = 0;
  std::uint64_t bytes = 0;
  double transferSeconds = 0.0;
};

struct PacketMessage {
  std::uint64_t frame = 0;
  std::uint32_t tile = 0;
  std::uint32_t attempt = 0;
  TileRect rect;
  const TileWork* work = nullptr;
  std::uint32_t traverse = 0;
  std::uint64_t packetId = 0;
  std::uint64_t orderedBytes = 0;
  std::uint64_t prefetchBytes = 0;
  double dispatched = 0.0;  // by the display
};

struct ReportMessage {
  std::uint32_t render = 0;
  std::uint64_t workload = 0;
  std::vector<std::uint32_t> loaded;
  std::vector<std::uint32_t> evicted;
  double secondsPerSplat = 0.0;
  double secondsPerByte = 0.0;
  std::uint64_t packetsDone = 0;
  std::vector<std::uint64_t> lastPacketFrom;  // per traverse
};

struct TileMessage {
  std::uint64_t frame = 0;
  std::uint32_t tile = 0;
  TileRect rect;
  std::uint32_t render = 0;
  std::uint64_t splats = 0;
  double seconds = 0.0;
  display::RenderSample sample;
  display::TileRecord record;
};

enum class Kind : std::uint8_t {
  WorkRequest,     // traverse -> display
  TileArrives,     // render -> display
  TileComposed,    // display CPU done with a tile
  TimeoutCheck,    // display: a tile's deadline
  TaskArrives,     // display -> traverse
  TraverseDone,    // traverse CPU done with a tile
  TraverseReport,  // render -> traverse
  Order,           // traverse or render -> data-send
  DatasendReport,  // render -> data-send
  PacketArrives,   // traverse -> render
  DataArrives,     // data-send -> render
  RenderIdle,      // render serve loop: onIdle
  RenderDone,      // render CPU done with a packet
  RenderMaintenance,
};

using Payload = std::variant<std::monostate, TaskMessage, std::shared_ptr<const OrderMessage>,
                             DataMessage, std::shared_ptr<const PacketMessage>,
                             std::shared_ptr<const ReportMessage>, std::shared_ptr<TileMessage>>;

struct Event {
  double time = 0.0;
  std::uint64_t sequence = 0;
  Kind kind = Kind::WorkRequest;
  std::uint32_t target = 0;  // index among its role
  Payload payload;
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

// --- the processes ----------------------------------------------------------

struct TraverseState {
  TraverseState(std::size_t renders, std::span<const TopLevelCell> topLevel,
                traverse::CostModel costModel)
      : model(renders, topLevel, costModel) {}
  traverse::RenderModel model;
  bool busy = false;
  std::optional<TaskMessage> task;
  const TileWork* work = nullptr;
  const std::vector<std::uint32_t>* ahead = nullptr;  // cells for the lookahead camera
  std::vector<Event> deferred;                        // reports that came while traversing
  std::uint64_t packetsSent = 0;
  std::vector<Interval> busyIntervals;
};

struct QueuedPacket {
  std::shared_ptr<const PacketMessage> packet;
  double arrived = 0.0;
  std::uint64_t sequence = 0;
  std::optional<double> dataComplete;  // when every cell was first present
};

struct RenderState {
  RenderState(std::uint64_t capBytes, double timeoutSeconds, std::size_t traverses)
      : cache(capBytes, std::chrono::milliseconds(static_cast<long>(timeoutSeconds * 1000.0))),
        lastPacketFrom(traverses, 0) {}
  render::CellCache cache;
  std::deque<QueuedPacket> queue;
  std::uint64_t packetsQueued = 0;
  std::uint64_t pinnedSequence = 0;
  std::vector<std::uint32_t> pinnedCells;
  // cell -> (when asked, frame it was asked for)
  std::map<std::uint32_t, std::pair<double, std::uint64_t>> requestedAt;
  std::vector<std::uint32_t> loaded;
  std::vector<std::uint32_t> evicted;
  std::vector<std::uint64_t> lastPacketFrom;
  bool busy = false;
  bool idlePending = false;
  bool maintenancePending = false;
  bool reportDirty = true;
  double lastMaintenance = 0.0;
  std::deque<Event> inbox;  // messages that came while rendering
  std::optional<QueuedPacket> current;
  double currentSeconds = 0.0;
  std::uint64_t workload = 0;
  std::uint64_t packetsDone = 0;
  std::uint64_t hits = 0;
  std::uint64_t misses = 0;
  std::uint64_t dataBytesReceived = 0;
  std::uint64_t droppedPrefetches = 0;
  double secondsPerSplat = 0.0;
  double secondsPerByte = 0.0;
  RecentSamples transferSamples{32};
  std::vector<Interval> busyIntervals;
};

constexpr double kMaintenanceSeconds = 0.25;  // render_role.cpp onIdle
constexpr double kRerequestSeconds = 1.0;     // render_role.cpp rerequestLateCells
constexpr double kSimulatedSecondsLimit = 1e5;

class Simulation {
 public:
  Simulation(const Scene& scene, const SimulationConfig& config, const ModelParameters& p)
      : scene_(scene),
        config_(config),
        p_(p),
        owners_(assignOwners(scene.topLevel(), config.datasends)),
        frames_(p.framesInFlight,
                std::chrono::milliseconds(static_cast<long>(p.tileTimeoutSeconds * 1000.0)),
                p.maxAttempts),
        planner_(display::TilePlanOptions{.scheduler = config.scheduler,
                                          .renders = config.renders,
                                          .tilesPerRender = config.tilesPerRender,
                                          .minTileSize = config.minTileSize,
                                          .balancedTiles = config.balancedTiles}),
        ranks_(1 + config.traverses + config.datasends + config.renders),
        outLinks_(ranks_),
        inLinks_(ranks_),
        sentTo_(config.datasends) {
    traverses_.reserve(config.traverses);
    for (std::uint32_t t = 0; t < config.traverses; ++t) {
      traverses_.emplace_back(config.renders, scene.topLevel(), config.costModel);
    }
    const auto capBytes = static_cast<std::uint64_t>(p.cacheMegabytes * 1024.0 * 1024.0);
    renders_.reserve(config.renders);
    for (std::uint32_t r = 0; r < config.renders; ++r) {
      renders_.emplace_back(capBytes, p.cacheTimeoutSeconds, config.traverses);
    }
    stats_.layout = "1," + std::to_string(config.traverses) + "," +
                    std::to_string(config.datasends) + "," + std::to_string(config.renders);
    stats_.dataset = scene.name();
    stats_.width = scene.width();
    stats_.height = scene.height();
    stats_.mode = "simulated";
  }

  SimulationResult run() {
    addFrames(0.0);
    for (std::uint32_t t = 0; t < config_.traverses; ++t) {
      schedule(control(0.0), Kind::WorkRequest, t, {});
    }
    // A render process reports once when it starts (reportDirty_ starts true).
    for (std::uint32_t r = 0; r < config_.renders; ++r) wakeRender(0.0, r);

    const std::size_t frameCount = scene_.cameras().size();
    while (!events_.empty() && stats_.frames.size() < frameCount) {
      std::pop_heap(events_.begin(), events_.end(), Later{});
      Event event = std::move(events_.back());
      events_.pop_back();
      ++eventCount_;
      if (event.time > kSimulatedSecondsLimit) {
        throw Error("simulation ran past " + std::to_string(kSimulatedSecondsLimit) +
                    " simulated seconds with " + std::to_string(stats_.frames.size()) + " of " +
                    std::to_string(frameCount) + " frames done");
      }
      handle(std::move(event));
    }
    if (stats_.frames.size() < frameCount) {
      throw Error("simulation stalled: no event left with " + std::to_string(stats_.frames.size()) +
                  " of " + std::to_string(frameCount) + " frames done (" + stats_.layout + ", " +
                  configName(config_) + ")");
    }
    return result();
  }

 private:
  // --- events and network ---------------------------------------------------

  void schedule(double time, Kind kind, std::uint32_t target, Payload payload) {
    events_.push_back(Event{time, ++sequence_, kind, target, std::move(payload)});
    std::push_heap(events_.begin(), events_.end(), Later{});
  }

  double control(double now) const { return now + p_.latencySeconds; }

  // Bulk bytes leave on the sender's outgoing link, first come first served,
  // and enter on the receiver's incoming link, which also serves one message
  // at a time; the switch buffers between the two, so a busy receiver does not
  // hold up the sender's other messages. Returns the arrival time.
  double bulk(double now, std::uint32_t fromRank, std::uint32_t toRank, std::uint64_t bytes) {
    Link& out = outLinks_[fromRank];
    Link& in = inLinks_[toRank];
    const double seconds = static_cast<double>(bytes) / p_.bandwidthBytesPerSecond;
    const double sent = std::max(now, out.freeAt) + seconds;
    out.busy.push_back({sent - seconds, sent});
    out.freeAt = sent;
    const double received = std::max(sent, in.freeAt + seconds);
    in.busy.push_back({received - seconds, received});
    in.freeAt = received;
    return received + p_.latencySeconds;
  }

  std::uint32_t traverseRank(std::uint32_t t) const { return 1 + t; }
  std::uint32_t datasendRank(std::uint32_t s) const { return 1 + config_.traverses + s; }
  std::uint32_t renderRank(std::uint32_t r) const {
    return 1 + config_.traverses + config_.datasends + r;
  }

  FrameTrace& trace(std::uint64_t frame) {
    FrameTrace& t = traces_[frame];
    t.frame = frame;
    return t;
  }

  void handle(Event&& event) {
    const double now = event.time;
    switch (event.kind) {
      case Kind::WorkRequest:
        idleTraverses_.push_back(event.target);
        dispatch(now);
        break;
      case Kind::TileArrives:
        tileArrives(now, std::get<std::shared_ptr<TileMessage>>(event.payload));
        break;
      case Kind::TileComposed:
        emitFrames(now);
        break;
      case Kind::TimeoutCheck:
        // Re-queued tiles go out again; tiles given up may complete a frame.
        if (frames_.checkTimeouts(toTime(now)) > 0) dispatch(now);
        emitFrames(now);
        break;
      case Kind::TaskArrives:
        taskArrives(now, event.target, std::get<TaskMessage>(std::move(event.payload)));
        break;
      case Kind::TraverseDone:
        traverseDone(now, event.target);
        break;
      case Kind::TraverseReport: {
        TraverseState& traverse = traverses_[event.target];
        if (traverse.busy) {
          traverse.deferred.push_back(std::move(event));
        } else {
          applyReport(now, event);
        }
        break;
      }
      case Kind::Order:
        order(now, event.target, *std::get<std::shared_ptr<const OrderMessage>>(event.payload));
        break;
      case Kind::DatasendReport: {
        const auto& report = *std::get<std::shared_ptr<const ReportMessage>>(event.payload);
        auto& sent = sentTo_[event.target];
        for (std::uint32_t cell : report.evicted) sent.erase(sentKey(report.render, cell));
        break;
      }
      case Kind::PacketArrives:
      case Kind::DataArrives:
      case Kind::RenderMaintenance: {
        RenderState& render = renders_[event.target];
        if (event.kind == Kind::RenderMaintenance) render.maintenancePending = false;
        if (render.busy) {
          render.inbox.push_back(std::move(event));
        } else {
          renderMessage(now, event);
          wakeRender(now, event.target);
        }
        break;
      }
      case Kind::RenderIdle: {
        RenderState& render = renders_[event.target];
        render.idlePending = false;
        if (!render.busy) idleStep(now, event.target);
        break;
      }
      case Kind::RenderDone:
        renderDone(now, event.target);
        break;
    }
  }

  // --- display (display/display_role.cpp) -------------------------------------

  void addFrames(double now) {
    const std::size_t frameCount = scene_.cameras().size();
    while (framesAdded_ < frameCount && framesAdded_ < stats_.frames.size() + p_.framesInFlight) {
      addFrame(framesAdded_++);
    }
    dispatch(now);
  }

  void addFrame(std::uint64_t index) {
    const Camera& camera = scene_.cameras()[index];
    std::vector<TileRect> tiles;
    const SceneBounds& bounds = scene_.bounds();
    if (const auto area =
            display::boxOfInterest(camera, bounds.min, bounds.max, scene_.marginWorld())) {
      tiles = planner_.plan(*area);
    }
    auto& feedback = feedback_[index];
    for (const TileRect& rect : tiles) feedback.push_back(display::TileFeedback{rect, 0.0, 0});
    trace(index).tilesPlanned = static_cast<std::uint32_t>(tiles.size());
    frames_.addFrame(index, camera, std::move(tiles), Image(1, 1));
  }

  void dispatch(double now) {
    while (!idleTraverses_.empty()) {
      const auto task = frames_.nextTask(toTime(now));
      if (!task) break;
      const display::FrameState* state = frames_.frame(task->frame);
      TaskMessage message;
      message.frame = task->frame;
      message.tile = task->tile;
      message.attempt = task->attempt;
      message.rect = state->tiles.at(task->tile).rect;
      // As the display does: assigned when handed out (round-robin counts hand-outs).
      message.assigned = planner_.assign(task->tile);
      message.dispatched = now;
      if (config_.scheduler == display::SchedulerKind::Cost && config_.prefetchFrames > 0 &&
          task->frame + config_.prefetchFrames < scene_.cameras().size()) {
        message.lookaheadFrame = task->frame + config_.prefetchFrames;
      }
      const std::uint32_t traverse = idleTraverses_.front();
      idleTraverses_.pop_front();
      schedule(control(now), Kind::TaskArrives, traverse, std::move(message));
      // FrameScheduler re-issues a tile once its deadline has passed.
      schedule(now + p_.tileTimeoutSeconds + 1e-6, Kind::TimeoutCheck, 0, {});
    }
  }

  void tileArrives(double now, const std::shared_ptr<TileMessage>& tile) {
    tile->sample.seconds = now;
    const int rank = static_cast<int>(renderRank(tile->render));
    stats_.renders[rank].push_back(tile->sample);
    tile->record.arrivedSeconds = now;
    stats_.tiles.push_back(tile->record);
    if (!frames_.tileArrived(tile->frame, tile->tile, tile->rect)) {
      ++stats_.lateTiles;
      return;
    }
    display::FrameRecord& record = pending_[tile->frame];
    record.splats += tile->splats;
    record.splatsPerRender[rank] += tile->splats;
    record.busySecondsPerRender[rank] += tile->seconds;
    feedback_.at(tile->frame).at(tile->tile) = {tile->rect, tile->seconds, tile->splats};
    ++trace(tile->frame).tilesComposed;
    // The display blits on its one CPU, tiles in arrival order.
    const double pixels = static_cast<double>(tile->rect.width()) * tile->rect.height();
    const double start = std::max(now, displayCpuFree_);
    displayCpuFree_ = start + pixels * p_.composeSecondsPerPixel;
    displayCpu_.push_back({start, displayCpuFree_});
    schedule(displayCpuFree_, Kind::TileComposed, 0, {});
  }

  void emitFrames(double now) {
    bool emitted = false;
    while (auto state = frames_.popCompleteFrame()) {
      emitted = true;
      display::FrameRecord record = std::move(pending_[state->index]);
      pending_.erase(state->index);
      record.frame = state->index;
      record.startSeconds = state->hasStarted ? toSeconds(state->started) : now;
      record.endSeconds = now;
      record.tiles = static_cast<std::uint32_t>(state->tiles.size());
      record.reissuedTiles = frames_.reissued(state->index);
      record.failedTiles = frames_.failed(state->index);
      for (std::uint32_t r = 0; r < config_.renders; ++r) {
        record.splatsPerRender.try_emplace(static_cast<int>(renderRank(r)), 0);
        record.busySecondsPerRender.try_emplace(static_cast<int>(renderRank(r)), 0.0);
      }
      // A frame with failed tiles has no measurement for them: no re-split from it.
      if (record.failedTiles == 0) planner_.frameDone(feedback_.at(state->index));
      feedback_.erase(state->index);
      completionOrder_.push_back(state->index);
      stats_.frames.push_back(std::move(record));
    }
    if (emitted) addFrames(now);
  }

  // --- traverse (traverse/traverse_role.cpp) ----------------------------------

  void taskArrives(double now, std::uint32_t t, TaskMessage task) {
    TraverseState& traverse = traverses_[t];
    if (traverse.busy) throw Error("internal error: a busy traverse process got a second task");
    traverse.busy = true;
    traverse.work = &scene_.tileWork(task.frame, task.rect);
    traverse.ahead =
        task.lookaheadFrame ? &scene_.cellsInTile(*task.lookaheadFrame, task.rect) : nullptr;
    traverse.task = std::move(task);
    // The prefetch walk stops at the top-level cells: charged one cell per cell found.
    const double cells = static_cast<double>(traverse.work->cellsVisited) +
                         (traverse.ahead ? static_cast<double>(traverse.ahead->size()) : 0.0);
    const double seconds = p_.traverseTileSeconds + p_.traverseSecondsPerCell * cells;
    traverse.busyIntervals.push_back({now, now + seconds});
    schedule(now + seconds, Kind::TraverseDone, t, {});
  }

  void traverseDone(double now, std::uint32_t t) {
    TraverseState& traverse = traverses_[t];
    const TaskMessage& task = *traverse.task;
    const TileWork& work = *traverse.work;
    // The choice sees the reports that arrived before the task, as in the
    // runtime, where reports wait in MPI while the traverse walks the tree.
    const traverse::RenderChoice choice =
        task.assigned ? traverse.model.assigned(*task.assigned, work.topLevelCells, work.splats)
                      : traverse.model.choose(work.topLevelCells, work.splats, toTime(now));
    const auto render = static_cast<std::uint32_t>(choice.render);

    std::map<std::uint32_t, std::vector<std::uint32_t>> orders;
    for (std::uint32_t cell : choice.missingCells) orders[owners_.at(cell)].push_back(cell);
    // Prefetch along the camera path: what this rect needs a few frames on
    // goes to the render drawing it now.
    std::uint64_t prefetchBytes = 0;
    if (traverse.ahead != nullptr) {
      std::vector<std::uint32_t> prefetch;
      for (std::uint32_t cell : traverse.model.missingCells(choice.render, *traverse.ahead)) {
        if (std::binary_search(choice.missingCells.begin(), choice.missingCells.end(), cell)) {
          continue;
        }
        const std::uint64_t bytes = scene_.topLevel()[cell].byteSize;
        if (prefetchBytes + bytes > traverse::kPrefetchBudgetBytes) break;
        prefetchBytes += bytes;
        prefetch.push_back(cell);
        orders[owners_.at(cell)].push_back(cell);
      }
      traverse.model.recordPrefetch(choice.render, prefetch);
    }
    for (auto& [owner, cells] : orders) {
      schedule(
          control(now), Kind::Order, owner,
          std::make_shared<const OrderMessage>(OrderMessage{render, std::move(cells), task.frame}));
    }
    auto packet = std::make_shared<PacketMessage>();
    packet->frame = task.frame;
    packet->tile = task.tile;
    packet->attempt = task.attempt;
    packet->rect = task.rect;
    packet->work = &work;
    packet->traverse = t;
    packet->packetId = ++traverse.packetsSent;
    packet->orderedBytes = choice.missingBytes;
    packet->prefetchBytes = prefetchBytes;
    packet->dispatched = task.dispatched;
    // A render packet carries the camera, the cells and three numbers per range.
    const std::uint64_t packetBytes = 160 + 4 * work.topLevelCells.size() + 12ull * work.ranges;
    schedule(bulk(now, traverseRank(t), renderRank(render), packetBytes), Kind::PacketArrives,
             render, std::shared_ptr<const PacketMessage>(packet));
    traverse.model.recordPacket(choice.render, packet->packetId, work.splats, choice.missingCells,
                                toTime(now));
    trace(task.frame).bytesOrdered += choice.missingBytes + prefetchBytes;
    trace(task.frame).bytesPrefetched += prefetchBytes;

    schedule(control(now), Kind::WorkRequest, t, {});
    traverse.busy = false;
    traverse.task.reset();
    traverse.work = nullptr;
    traverse.ahead = nullptr;
    auto deferred = std::move(traverse.deferred);
    traverse.deferred.clear();
    for (const Event& report : deferred) applyReport(now, report);
  }

  void applyReport(double now, const Event& event) {
    const auto& report = *std::get<std::shared_ptr<const ReportMessage>>(event.payload);
    traverse::RenderReportView view;
    view.workloadSplats = report.workload;
    view.loaded = report.loaded;
    view.evicted = report.evicted;
    view.secondsPerSplat = report.secondsPerSplat;
    view.secondsPerByte = report.secondsPerByte;
    view.lastPacketFromUs = report.lastPacketFrom.at(event.target);
    view.packetsDone = report.packetsDone;
    traverses_[event.target].model.applyReport(report.render, view, toTime(now));
  }

  // --- data-send (datasend/datasend_role.cpp) ---------------------------------

  static std::uint64_t sentKey(std::uint32_t render, std::uint32_t cell) {
    return (static_cast<std::uint64_t>(render) << 32) | cell;
  }

  void order(double now, std::uint32_t s, const OrderMessage& message) {
    auto& sent = sentTo_[s];
    for (std::uint32_t cell : message.cells) {
      if (owners_.at(cell) != s) {
        throw Error("internal error: cell " + std::to_string(cell) +
                    " ordered from a data-send process that does not own it");
      }
      // Never the same cell to the same render twice while it is there or on its way.
      if (!sent.insert(sentKey(message.render, cell)).second) {
        ++duplicateOrders_;
        continue;
      }
      const std::uint64_t bytes = scene_.topLevel()[cell].byteSize;
      const double arrival = bulk(now, datasendRank(s), renderRank(message.render), bytes);
      schedule(arrival, Kind::DataArrives, message.render,
               DataMessage{cell, bytes, static_cast<double>(bytes) / p_.bandwidthBytesPerSecond});
      trace(message.frame).bytesMoved += bytes;
      bytesMoved_ += bytes;
    }
  }

  // --- render (render/render_role.cpp) ----------------------------------------

  void wakeRender(double now, std::uint32_t r) {
    RenderState& render = renders_[r];
    if (render.idlePending || render.busy) return;
    render.idlePending = true;
    schedule(now, Kind::RenderIdle, r, {});
  }

  void renderMessage(double now, const Event& event) {
    switch (event.kind) {
      case Kind::PacketArrives:
        handlePacket(now, event.target,
                     std::get<std::shared_ptr<const PacketMessage>>(event.payload));
        break;
      case Kind::DataArrives:
        handleData(now, event.target, std::get<DataMessage>(event.payload));
        break;
      default:  // maintenance: the next idle step does it
        break;
    }
  }

  void handlePacket(double now, std::uint32_t r, std::shared_ptr<const PacketMessage> packet) {
    RenderState& render = renders_[r];
    render.lastPacketFrom[packet->traverse] =
        std::max(render.lastPacketFrom[packet->traverse], packet->packetId);
    std::map<std::uint32_t, std::vector<std::uint32_t>> requests;
    for (std::uint32_t cell : packet->work->topLevelCells) {
      if (render.cache.contains(cell)) {
        ++render.hits;
        render.cache.touch(cell, toTime(now));
        continue;
      }
      ++render.misses;
      // The traverse ordered it already; asking too covers a cell evicted after
      // the traverse last heard from us (data-send drops the duplicate).
      if (!render.requestedAt.contains(cell)) {
        render.requestedAt[cell] = {now, packet->frame};
        requests[owners_.at(cell)].push_back(cell);
      }
    }
    sendRequests(now, r, requests, packet->frame);
    render.workload += packet->work->splats;
    render.queue.push_back({std::move(packet), now, ++render.packetsQueued, std::nullopt});
    if (ready(render, *render.queue.back().packet)) render.queue.back().dataComplete = now;
    render.reportDirty = true;
  }

  void handleData(double now, std::uint32_t r, const DataMessage& data) {
    RenderState& render = renders_[r];
    render.dataBytesReceived += data.bytes;
    if (data.bytes >= 4096 && data.transferSeconds > 0.0) {
      render.transferSamples.add(data.transferSeconds / static_cast<double>(data.bytes));
      render.secondsPerByte = render.transferSamples.lowerQuartile();
    }
    render.requestedAt.erase(data.cell);
    if (render.cache.contains(data.cell)) return;  // a late duplicate
    if (!render.cache.pinned(data.cell) && !render.cache.canFit(data.bytes)) {
      // Prefetched data that cannot fit beside the packet being waited for.
      ++render.droppedPrefetches;
      render.evicted.push_back(data.cell);
      render.reportDirty = true;
      return;
    }
    for (std::uint32_t victim : render.cache.insert(data.cell, data.bytes, toTime(now))) {
      render.evicted.push_back(victim);
    }
    // Stamps the packets whose data has just become complete (data_wait_us).
    for (QueuedPacket& queued : render.queue) {
      if (!queued.dataComplete && ready(render, *queued.packet)) queued.dataComplete = now;
    }
    render.loaded.push_back(data.cell);
    render.reportDirty = true;
  }

  void sendRequests(double now, std::uint32_t r,
                    std::map<std::uint32_t, std::vector<std::uint32_t>>& requests,
                    std::uint64_t frame) {
    if (requests.empty()) return;
    RenderState& render = renders_[r];
    // Data-send must hear of an eviction before a request for the same cell.
    if (!render.evicted.empty()) sendReports(now, r);
    for (auto& [owner, cells] : requests) {
      schedule(control(now), Kind::Order, owner,
               std::make_shared<const OrderMessage>(OrderMessage{r, std::move(cells), frame}));
    }
    if (!render.maintenancePending) {
      render.maintenancePending = true;
      schedule(now + kRerequestSeconds + 1e-6, Kind::RenderMaintenance, r, {});
    }
  }

  void pinHeadPacket(double now, std::uint32_t r) {
    RenderState& render = renders_[r];
    const std::uint64_t head = render.queue.empty() ? 0 : render.queue.front().sequence;
    if (head == render.pinnedSequence) return;
    for (std::uint32_t cell : render.pinnedCells) render.cache.unpin(cell);
    render.pinnedCells.clear();
    render.pinnedSequence = head;
    if (render.queue.empty()) return;
    const PacketMessage& packet = *render.queue.front().packet;
    std::map<std::uint32_t, std::vector<std::uint32_t>> requests;
    for (std::uint32_t cell : packet.work->topLevelCells) {
      render.cache.pin(cell);
      render.pinnedCells.push_back(cell);
      if (!render.cache.contains(cell) && !render.requestedAt.contains(cell)) {
        render.requestedAt[cell] = {now, packet.frame};
        requests[owners_.at(cell)].push_back(cell);
      }
    }
    sendRequests(now, r, requests, packet.frame);
  }

  bool ready(const RenderState& render, const PacketMessage& packet) const {
    return std::all_of(packet.work->topLevelCells.begin(), packet.work->topLevelCells.end(),
                       [&](std::uint32_t cell) { return render.cache.contains(cell); });
  }

  // onIdle: maintenance, pin the head packet, render the first ready packet;
  // the report goes out after the packet, or now when nothing could render.
  void idleStep(double now, std::uint32_t r) {
    RenderState& render = renders_[r];
    if (now - render.lastMaintenance > kMaintenanceSeconds) {
      render.lastMaintenance = now;
      for (std::uint32_t cell : render.cache.expire(toTime(now))) render.evicted.push_back(cell);
      if (!render.evicted.empty()) render.reportDirty = true;
      rerequestLateCells(now, r);
    }
    pinHeadPacket(now, r);
    for (auto it = render.queue.begin(); it != render.queue.end(); ++it) {
      if (!ready(render, *it->packet)) continue;
      render.current = std::move(*it);
      render.queue.erase(it);
      render.busy = true;
      render.currentSeconds =
          p_.packetOverheadSeconds +
          static_cast<double>(render.current->packet->work->splats) * p_.secondsPerSplat;
      render.busyIntervals.push_back({now, now + render.currentSeconds});
      schedule(now + render.currentSeconds, Kind::RenderDone, r, {});
      return;
    }
    if (render.reportDirty) sendReports(now, r);
    if (!render.requestedAt.empty() && !render.maintenancePending) {
      render.maintenancePending = true;
      schedule(now + kMaintenanceSeconds + 1e-6, Kind::RenderMaintenance, r, {});
    }
  }

  void rerequestLateCells(double now, std::uint32_t r) {
    RenderState& render = renders_[r];
    std::map<std::uint32_t, std::vector<std::uint32_t>> requests;
    std::uint64_t frame = 0;
    for (auto& [cell, asked] : render.requestedAt) {
      if (now - asked.first > kRerequestSeconds) {
        asked.first = now;
        frame = asked.second;
        requests[owners_.at(cell)].push_back(cell);
      }
    }
    sendRequests(now, r, requests, frame);
  }

  void renderDone(double now, std::uint32_t r) {
    RenderState& render = renders_[r];
    const QueuedPacket queued = std::move(*render.current);
    render.current.reset();
    const PacketMessage& packet = *queued.packet;
    const std::uint64_t splats = packet.work->splats;
    const double seconds = render.currentSeconds;
    for (std::uint32_t cell : packet.work->topLevelCells) render.cache.touch(cell, toTime(now));
    if (splats >= 1000 && seconds > 0.0) {
      render.secondsPerSplat =
          movingAverage(render.secondsPerSplat, seconds / static_cast<double>(splats));
    }
    render.workload -= std::min(render.workload, splats);
    ++render.packetsDone;
    ++trace(packet.frame).packetsRendered;
    ++packetsRendered_;

    auto tile = std::make_shared<TileMessage>();
    tile->frame = packet.frame;
    tile->tile = packet.tile;
    tile->rect = packet.rect;
    tile->render = r;
    tile->splats = splats;
    tile->seconds = seconds;
    tile->sample.frame = packet.frame;
    tile->sample.workloadSplats = render.workload;
    tile->sample.cacheBytes = render.cache.bytes();
    tile->sample.peakCacheBytes = render.cache.peakBytes();
    tile->sample.cacheHits = render.hits;
    tile->sample.cacheMisses = render.misses;
    tile->sample.evictions = render.cache.evictions();
    tile->sample.dataBytesReceived = render.dataBytesReceived;
    display::TileRecord& record = tile->record;
    record.frame = packet.frame;
    record.tile = packet.tile;
    record.attempt = packet.attempt;
    record.renderRank = static_cast<int>(renderRank(r));
    record.traverseRank = static_cast<int>(traverseRank(packet.traverse));
    record.dispatchedSeconds = packet.dispatched;
    record.queuedSeconds = now - queued.arrived;
    record.dataWaitSeconds = queued.dataComplete.value_or(queued.arrived) - queued.arrived;
    record.renderSeconds = seconds;
    record.splats = splats;
    record.pixels = static_cast<std::uint64_t>(packet.rect.width()) * packet.rect.height();
    record.orderedBytes = packet.orderedBytes;
    record.prefetchBytes = packet.prefetchBytes;
    const std::uint64_t imageBytes =
        static_cast<std::uint64_t>(packet.rect.width()) * packet.rect.height() * 4 + 128;
    schedule(bulk(now, renderRank(r), 0, imageBytes), Kind::TileArrives, 0, std::move(tile));
    render.reportDirty = true;
    sendReports(now, r);
    render.busy = false;

    // The serve loop drains what came while rendering, then idles again.
    while (!render.inbox.empty()) {
      const Event event = std::move(render.inbox.front());
      render.inbox.pop_front();
      renderMessage(now, event);
    }
    idleStep(now, r);
  }

  void sendReports(double now, std::uint32_t r) {
    RenderState& render = renders_[r];
    render.reportDirty = false;
    auto report = std::make_shared<ReportMessage>();
    report->render = r;
    report->workload = render.workload;
    report->loaded = std::move(render.loaded);
    report->evicted = std::move(render.evicted);
    report->secondsPerSplat = render.secondsPerSplat;
    report->secondsPerByte = render.secondsPerByte;
    report->packetsDone = render.packetsDone;
    report->lastPacketFrom = render.lastPacketFrom;
    render.loaded.clear();
    render.evicted.clear();
    const std::shared_ptr<const ReportMessage> shared = std::move(report);
    for (std::uint32_t t = 0; t < config_.traverses; ++t) {
      schedule(control(now), Kind::TraverseReport, t, shared);
    }
    // Data-send only reads the evictions, so a report without any is not sent.
    if (!shared->evicted.empty()) {
      for (std::uint32_t s = 0; s < config_.datasends; ++s) {
        schedule(control(now), Kind::DatasendReport, s, shared);
      }
    }
  }

  // --- results -------------------------------------------------------------

  SimulationResult result() {
    SimulationResult out;
    out.config = config_;
    out.stats = std::move(stats_);
    display::RunStats& stats = out.stats;
    stats.totalSeconds = stats.frames.empty() ? 0.0 : stats.frames.back().endSeconds;
    for (display::FrameRecord& record : stats.frames) {
      record.bytesOrdered = trace(record.frame).bytesMoved;
      record.bytesPrefetched = trace(record.frame).bytesPrefetched;
    }
    out.figures = stats.keyFigures();
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
    for (const RenderState& render : renders_) {
      const double share = busyShare(render.busyIntervals, from, to);
      u.renderMean += share / static_cast<double>(renders_.size());
      u.renderMax = std::max(u.renderMax, share);
      out.droppedPrefetches += render.droppedPrefetches;
    }
    for (const TraverseState& traverse : traverses_) {
      const double share = busyShare(traverse.busyIntervals, from, to);
      u.traverseMean += share / static_cast<double>(traverses_.size());
      u.traverseMax = std::max(u.traverseMax, share);
    }
    for (std::uint32_t rank = 1; rank < ranks_; ++rank) {
      u.networkMax = std::max({u.networkMax, busyShare(outLinks_[rank].busy, from, to),
                               busyShare(inLinks_[rank].busy, from, to)});
    }
    u.displayLink = busyShare(inLinks_[0].busy, from, to);
    u.displayCpu = busyShare(displayCpu_, from, to);
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
    // Nothing near saturation: the frames in flight wait on round trips.
    if (out.bottleneckUtilisation < 0.5) out.bottleneck = "latency";

    out.packetsRendered = packetsRendered_;
    out.bytesMoved = bytesMoved_;
    out.duplicateOrders = duplicateOrders_;
    out.events = eventCount_;
    return out;
  }

  const Scene& scene_;
  SimulationConfig config_;
  ModelParameters p_;
  std::vector<std::uint32_t> owners_;

  std::vector<Event> events_;  // a heap ordered by (time, sequence)
  std::uint64_t sequence_ = 0;
  std::uint64_t eventCount_ = 0;

  // display
  display::FrameScheduler frames_;
  display::TilePlanner planner_;
  std::uint64_t framesAdded_ = 0;
  std::map<std::uint64_t, std::vector<display::TileFeedback>> feedback_;
  std::map<std::uint64_t, display::FrameRecord> pending_;
  std::deque<std::uint32_t> idleTraverses_;
  double displayCpuFree_ = 0.0;
  std::vector<Interval> displayCpu_;
  display::RunStats stats_;
  std::vector<std::uint64_t> completionOrder_;
  std::map<std::uint64_t, FrameTrace> traces_;

  std::uint32_t ranks_;
  std::vector<Link> outLinks_;
  std::vector<Link> inLinks_;
  std::vector<TraverseState> traverses_;
  std::vector<std::unordered_set<std::uint64_t>> sentTo_;  // per data-send: (render, cell)
  std::vector<RenderState> renders_;

  std::uint64_t packetsRendered_ = 0;
  std::uint64_t bytesMoved_ = 0;
  std::uint64_t duplicateOrders_ = 0;
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
