#include "display/display_role.hpp"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <deque>
#include <filesystem>
#include <thread>

#include "common/camera_path.hpp"
#include "common/dataset.hpp"
#include "common/image.hpp"
#include "common/mpi/role_options.hpp"
#include "common/view_options.hpp"
#include "display/frame_scheduler.hpp"
#include "display/frame_stats.hpp"
#include "display/tile_planner.hpp"
#include "display/tiling.hpp"

namespace pointillist::display {
namespace {

using Clock = std::chrono::steady_clock;
constexpr Rgba8 kBackground{0, 0, 0, 255};
constexpr Rgba8 kFailedTile{255, 0, 255, 255};  // a tile that never came back

struct DisplayOptions {
  CommonRoleOptions common;
  double idleSeconds = 0.0;
  double shutdownTimeoutSeconds = 60.0;
  std::string datasetPath;
  ViewOptions view;
  std::string outDir;
  std::string statsFile;
  std::uint32_t framesInFlight = 3;
  double tilesPerRender = 2.0;
  std::uint32_t minTileSize = 32;
  double tileTimeoutSeconds = 10.0;
  std::uint32_t maxAttempts = 3;
  std::string scheduler = "cost";
  bool equalTiles = false;
  std::string costModel = "paper";
  std::uint32_t prefetchFrames = 0;
  bool quiet = false;
};

v1::Scheduler schedulerMessage(SchedulerKind kind) {
  switch (kind) {
    case SchedulerKind::Cost:
      return v1::SCHEDULER_COST;
    case SchedulerKind::RoundRobin:
      return v1::SCHEDULER_ROUND_ROBIN;
    case SchedulerKind::Static:
      return v1::SCHEDULER_STATIC;
    case SchedulerKind::Equalizer:
      return v1::SCHEDULER_EQUALIZER;
  }
  return v1::SCHEDULER_COST;
}

v1::CostModel parseCostModel(const std::string& name) {
  if (name == "overlap") return v1::COST_MODEL_OVERLAP;
  if (name == "paper") return v1::COST_MODEL_PAPER;
  throw UsageError("cost model '" + name + "' is not one of: overlap, paper");
}

TilePlanOptions tilePlanOptions(const DisplayOptions& options, std::uint32_t renders) {
  TilePlanOptions plan;
  plan.scheduler = parseSchedulerKind(options.scheduler);
  plan.renders = renders;
  plan.tilesPerRender = options.tilesPerRender;
  plan.minTileSize = options.minTileSize;
  plan.balancedTiles = !options.equalTiles;
  return plan;
}

double since(Clock::time_point start, Clock::time_point now) {
  return std::chrono::duration<double>(now - start).count();
}

class DisplayProcess {
 public:
  DisplayProcess(Job& job, const DisplayOptions& options)
      : job_(job),
        options_(options),
        dataset_(Dataset::open(options.datasetPath, DatasetParts::Cells)),
        frames_(options.framesInFlight,
                std::chrono::milliseconds(static_cast<long>(options.tileTimeoutSeconds * 1000.0)),
                options.maxAttempts),
        mode_(parseRenderMode(options.view.mode)),
        planner_(tilePlanOptions(options, job.layout().render)),
        scheduler_(schedulerMessage(planner_.options().scheduler)),
        costModel_(parseCostModel(options.costModel)) {
    bounds_ = datasetBounds(dataset_.manifest());
    // The root holds the largest splat radius of the whole tree.
    maxRadius_ = dataset_.cells().empty() ? 0.0f : dataset_.cells()[0].maxSplatRadius;
    cameras_ = viewCameras(options.view, bounds_);
    const auto [width, height] = parseImageSize(options.view.size);
    width_ = width;
    height_ = height;
    // Fail before rendering, not after, when the outputs cannot be written.
    if (!options.outDir.empty()) std::filesystem::create_directories(options.outDir);
    if (const auto folder = std::filesystem::path(options.statsFile).parent_path();
        !folder.empty()) {
      std::filesystem::create_directories(folder);
    }
    stats_.layout = job.layout().toString();
    stats_.dataset = options.datasetPath;
    stats_.cameraPath = options.view.cameraPath;
    stats_.width = width_;
    stats_.height = height_;
    stats_.mode = options.view.mode;
  }

  void run() {
    start_ = Clock::now();
    Backoff backoff;
    while (framesAdded_ < cameras_.size() || !frames_.finished()) {
      // Frames are laid out when they enter the window, so a re-split from the
      // last completed frame applies to the next one.
      while (framesAdded_ < cameras_.size() &&
             framesAdded_ < stats_.frames.size() + options_.framesInFlight) {
        addFrame(framesAdded_++);
      }
      bool worked = false;
      while (auto envelope = job_.channel().tryReceive()) {
        handle(*envelope);
        worked = true;
      }
      worked = dispatch() || worked;
      const auto requeued = frames_.checkTimeouts(Clock::now());
      if (requeued > 0) {
        std::fprintf(stderr, "display: %u tile(s) did not come back in %.1f s; re-issued\n",
                     requeued, options_.tileTimeoutSeconds);
        worked = true;
      }
      worked = emitFrames() || worked;
      if (worked) {
        backoff.reset();
      } else {
        backoff.wait();
      }
    }
    stats_.totalSeconds = since(start_, Clock::now());
    std::printf("%s", stats_.summary().c_str());
    const std::string statsFile = !options_.statsFile.empty() ? options_.statsFile
                                  : !options_.outDir.empty()  ? options_.outDir + "/stats.json"
                                                              : std::string();
    if (!statsFile.empty()) {
      stats_.writeJson(statsFile);
      const auto csvDir = std::filesystem::path(statsFile).parent_path();
      stats_.writeCsv(csvDir.empty() ? std::filesystem::path(".") : csvDir);
      std::printf("display: statistics in %s and the CSV files beside it\n", statsFile.c_str());
    }
    std::fflush(stdout);
  }

 private:
  void addFrame(std::uint64_t index) {
    const Camera& camera = cameras_[index];
    std::vector<TileRect> tiles;
    const float margin = maxRadius_ * options_.view.sizeScale;
    if (const auto area = boxOfInterest(camera, bounds_.min, bounds_.max, margin)) {
      tiles = planner_.plan(*area);
    }
    frames_.addFrame(index, camera, std::move(tiles), Image(width_, height_, kBackground));
  }

  void handle(Envelope& envelope) {
    switch (envelope.kind) {
      case MessageKind::WorkRequest:
        idleTraverses_.push_back(envelope.source);
        break;
      case MessageKind::TileImage:
        handleTile(envelope);
        break;
      case MessageKind::ErrorReport: {
        const auto report = envelope.as<v1::ErrorReport>();
        throw ProtocolError(executableName(report.origin_role()) + " rank " +
                            std::to_string(report.origin_rank()) + " failed: " + report.message());
      }
      default:
        throw ProtocolError(std::string("display got an unexpected ") +
                            messageKindName(envelope.kind) + " from rank " +
                            std::to_string(envelope.source));
    }
  }

  bool dispatch() {
    bool worked = false;
    while (!idleTraverses_.empty()) {
      const auto task = frames_.nextTask(Clock::now());
      if (!task) break;
      const FrameState* state = frames_.frame(task->frame);
      v1::TileTask message;
      message.set_frame_id(task->frame);
      message.set_tile_id(task->tile);
      *message.mutable_camera() = state->camera;
      *message.mutable_rect() = state->tiles.at(task->tile).rect;
      message.set_timestamp_ns(
          std::chrono::duration_cast<std::chrono::nanoseconds>(Clock::now().time_since_epoch())
              .count());
      message.set_attempt(task->attempt);
      message.set_mode(mode_);
      message.set_lod_pixels(options_.view.lodPixels);
      message.set_size_scale(options_.view.sizeScale);
      message.set_backface_cull(!options_.view.noBackfaceCull);
      message.set_scheduler(scheduler_);
      message.set_cost_model(costModel_);
      if (scheduler_ == v1::SCHEDULER_COST && options_.prefetchFrames > 0 &&
          task->frame + options_.prefetchFrames < cameras_.size()) {
        *message.mutable_lookahead_camera() = cameras_[task->frame + options_.prefetchFrames];
      }
      message.set_assigned_render(planner_.assign(task->tile).value_or(0));
      dispatchedAt_[{task->frame, task->tile}] = since(start_, Clock::now());
      const int traverse = idleTraverses_.front();
      idleTraverses_.pop_front();
      sends_.push_back(job_.channel().post(traverse, MessageKind::TileTask, message));
      worked = true;
    }
    while (!sends_.empty() && sends_.front().test()) sends_.pop_front();
    return worked;
  }

  void handleTile(const Envelope& envelope) {
    const auto header = envelope.as<v1::TileImageHeader>();
    const auto now = Clock::now();
    RenderSample sample;
    sample.seconds = since(start_, now);
    sample.frame = header.frame_id();
    sample.workloadSplats = header.workload_splats();
    sample.cacheBytes = header.cache_bytes();
    sample.peakCacheBytes = header.peak_cache_bytes();
    sample.cacheHits = header.cache_hits();
    sample.cacheMisses = header.cache_misses();
    sample.evictions = header.evictions();
    sample.dataBytesReceived = header.data_bytes_received();
    stats_.renders[header.render_rank()].push_back(sample);

    const std::uint64_t expectedBytes =
        static_cast<std::uint64_t>(header.rect().width()) * header.rect().height() * 4;
    if (header.format() != v1::PIXEL_FORMAT_RGBA8 || envelope.payload.size() != expectedBytes) {
      throw ProtocolError("tile image from rank " + std::to_string(envelope.source) + " has " +
                          std::to_string(envelope.payload.size()) + " bytes, expected " +
                          std::to_string(expectedBytes));
    }
    TileRecord tileRecord;
    tileRecord.frame = header.frame_id();
    tileRecord.tile = header.tile_id();
    tileRecord.attempt = header.attempt();
    tileRecord.renderRank = header.render_rank();
    tileRecord.traverseRank = header.traverse_rank();
    tileRecord.arrivedSeconds = sample.seconds;
    if (const auto found = dispatchedAt_.find({header.frame_id(), header.tile_id()});
        found != dispatchedAt_.end()) {
      tileRecord.dispatchedSeconds = found->second;
      dispatchedAt_.erase(found);
    }
    tileRecord.queuedSeconds = static_cast<double>(header.queued_time_us()) * 1e-6;
    tileRecord.dataWaitSeconds = static_cast<double>(header.data_wait_us()) * 1e-6;
    tileRecord.renderSeconds = static_cast<double>(header.render_time_us()) * 1e-6;
    tileRecord.splats = header.splats_rendered();
    tileRecord.pixels = static_cast<std::uint64_t>(header.rect().width()) * header.rect().height();
    tileRecord.orderedBytes = header.ordered_bytes();
    tileRecord.prefetchBytes = header.prefetch_bytes();
    stats_.tiles.push_back(tileRecord);
    if (!frames_.tileArrived(header.frame_id(), header.tile_id(), header.rect())) {
      ++stats_.lateTiles;
      return;
    }
    FrameState* state = frames_.frame(header.frame_id());
    blit(std::span<const std::uint8_t>(
             reinterpret_cast<const std::uint8_t*>(envelope.payload.data()),
             envelope.payload.size()),
         header.rect().width(), header.rect().height(), state->image, header.rect().x(),
         header.rect().y());
    FrameRecord& record = pending_[header.frame_id()];
    record.splats += header.splats_rendered();
    record.bytesOrdered += header.ordered_bytes() + header.prefetch_bytes();
    record.bytesPrefetched += header.prefetch_bytes();
    record.splatsPerRender[header.render_rank()] += header.splats_rendered();
    record.busySecondsPerRender[header.render_rank()] +=
        static_cast<double>(header.render_time_us()) * 1e-6;
    auto& feedback = tileFeedback_[header.frame_id()];
    feedback.resize(state->tiles.size());
    TileFeedback& tile = feedback.at(header.tile_id());
    tile.rect = header.rect();
    tile.seconds = static_cast<double>(header.render_time_us()) * 1e-6;
    tile.splats = header.splats_rendered();
  }

  bool emitFrames() {
    bool worked = false;
    while (auto state = frames_.popCompleteFrame()) {
      worked = true;
      const auto now = Clock::now();
      FrameRecord record = std::move(pending_[state->index]);
      pending_.erase(state->index);
      record.frame = state->index;
      record.startSeconds = state->hasStarted ? since(start_, state->started) : since(start_, now);
      record.endSeconds = since(start_, now);
      record.tiles = static_cast<std::uint32_t>(state->tiles.size());
      record.reissuedTiles = frames_.reissued(state->index);
      record.failedTiles = frames_.failed(state->index);
      if (record.failedTiles == 0) planner_.frameDone(tileFeedback_[state->index]);
      tileFeedback_.erase(state->index);
      for (const auto& [rank, samples] : stats_.renders) {
        record.splatsPerRender.try_emplace(rank, 0);
        record.busySecondsPerRender.try_emplace(rank, 0.0);
      }
      for (const TileState& tile : state->tiles) {
        if (!tile.failed) continue;
        for (std::uint32_t y = 0; y < tile.rect.height(); ++y) {
          for (std::uint32_t x = 0; x < tile.rect.width(); ++x) {
            state->image.set(tile.rect.x() + x, tile.rect.y() + y, kFailedTile);
          }
        }
      }
      if (!options_.outDir.empty()) {
        char name[64];
        std::snprintf(name, sizeof name, "frame_%05llu.png",
                      static_cast<unsigned long long>(state->index));
        writePng(state->image, std::filesystem::path(options_.outDir) / name, true);
      }
      if (!options_.quiet) {
        std::printf(
            "frame %4llu: %7.1f ms (done at %.2f s), %6.2f M splats, %3u tiles, %8.1f KiB "
            "data%s%s\n",
            static_cast<unsigned long long>(record.frame),
            (record.endSeconds - record.startSeconds) * 1000.0, record.endSeconds,
            static_cast<double>(record.splats) / 1e6, record.tiles,
            static_cast<double>(record.bytesOrdered) / 1024.0,
            record.reissuedTiles
                ? (", " + std::to_string(record.reissuedTiles) + " re-issued").c_str()
                : "",
            record.failedTiles ? (", " + std::to_string(record.failedTiles) + " FAILED").c_str()
                               : "");
        std::fflush(stdout);
      }
      if (record.failedTiles > 0) {
        std::fprintf(
            stderr,
            "display: frame %llu: %u tile(s) never arrived after %u attempts (drawn magenta)\n",
            static_cast<unsigned long long>(record.frame), record.failedTiles,
            options_.maxAttempts);
      }
      stats_.frames.push_back(std::move(record));
    }
    return worked;
  }

  Job& job_;
  DisplayOptions options_;
  Dataset dataset_;
  FrameScheduler frames_;
  v1::RenderMode mode_;
  TilePlanner planner_;
  v1::Scheduler scheduler_;
  v1::CostModel costModel_;
  std::uint64_t framesAdded_ = 0;
  std::map<std::uint64_t, std::vector<TileFeedback>> tileFeedback_;
  std::map<std::pair<std::uint64_t, std::uint32_t>, double> dispatchedAt_;
  SceneBounds bounds_;
  float maxRadius_ = 0.0f;
  std::uint32_t width_ = 0;
  std::uint32_t height_ = 0;
  std::vector<Camera> cameras_;
  std::deque<int> idleTraverses_;
  std::deque<SendHandle> sends_;
  std::map<std::uint64_t, FrameRecord> pending_;
  RunStats stats_;
  Clock::time_point start_;
};

void stayIdle(double seconds) {
  if (seconds <= 0.0) return;
  std::this_thread::sleep_for(std::chrono::duration<double>(seconds));
}

}  // namespace

int runDisplayRole(Job& job, int argc, char** argv) {
  CLI::App app{"Pointillist display process (started by deploy/run.sh)"};
  DisplayOptions options;
  addCommonRoleOptions(app, options.common);
  app.add_option("--idle-seconds", options.idleSeconds,
                 "Keep the job up and idle this long before shutting down");
  app.add_option("--shutdown-timeout", options.shutdownTimeoutSeconds,
                 "Seconds to wait for every process to acknowledge shutdown");
  app.add_option("--dataset", options.datasetPath, "Dataset directory (pointillist-preprocess)");
  addViewOptions(app, options.view);
  app.add_option("--out", options.outDir, "Directory for PNG frames and stats.json");
  app.add_option("--stats", options.statsFile, "Statistics JSON file (default OUT/stats.json)");
  app.add_option("--frames-in-flight", options.framesInFlight, "Frames handed out at once");
  app.add_option("--tiles-per-render", options.tilesPerRender,
                 "Mini frusta per frame per render process");
  app.add_option("--min-tile", options.minTileSize, "Smallest tile side in pixels");
  app.add_option("--tile-timeout", options.tileTimeoutSeconds,
                 "Seconds before a missing tile is handed out again");
  app.add_option("--max-attempts", options.maxAttempts,
                 "Times a tile is handed out before it is given up");
  app.add_option("--scheduler", options.scheduler,
                 "How tiles are given to render processes: cost (seed 003), round-robin, "
                 "static, equalizer");
  app.add_option("--cost-model", options.costModel,
                 "Cost scheduler: paper (seed 003: transfer time adds to the queue, default) or "
                 "overlap (transfers overlap queued work)");
  app.add_option("--prefetch-frames", options.prefetchFrames,
                 "Cost scheduler: order the data each tile's rect needs this many frames on "
                 "(0: no prefetch)");
  app.add_flag("--equal-tiles", options.equalTiles,
               "Cost scheduler: equal tiles instead of tiles sized by last frame's work");
  app.add_flag("--quiet", options.quiet, "No per-frame lines");
  if (!parseRoleOptions(app, job, argc, argv)) return 0;

  const auto start = Clock::now();
  std::unique_ptr<DisplayProcess> process;
  if (!options.datasetPath.empty()) process = std::make_unique<DisplayProcess>(job, options);
  job.handshake(handshakeOptions(options.common));
  const auto ready = job.awaitReady(std::chrono::milliseconds(
      static_cast<long>(options.common.handshakeTimeoutSeconds * 1000.0)));
  std::printf("display: job %s ready (%zu peers) in %.2f s\n", job.layout().toString().c_str(),
              ready.size(), since(start, Clock::now()));
  for (const auto& peer : ready) {
    if (!peer.detail().empty() && !options.quiet) {
      std::printf("  %s rank %d: %s\n", executableName(peer.role()).c_str(), peer.world_rank(),
                  peer.detail().c_str());
    }
  }
  std::fflush(stdout);

  const double displayCpuBefore = processCpuSeconds();
  if (process) {
    process->run();
  } else {
    stayIdle(options.idleSeconds);
  }
  const double displayCpu = processCpuSeconds() - displayCpuBefore;

  job.shutdownAll("job complete", std::chrono::milliseconds(
                                      static_cast<long>(options.shutdownTimeoutSeconds * 1000.0)));
  double peerCpu = 0.0;
  double peerWall = 0.0;
  for (const auto& ack : job.lastAcks()) {
    peerCpu += ack.cpu_seconds_since_ready();
    peerWall = std::max(peerWall, ack.wall_seconds_since_ready());
    if (process && !options.quiet && !ack.summary().empty()) {
      std::printf("  %s rank %d: %s\n", executableName(ack.role()).c_str(), ack.world_rank(),
                  ack.summary().c_str());
    }
  }
  std::printf(
      "display: shutdown complete; cpu since ready: %.3f core-seconds over %.2f s across %d "
      "ranks (display %.3f)\n",
      peerCpu + displayCpu, peerWall, job.worldSize(), displayCpu);
  std::fflush(stdout);
  return 0;
}

}  // namespace pointillist::display
