#include "display/display_role.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <exception>
#include <filesystem>
#include <limits>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <thread>

#include "common/camera_path.hpp"
#include "common/clock.hpp"
#include "common/dataset.hpp"
#include "common/image.hpp"
#include "common/instanced_section.hpp"
#include "common/mpi/role_program.hpp"
#include "common/peer_watch.hpp"
#include "common/run_settings.hpp"
#include "common/statistical_node.hpp"
#include "common/task_pool.hpp"
#include "common/view_options.hpp"
#include "display/core/frame_assembly.hpp"
#include "display/core/frame_stats.hpp"
#include "display/core/tile_parts.hpp"
#include "display/core/tile_planner.hpp"
#include "display/frame_source.hpp"
#include "display/service_frame_source.hpp"

namespace pointillist::display {
namespace {

constexpr Rgba8 kBackground = kFrameBackground;
constexpr Rgba8 kFailedTile{255, 0, 255, 255};  // a tile that never came back

struct DisplayOptions {
  CommonRoleOptions common;
  double idleSeconds = 0.0;
  double shutdownTimeoutSeconds = 60.0;
  std::string datasetPath;
  ViewOptions view;
  std::string outDir;
  std::string statsFile;
  std::size_t statsFrames = 4096;
  std::uint32_t framesInFlight = 3;
  unsigned imageThreads = 0;  // expanding compressed tile images (0: the cores, at most 8)
  double tilesPerRender = 2.0;
  bool tilesPerRenderGiven = false;  // else the cost scheduler's tile count is tuned
  std::uint32_t minTileSize = 32;
  double tileTimeoutSeconds = 10.0;
  std::uint32_t maxAttempts = 3;
  LivenessSettings liveness;
  double checkpointSeconds = 10.0;
  std::string scheduler = "cost";
  bool equalTiles = false;
  std::string costModel = costModelName(kDefaultCostModel);
  std::uint32_t prefetchFrames = 0;
  std::string tileTasksAhead = "auto";
  std::string renderCoreShare = "auto";
  std::string tileSplit = "auto";
  std::string sharedPackets = "on";
  std::string needGap = "auto";
  bool quiet = false;
  // Serve mode: frames are asked for by clients over ZeroMQ.
  bool serve = false;
  std::string listen = "tcp://127.0.0.1:5570";
  std::string streamListen;
  std::size_t maxClients = 64;
  int streamHighWaterMark = 16;
  std::string encoding = "png";
  std::uint32_t jpegQuality = 90;
  std::string curveSecretKey;
  std::string curveAuthorizedKeys;
  // Serve mode's render cache (seed 001); unset: on in serve mode.
  std::optional<double> interimMs;
  std::size_t cachePoints = 0;
  std::uint32_t cacheMaxAge = RenderCacheOptions{}.maxAge;
  float depthCull = RenderCacheOptions{}.depthCullFraction;
  std::string tilePriority = "cache";
  double interimRefreshMs = -1.0;
};

// With --serve and no --interim-ms: an interim frame at once.
constexpr double kServeInterimMs = 0.0;

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

// What every process of the run is told once, in the handshake reply.
// `manifest`: the dataset's, when the display has one.
v1::RunSettings runSettings(const DisplayOptions& options, const DatasetManifest* manifest,
                            const JobLayout& layout) {
  v1::RunSettings settings;
  if (manifest != nullptr) {
    settings.set_instanced_sections(manifest->file(kInstancedSectionsKey) != nullptr);
    settings.set_statistical_hierarchy(manifest->file(kStatisticalIndexKey) != nullptr);
  }
  settings.set_mode(parseRenderMode(options.view.mode));
  settings.set_lod_pixels(options.view.lodPixels);
  settings.set_size_scale(options.view.sizeScale);
  settings.set_backface_cull(!options.view.noBackfaceCull);
  settings.set_scheduler(schedulerMessage(parseSchedulerKind(options.scheduler)));
  settings.set_cost_model(parseCostModel(options.costModel));
  const std::uint32_t ahead = parseTileTasksAhead(options.tileTasksAhead);
  settings.set_tile_tasks_ahead(
      ahead > 0 ? ahead
                : autoTileTasksAhead(options.tilesPerRender * layout.render, layout.traverse));
  parseTileSplit(options.tileSplit, settings);
  settings.set_no_shared_packets(options.sharedPackets == "off");
  // A number here; auto is filled in at the handshake, from where processes run.
  if (const auto gap = parseNeedGapSplats(options.needGap)) settings.set_need_gap_splats(*gap);
  // A number here; auto is filled in at the handshake, from every process's host.
  if (const float share = parseRenderCoreShare(options.renderCoreShare); share > 0.0f) {
    for (std::uint32_t render = 0; render < layout.render; ++render) {
      settings.add_render_core_share(share);
    }
  }
  settings.set_unlit(options.view.unlit);
  settings.set_renderer(parseRenderer(options.view.renderer));
  (void)resolveRenderer(settings.renderer(), settings.mode());  // a mismatch fails here
  checkViewEdl(options.view);
  if (options.view.edl) {
    settings.set_edl(true);
    settings.set_edl_strength(options.view.edlStrength);
    settings.set_edl_radius(options.view.edlRadius);
  }
  setLiveness(settings, options.liveness);
  if (manifest != nullptr && settings.mode() == v1::RENDER_MODE_INSTANCED)
    checkInstancedSections(settings, options.datasetPath);
  if (manifest != nullptr && settings.mode() == v1::RENDER_MODE_STATISTICAL)
    checkStatisticalHierarchy(settings, options.datasetPath);
  return settings;
}

// A process the job cannot go on without is gone.
class JobCannotGoOnError : public Error {
 public:
  using Error::Error;
  const char* kind() const noexcept override { return "lost process"; }
};

class DisplayProcess {
 public:
  DisplayProcess(Job& job, const DisplayOptions& options)
      : job_(job),
        options_(options),
        dataset_(Dataset::open(options.datasetPath, DatasetParts::Manifest)),
        selfKill_(options.common, job) {
    const auto [width, height] = parseImageSize(options.view.size);
    width_ = width;
    height_ = height;
    // Fail before rendering, not after, when the outputs cannot be written.
    if (!options.outDir.empty()) std::filesystem::create_directories(options.outDir);
    if (const auto folder = std::filesystem::path(options.statsFile).parent_path();
        !folder.empty()) {
      std::filesystem::create_directories(folder);
    }
    config_.bounds = datasetBounds(dataset_.manifest());
    if (!options.serve) config_.cameras = viewCameras(options.view, config_.bounds);
    // The manifest carries the root's largest splat radius, so cells.bin stays unread here.
    config_.marginWorld = dataset_.manifest().maxSplatRadius * options.view.sizeScale;
    config_.framesInFlight = options.framesInFlight;
    config_.tileTimeout =
        std::chrono::milliseconds(static_cast<long>(options.tileTimeoutSeconds * 1000.0));
    config_.maxAttempts = options.maxAttempts;
    config_.plan = tilePlanOptions(options, job.layout().render);
    config_.prefetchFrames = options.prefetchFrames;
    config_.run = runSettings(options, &dataset_.manifest(), job.layout());
    // Served frames come at the clients' pace: their rate says nothing of the part size.
    config_.tunePartSize = !options.serve;
    config_.tuneTileCount = !options.serve && !options.tilesPerRenderGiven;
  }

  const DatasetManifest& manifest() const { return dataset_.manifest(); }

  // What a client sees of the dataset and the job (no paths on this machine).
  service::ServedDataset servedDataset() const {
    const DatasetManifest& manifest = dataset_.manifest();
    service::ServedDataset served;
    served.bounds = config_.bounds;
    served.up = parseUpAxis(options_.view.up, config_.bounds);
    served.run = runSettings(options_, &dataset_.manifest(), job_.layout());
    service::v1::DatasetInfo& info = served.info;
    info.set_name(
        std::filesystem::path(options_.datasetPath).lexically_normal().filename().string());
    const auto vec = [](service::v1::Vec3* out, const glm::vec3& v) {
      out->set_x(v.x);
      out->set_y(v.y);
      out->set_z(v.z);
    };
    vec(info.mutable_bounds_min(), config_.bounds.min);
    vec(info.mutable_bounds_max(), config_.bounds.max);
    vec(info.mutable_default_up(), served.up);
    info.set_points(manifest.pointCount);
    info.set_level_splats(manifest.levelSplatCount);
    info.set_cells(manifest.cellCount);
    info.set_top_level_cells(static_cast<std::uint32_t>(manifest.topLevelCount));
    // The modes a client may switch to (set_options): those this job's
    // renderer draws and, with EDL, shades.
    for (const v1::RenderMode mode :
         {v1::RENDER_MODE_POINTS, v1::RENDER_MODE_SPLATS, v1::RENDER_MODE_BLENDED,
          v1::RENDER_MODE_INSTANCED, v1::RENDER_MODE_STATISTICAL}) {
      v1::FrameSettings frame;
      frame.set_mode(mode);
      try {
        checkFrameSettings(served.run, frame);
        info.add_modes_available(renderModeName(mode));
      } catch (const UsageError&) {
      }
    }
    info.set_mode(options_.view.mode);
    info.set_lod_pixels(options_.view.lodPixels);
    info.set_scheduler(options_.scheduler);
    info.set_layout(job_.layout().toString());
    for (const auto& name : builtinCameraPaths()) info.add_camera_paths(name);
    return served;
  }

  service::ServiceOptions serviceOptions() const {
    service::ServiceOptions service;
    service.listen = options_.listen;
    service.streamListen = options_.streamListen;
    service.maxClients = options_.maxClients;
    service.streamHighWaterMark = options_.streamHighWaterMark;
    service.maxEncodeBacklog = std::max<std::size_t>(2, options_.framesInFlight + 1);
    service.defaultFormat.set_width(width_);
    service.defaultFormat.set_height(height_);
    service.defaultFormat.set_encoding(service::parseEncoding(options_.encoding));
    service.defaultFormat.set_jpeg_quality(options_.jpegQuality);
    service.curveSecretKeyFile = options_.curveSecretKey;
    service.curveAuthorizedKeysFile = options_.curveAuthorizedKeys;
    service::validateFrameFormat(service.defaultFormat, service.limits);
    return service;
  }

  // Serve mode: binds the service's sockets once every process is ready, so a
  // client's first request finds the job up.
  void openService() {
    if (!service::isLocalEndpoint(options_.listen) && options_.curveSecretKey.empty()) {
      std::fprintf(stderr,
                   "display: warning: the service listens on %s, beyond this machine, without "
                   "authentication (--curve-secret-key, --curve-authorized-keys)\n",
                   options_.listen.c_str());
    }
    RenderCacheServing cache;
    cache.interimMs = options_.interimMs.value_or(kServeInterimMs);
    cache.cache.capacity = options_.cachePoints;
    cache.cache.maxAge = options_.cacheMaxAge;
    cache.cache.depthCullFraction = options_.depthCull;
    cache.tilePriority = options_.tilePriority == "cache";
    cache.refreshMs = options_.interimRefreshMs;
    service_ = std::make_unique<ServiceFrameSource>(serviceOptions(), servedDataset(), cache);
    source_ = service_.get();
    std::printf("display: service listening on %s (frames on %s%s)\n",
                service_->frontEnd().controlEndpoint().c_str(),
                service_->frontEnd().streamEndpoint().c_str(),
                service_->frontEnd().curve() ? ", CURVE" : "");
    std::fflush(stdout);
  }

  void run() {
    const auto start = Clock::now();
    runStart_ = start;
    FrameAssembly assembly(config_, job_.peers(), start);
    RunStats& stats = assembly.stats();
    stats.dataset = options_.datasetPath;
    stats.cameraPath = source_ != nullptr ? "service" : options_.view.cameraPath;
    stats.width = width_;
    stats.height = height_;
    stats.mode = options_.view.mode;
    stats.frameLimit = options_.statsFrames;
    if (source_ == nullptr && options_.view.loops > 1) {
      stats.loopFrames = config_.cameras.size() / options_.view.loops;
    }
    stats.reserveDetail(job_.ranksOf(v1::ROLE_RENDER));
    Backoff backoff;
    CpuActivities::Meter meter(job_.activities(), "poll");
    const LivenessSettings liveness = livenessOf(job_.runSettings());
    std::vector<int> workers;
    for (v1::Role role : {v1::ROLE_TRAVERSE, v1::ROLE_DATASEND, v1::ROLE_RENDER}) {
      for (int rank : job_.ranksOf(role)) workers.push_back(rank);
    }
    PeerWatch watch(workers, liveness.peerTimeout, start);
    HeartbeatTimer heartbeat(liveness.heartbeat, start);
    HeartbeatTimer checkpoint(
        std::chrono::milliseconds(static_cast<long>(options_.checkpointSeconds * 1000.0)), start);
    sendHeartbeats(start);  // arms every process's watch of the display
    try {
      runLoop(assembly, watch, heartbeat, checkpoint, backoff, meter);
    } catch (const JobCannotGoOnError& error) {
      // What was done so far is kept: the statistics first, in case a
      // survivor takes the job down while it is being shut down.
      stats.totalSeconds = since(start, Clock::now());
      stats_ = std::move(stats);
      failure_ = error.what();
      std::fprintf(stderr, "display: %s\n", failure_.c_str());
      if (!statisticsFile().empty()) writeStatistics(stats_);
      if (service_) service_->close();
      return;
    }
    stats.totalSeconds = since(start, Clock::now());
    stats_ = std::move(stats);
    if (service_) {
      std::printf("%s", service_->renderCacheSummary().c_str());
      std::printf("display: service stopped (%s)\n", service_->stopReason().c_str());
      service_->close();
    }
  }

  // Why the job ended early (a process it cannot go on without was lost);
  // empty when it ran to the end.
  const std::string& failure() const { return failure_; }

 private:
  void sendHeartbeats(TimePoint now) {
    v1::Heartbeat beat;
    beat.set_sent_ns(now.time_since_epoch().count());
    for (v1::Role role : {v1::ROLE_TRAVERSE, v1::ROLE_DATASEND, v1::ROLE_RENDER}) {
      for (int rank : job_.ranksOf(role)) {
        if (!job_.lost(rank)) job_.sends().post(rank, MessageKind::Heartbeat, beat);
      }
    }
  }

  // A worker is gone. A render process the job can do without: its tiles go
  // to the others. Any other process, or the last render: the job ends.
  void peerLost(FrameAssembly& assembly, int rank, const std::string& reason, TimePoint now) {
    job_.markLost(rank);
    const v1::Role role = job_.roleOf(rank);
    const std::string who = job_.describeRank(rank);
    if (role == v1::ROLE_RENDER && assembly.planner().liveRenders() > 1) {
      const std::uint32_t reissued = assembly.renderLost(rank, now, reason);
      std::fprintf(stderr,
                   "display: %s lost (%s); %u tile(s) out re-issued, going on with %u render "
                   "process(es)\n",
                   who.c_str(), reason.c_str(), reissued, assembly.planner().liveRenders());
      v1::PeerLost lost;
      lost.set_world_rank(rank);
      lost.set_role(role);
      lost.set_reason(reason);
      for (v1::Role told : {v1::ROLE_TRAVERSE, v1::ROLE_DATASEND}) {
        for (int peer : job_.ranksOf(told)) job_.sends().post(peer, MessageKind::PeerLost, lost);
      }
      return;
    }
    assembly.stats().lost.push_back({roleName(role), rank, since(runStart_, now), reason, false});
    throw JobCannotGoOnError(who + " lost (" + reason + "): the job cannot go on without " +
                             (role == v1::ROLE_RENDER ? "a render process" : "it"));
  }

  void runLoop(FrameAssembly& assembly, PeerWatch& watch, HeartbeatTimer& heartbeat,
               HeartbeatTimer& checkpoint, Backoff& backoff, CpuActivities::Meter& meter) {
    RunStats& stats = assembly.stats();
    while (true) {
      bool worked = false;
      if (source_ == nullptr) {
        if (assembly.done()) break;
      } else if (source_->finished()) {
        if (assembly.framesInFlight() == 0) break;
      } else {
        const std::size_t window = std::max<std::size_t>(1, options_.framesInFlight);
        const std::size_t room = window - std::min(window, assembly.framesInFlight());
        for (const FrameRequest& frame : source_->take(room)) {
          const Camera& camera = frame.camera;
          frameSizes_[framesAppended_++] = {camera.image_width(), camera.image_height()};
          assembly.appendCamera(camera, frame.settings, frame.tilePriority);
          if (frame.settings.tile_depth()) depthFrames_.insert(framesAppended_ - 1);
          worked = true;
        }
      }
      while (true) {
        meter.switchTo("receive");
        std::optional<Envelope> envelope;
        try {
          envelope = job_.channel().tryReceive();
        } catch (const PeerSilentError& silent) {
          peerLost(assembly, silent.rank(), silent.what(), Clock::now());
          worked = true;
          continue;
        }
        if (!envelope) {
          meter.relabel("poll");
          handleBatch(assembly, meter);
          break;
        }
        worked = true;
        if (job_.lost(envelope->source)) continue;  // taken for lost: its work went elsewhere
        watch.heard(envelope->source, Clock::now());
        if (envelope->kind == MessageKind::Heartbeat) continue;
        if (envelope->kind == MessageKind::TileImage) {
          // A render process says nothing while it draws: twice its longest
          // tile so far is not silence.
          const auto drawn = envelope->as<v1::TileImageHeader>().render_time_us();
          watch.allowSilence(envelope->source,
                             std::chrono::milliseconds(std::max<std::int64_t>(0, drawn / 500)));
        }
        // Compressed tile images wait for the messages right behind them,
        // then expand on several threads together; everything is handled in
        // the order it came.
        if (envelope->kind == MessageKind::TileImage &&
            envelope->as<v1::TileImageHeader>().compressed_bytes() != 0) {
          batch_.push_back({std::move(*envelope), {}, {}});
          if (batch_.size() >= kImageBatch) handleBatch(assembly, meter);
          continue;
        }
        handleBatch(assembly, meter);
        meter.switchTo(std::string("handle ") + messageKindName(envelope->kind));
        handle(assembly, *envelope);
      }
      meter.switchTo("liveness");
      const TimePoint now = Clock::now();
      for (int rank : watch.newlyLost(now)) {
        peerLost(assembly, rank, silenceText(watch.silentSeconds(rank, now)), now);
        worked = true;
      }
      if (heartbeat.due(now)) sendHeartbeats(now);
      if (checkpoint.due(now) && !statisticsFile().empty()) {
        meter.switchTo("checkpoint");
        stats.totalSeconds = secondsBetween(runStart_, now);
        writeStatistics(stats);
      }
      meter.switchTo("schedule");
      Outbox out;
      const std::uint32_t requeued = assembly.dispatch(Clock::now(), out);
      if (requeued > 0) {
        std::fprintf(stderr, "display: %u tile(s) did not come back in %.1f s; re-issued\n",
                     requeued, options_.tileTimeoutSeconds);
      }
      worked = worked || requeued > 0 || !out.empty();
      meter.switchTo("send");
      job_.sends().post(out);
      job_.sends().reap();
      // After the new frames' tiles went out: a reprojection here runs while
      // they are drawn.
      if (source_ != nullptr) {
        meter.switchTo("frame source");
        source_->poll();
      }
      meter.switchTo("finish frames");
      for (FinishedFrame& frame : assembly.finishFrames(Clock::now())) {
        emit(frame);
        selfKill_.count();
        worked = true;
      }
      if (worked) {
        backoff.reset();
      } else {
        meter.relabel("poll");
        backoff.wait();
      }
    }
  }

 public:
  // After shutdown, with every process's CPU time: the summary and the files.
  void report(const std::vector<v1::ShutdownAck>& acks, const ProcessCpu& display) {
    stats_.processes.push_back(display);
    for (const auto& ack : acks) {
      ProcessCpu process{roleName(ack.role()),
                         ack.world_rank(),
                         ack.cpu_seconds_since_ready(),
                         ack.wall_seconds_since_ready(),
                         {}};
      for (const auto& [activity, seconds] : ack.cpu_seconds_by_activity()) {
        process.activities[activity] = seconds;
      }
      stats_.processes.push_back(std::move(process));
    }
    std::printf("%s", stats_.summary().c_str());
    if (const std::string file = statisticsFile(); !file.empty()) {
      writeStatistics(stats_);
      std::printf("display: statistics in %s and the CSV files beside it\n", file.c_str());
    }
    std::fflush(stdout);
  }

  std::string statisticsFile() const {
    return !options_.statsFile.empty() ? options_.statsFile
           : !options_.outDir.empty()  ? options_.outDir + "/stats.json"
                                       : std::string();
  }

  // Every write replaces the files whole (a rename), so a display that dies
  // between checkpoints leaves the last one intact.
  void writeStatistics(const RunStats& stats) const {
    const std::filesystem::path file = statisticsFile();
    stats.writeJson(file);
    const auto csvDir = file.parent_path();
    stats.writeCsv(csvDir.empty() ? std::filesystem::path(".") : csvDir);
  }

 private:
  // The compressed tile images received, expanded on the pool's threads
  // (a bad one keeps its error for its turn), then handled in order.
  void handleBatch(FrameAssembly& assembly, CpuActivities::Meter& meter) {
    if (batch_.empty()) return;
    meter.switchTo("expand images");
    if (batch_.size() > 1 && !imagePool_) {
      unsigned threads = options_.imageThreads;
      if (threads == 0) threads = std::clamp(std::thread::hardware_concurrency(), 1u, 8u);
      imagePool_ = std::make_unique<TaskPool>(threads);
    }
    const auto expand = [&](std::size_t i) {
      PendingImage& image = batch_[i];
      try {
        const auto header = image.envelope.as<v1::TileImageHeader>();
        (void)tileImagePayload(header, image.envelope.payload, image.expanded,
                               image.envelope.source);
      } catch (...) {
        image.error = std::current_exception();
      }
    };
    if (imagePool_ && batch_.size() > 1) {
      imagePool_->run(batch_.size(), expand);
    } else {
      for (std::size_t i = 0; i < batch_.size(); ++i) expand(i);
    }
    meter.switchTo("handle TileImage");
    // Taken out first: handling may end the run, or throw.
    std::vector<PendingImage> batch = std::move(batch_);
    batch_.clear();
    for (PendingImage& image : batch) {
      if (job_.lost(image.envelope.source)) continue;  // taken for lost since it came
      if (image.error) std::rethrow_exception(image.error);
      handle(assembly, image.envelope, &image.expanded);
    }
  }

  // `inflated`: the payload of a compressed tile image, expanded and checked already.
  void handle(FrameAssembly& assembly, Envelope& envelope,
              std::vector<std::byte>* inflated = nullptr) {
    switch (envelope.kind) {
      case MessageKind::WorkRequest:
        assembly.workRequested(envelope.source, envelope.as<v1::WorkRequest>());
        break;
      case MessageKind::TileImage: {
        const auto header = envelope.as<v1::TileImageHeader>();
        const v1::TileRect& rect = header.rect();
        std::vector<std::byte> decompressed;
        const std::span<const std::byte> payload =
            inflated != nullptr && header.compressed_bytes() != 0
                ? std::span<const std::byte>(*inflated)
                : tileImagePayload(header, envelope.payload, decompressed, envelope.source);
        const std::uint64_t pixelBytes =
            tileImagePixelBytes(header, payload.size(), envelope.source);
        const bool withDepth = header.depth() == v1::DEPTH_FORMAT_EYE_FLOAT32;
        const TileArrival arrival = assembly.tileArrived(header, Clock::now());
        if (arrival == TileArrival::Late) return;
        const auto* bytes = reinterpret_cast<const std::uint8_t*>(payload.data());
        std::vector<std::byte> expanded;
        const std::span<const std::byte> pixels =
            tileImagePixels(header, payload, pixelBytes, expanded);
        std::vector<std::uint8_t> composed;
        if (header.format() == v1::PIXEL_FORMAT_POINT_WORDS64) {
          parts_.merge(header.frame_id(), header.tile_id(), header.attempt(), rect,
                       header.has_drawn_rect() ? header.drawn_rect() : rect, pixels);
          if (arrival == TileArrival::Part) return;
          composed = parts_.take(header.frame_id(), header.tile_id(), header.attempt(),
                                 packRgba(kBackground));
        }
        auto image = images_.find(header.frame_id());
        if (image == images_.end()) {
          image = images_.emplace(header.frame_id(), blankImage(header.frame_id())).first;
        }
        // A background tile leaves the blank image and +infinity depth as
        // they are; a whole tile's drawn box leaves them around it.
        if (!composed.empty()) {
          blit(composed, rect.width(), rect.height(), image->second, rect.x(), rect.y());
        } else if (header.format() != v1::PIXEL_FORMAT_BACKGROUND) {
          const v1::TileRect& drawn = header.has_drawn_rect() ? header.drawn_rect() : rect;
          if (drawn.width() > 0 && drawn.height() > 0)
            blit(std::span<const std::uint8_t>(reinterpret_cast<const std::uint8_t*>(pixels.data()),
                                               pixels.size()),
                 drawn.width(), drawn.height(), image->second, drawn.x(), drawn.y());
        }
        if (withDepth && depthFrames_.contains(header.frame_id())) {
          composeDepth(header.frame_id(), image->second, rect, bytes + pixelBytes);
        }
        if (source_ != nullptr) {
          const auto [done, tiles] = assembly.tileProgress(header.frame_id());
          source_->tileComposed({header.frame_id(), rect, done, tiles}, image->second);
        }
        break;
      }
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

  void emit(const FinishedFrame& frame) {
    const FrameRecord& record = frame.record;
    const auto found = images_.find(record.frame);
    Image image = found != images_.end() ? std::move(found->second) : blankImage(record.frame);
    if (found != images_.end()) images_.erase(found);
    parts_.dropFrame(record.frame);
    for (const TileRect& rect : frame.failedTiles) {
      for (std::uint32_t y = 0; y < rect.height(); ++y) {
        for (std::uint32_t x = 0; x < rect.width(); ++x) {
          image.set(rect.x() + x, rect.y() + y, kFailedTile);
        }
      }
    }
    if (!options_.outDir.empty()) {
      char name[64];
      std::snprintf(name, sizeof name, "frame_%05llu.png",
                    static_cast<unsigned long long>(record.frame));
      writePng(image, std::filesystem::path(options_.outDir) / name, true);
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
      std::string holders;
      for (const int rank : frame.failedTileRenders) {
        holders += (holders.empty() ? "" : ", ") + std::to_string(rank);
      }
      if (!holders.empty()) {
        holders = (frame.failedTileRenders.size() == 1 ? ", last sent to render rank "
                                                       : ", last sent to render ranks ") +
                  holders;
      }
      std::fprintf(stderr,
                   "display: frame %llu: %u tile(s) never arrived after %u attempt%s%s (drawn "
                   "magenta)\n",
                   static_cast<unsigned long long>(record.frame), record.failedTiles,
                   options_.maxAttempts, options_.maxAttempts == 1 ? "" : "s", holders.c_str());
    }
    if (source_ != nullptr) {
      frameSizes_.erase(record.frame);
      std::vector<float> depth;
      if (depthFrames_.erase(record.frame) > 0) {
        const auto composed = depths_.find(record.frame);
        // No tile at all (nothing in view): background everywhere.
        depth = composed != depths_.end()
                    ? std::move(composed->second)
                    : std::vector<float>(static_cast<std::size_t>(image.width()) * image.height(),
                                         std::numeric_limits<float>::infinity());
        if (composed != depths_.end()) depths_.erase(composed);
      }
      source_->frameDone(frame, std::move(image), std::move(depth));
    } else if (spareImages_.size() <= options_.framesInFlight) {
      spareImages_.push_back(std::move(image));
    }
  }

  // A tile's eye-space depth into its frame's depth image (+infinity where
  // no tile drew), rows bottom-up as the pixels.
  void composeDepth(std::uint64_t frame, const Image& image, const v1::TileRect& rect,
                    const std::uint8_t* depthBytes) {
    auto found = depths_.find(frame);
    if (found == depths_.end()) {
      found = depths_
                  .emplace(frame, std::vector<float>(
                                      static_cast<std::size_t>(image.width()) * image.height(),
                                      std::numeric_limits<float>::infinity()))
                  .first;
    }
    const std::size_t rowBytes = static_cast<std::size_t>(rect.width()) * sizeof(float);
    for (std::uint32_t row = 0; row < rect.height(); ++row) {
      std::memcpy(found->second.data() + static_cast<std::size_t>(rect.y() + row) * image.width() +
                      rect.x(),
                  depthBytes + row * rowBytes, rowBytes);
    }
  }

  // A frame-sized image of the background. Finished frames' images are kept
  // for reuse: a fresh 1280x720 allocation per frame costs the display more
  // page faults than its compositing.
  Image blankImage(std::uint64_t frame) {
    // Served frames each have the size their client asked for.
    if (const auto size = frameSizes_.find(frame); size != frameSizes_.end()) {
      return Image(size->second.first, size->second.second, kBackground);
    }
    if (spareImages_.empty()) return Image(width_, height_, kBackground);
    Image image = std::move(spareImages_.back());
    spareImages_.pop_back();
    image.fill(kBackground);
    return image;
  }

  struct PendingImage {
    Envelope envelope;
    std::vector<std::byte> expanded;
    std::exception_ptr error;
  };
  // Compressed tile images expanded together at most this many at a time:
  // enough for every thread, few enough not to hold the first one long.
  static constexpr std::size_t kImageBatch = 64;

  Job& job_;
  DisplayOptions options_;
  std::vector<PendingImage> batch_;
  std::unique_ptr<TaskPool> imagePool_;
  Dataset dataset_;
  FrameAssemblyConfig config_;
  TimePoint runStart_{};
  std::string failure_;
  SelfKill selfKill_;  // test hook: counts finished frames
  std::uint32_t width_ = 0;
  std::uint32_t height_ = 0;
  RunStats stats_;
  std::map<std::uint64_t, Image> images_;  // frames with tiles composed so far
  TilePartCompositor parts_;               // split tiles' parts so far
  std::vector<Image> spareImages_;
  std::unique_ptr<ServiceFrameSource> service_;
  FrameSource* source_ = nullptr;  // serve mode; the fixed path otherwise
  // Served frames' sizes until they are emitted, by frame number.
  std::map<std::uint64_t, std::pair<std::uint32_t, std::uint32_t>> frameSizes_;
  std::uint64_t framesAppended_ = 0;
  // Served frames whose tiles carry depth (the render cache), and their
  // depth images so far.
  std::set<std::uint64_t> depthFrames_;
  std::map<std::uint64_t, std::vector<float>> depths_;
};

void stayIdle(double seconds) {
  if (seconds <= 0.0) return;
  std::this_thread::sleep_for(std::chrono::duration<double>(seconds));
}

}  // namespace

int runDisplayMain(int argc, char** argv) {
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
  app.add_option("--stats-frames", options.statsFrames,
                 "Per-frame records kept in the statistics; past it they thin evenly "
                 "(the run's figures stay exact; 0 keeps every frame)");
  app.add_option("--frames-in-flight", options.framesInFlight, "Frames handed out at once");
  app.add_option("--image-threads", options.imageThreads,
                 "Threads expanding compressed tile images (the renders' --image-compression) "
                 "that arrive together; 0: this machine's cores, at most 8")
      ->check(CLI::Range(0, 64));
  app.add_option("--tiles-per-render", options.tilesPerRender,
                 "Mini frusta per frame per render process (default 2; with the cost scheduler "
                 "divided by 1, 2, 4, ... as the frame rate says: fewer tiles are tried while "
                 "they make frames faster; given: as given)");
  app.add_option("--min-tile", options.minTileSize, "Smallest tile side in pixels");
  app.add_option("--tile-timeout", options.tileTimeoutSeconds,
                 "Seconds before a missing tile is handed out again");
  app.add_option("--max-attempts", options.maxAttempts,
                 "Times a tile is handed out before it is given up");
  app.add_option_function<double>(
         "--heartbeat",
         [&](double seconds) {
           options.liveness.heartbeat = std::chrono::milliseconds(std::lround(seconds * 1000.0));
         },
         "Seconds between heartbeats of the display and every process (default 1)")
      ->check(CLI::Range(0.01, 60.0));
  app.add_option_function<double>(
         "--peer-timeout",
         [&](double seconds) {
           options.liveness.peerTimeout = std::chrono::milliseconds(std::lround(seconds * 1000.0));
         },
         "Seconds of silence after which a process is lost (default 5): a lost render process's "
         "tiles go to the others and the job goes on (mpirun --enable-recovery, as deploy/run.sh "
         "starts it); any other lost process ends the job")
      ->check(CLI::Range(0.1, 3600.0));
  app.add_option("--checkpoint-seconds", options.checkpointSeconds,
                 "Write the statistics so far this often during the run (0: only at the end)")
      ->capture_default_str();
  app.add_option("--scheduler", options.scheduler,
                 "How tiles are given to render processes: cost (seed 003), regions (one "
                 "screen region per render, cut by last frame's work), round-robin, static, "
                 "equalizer");
  app.add_option("--tile-tasks-ahead", options.tileTasksAhead,
                 "Tile requests each traverse process keeps at the display (1: one at a time; "
                 "auto: " +
                     autoTileTasksAheadRule() +
                     ", so short walks do not wait a request's round trip)")
      ->capture_default_str();
  app.add_option("--render-core-share", options.renderCoreShare,
                 "Cost scheduler: how much a render process's queue counts against moving data "
                 "to another (auto: the share of a core each job process has on its machine, "
                 "at most 1; 1: each render its own node, as seed 003 writes the cost)")
      ->capture_default_str();
  app.add_option("--tile-split", options.tileSplit,
                 "Cost and regions schedulers, points drawn by the cpu kernel without EDL: a tile "
                 "whose walk draws at least twice the part size is split by its cells into parts "
                 "drawn by several render processes and composed by depth here (exact). auto: "
                 "only tiles too small to cut further, parts of one render's share of last "
                 "frame's splats, at least " +
                     std::to_string(kDefaultMinTilePartSplats) +
                     ", times a factor tuned on the frame rate (1, 2, 4, ...: larger parts are "
                     "tried while they make frames faster); share: that share, not tuned; off; "
                     "or a part size in splats for every tile")
      ->capture_default_str();
  app.add_option("--cost-model", options.costModel,
                 "Cost scheduler: paper (seed 003: transfer time adds to the queue, default) or "
                 "overlap (transfers overlap queued work)");
  app.add_option("--prefetch-frames", options.prefetchFrames,
                 "Cost scheduler: order the data each tile's rect needs this many frames on "
                 "(0: no prefetch)");
  app.add_option("--shared-packets", options.sharedPackets,
                 "on: render processes read data packets in place from the memory of a "
                 "data-send process on their machine (common/shared_packets.hpp); off: every "
                 "packet is copied through MPI")
      ->check(CLI::IsMember({"on", "off"}))
      ->capture_default_str();
  app.add_option("--need-gap", options.needGap,
                 "Drawn ranges of a packet at most this many splats apart are needed and sent "
                 "as one range; auto: " +
                     std::to_string(kNeedGapSplatsInPlace) +
                     " where every render process reads packets in place on its machine, else " +
                     std::to_string(kNeedGapSplatsCopied))
      ->capture_default_str();
  app.add_flag("--equal-tiles", options.equalTiles,
               "Cost scheduler: equal tiles instead of tiles sized by last frame's work");
  app.add_flag("--quiet", options.quiet, "No per-frame lines");
  app.add_flag("--serve", options.serve,
               "Serve mode: render frames clients ask for over ZeroMQ until a shutdown request, "
               "SIGINT or SIGTERM (instead of --camera-path)");
  app.add_option("--listen", options.listen,
                 "Serve mode: control endpoint (loopback by default); frames on the next port")
      ->capture_default_str();
  app.add_option("--stream-listen", options.streamListen,
                 "Serve mode: frames endpoint (default: --listen's port + 1)");
  app.add_option("--max-clients", options.maxClients, "Serve mode: clients known at once")
      ->capture_default_str();
  app.add_option("--stream-hwm", options.streamHighWaterMark,
                 "Serve mode: frames queued for one client before its frames are dropped")
      ->capture_default_str();
  app.add_option("--encoding", options.encoding,
                 "Serve mode: clients' default encoding: raw, png, jpeg")
      ->capture_default_str();
  app.add_option("--jpeg-quality", options.jpegQuality, "Serve mode: clients' default JPEG quality")
      ->check(CLI::Range(1, 100))
      ->capture_default_str();
  app.add_option("--curve-secret-key", options.curveSecretKey,
                 "Serve mode: CURVE: the server's secret key file (pointillist-client keygen)");
  app.add_option("--curve-authorized-keys", options.curveAuthorizedKeys,
                 "Serve mode: CURVE: file of client public keys admitted, one per line");
  app.add_option("--interim-ms", options.interimMs,
                 "Serve mode: render cache (seed 001): a client's new camera gets an interim "
                 "frame reprojected from its earlier frames when the final one is not composed "
                 "this many ms after it started (default 0: at once); negative: no render cache");
  app.add_option("--interim-refresh-ms", options.interimRefreshMs,
                 "Serve mode: after the interim frame, send it again with the tiles that came "
                 "since pasted in (exact there), at most this often (0: as they come), until the "
                 "final frame; negative: one interim frame. Each costs an encode")
      ->capture_default_str();
  app.add_option("--cache-points", options.cachePoints,
                 "Serve mode: points each client's render cache holds (default: twice the "
                 "frame's pixels)");
  app.add_option("--cache-max-age", options.cacheMaxAge,
                 "Serve mode: final frames a cached point survives unseen")
      ->capture_default_str()
      ->check(CLI::Range(1, 250));
  app.add_option("--depth-cull", options.depthCull,
                 "Serve mode: render cache depth cull threshold, relative to the filtered depth")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  app.add_option("--tile-priority", options.tilePriority,
                 "Serve mode: cache: a new camera is reprojected before its tiles go out, and "
                 "the tiles the render cache could not fill go first (seed 001); none: the "
                 "tiles go out at once and the reprojection runs while they are drawn (the "
                 "final frame comes sooner)")
      ->capture_default_str()
      ->check(CLI::IsMember({"cache", "none"}));
  return runRoleMain(argc, argv, v1::ROLE_DISPLAY, app, [&](Job& job) {
    const auto start = Clock::now();
    options.tilesPerRenderGiven = app.count("--tiles-per-render") > 0;
    std::unique_ptr<DisplayProcess> process;
    if (options.serve && options.datasetPath.empty()) {
      throw UsageError("--serve needs --dataset: clients render the dataset the job starts with");
    }
    if (!options.datasetPath.empty()) process = std::make_unique<DisplayProcess>(job, options);
    HandshakeOptions handshake = handshakeOptions(options.common);
    handshake.settings =
        runSettings(options, process ? &process->manifest() : nullptr, job.layout());
    job.handshake(handshake);
    const auto ready = job.awaitReady(std::chrono::milliseconds(
        static_cast<long>(options.common.handshakeTimeoutSeconds * 1000.0)));
    std::printf("display: job %s ready (%zu peers) in %.2f s\n", job.layout().toString().c_str(),
                ready.size(), since(start, Clock::now()));
    const auto& shares = job.runSettings().render_core_share();
    if (!shares.empty() && *std::min_element(shares.begin(), shares.end()) < 1.0f) {
      const auto [least, most] = std::minmax_element(shares.begin(), shares.end());
      char weight[64];
      std::snprintf(weight, sizeof weight, *most > *least ? "%.2g-%.2g" : "%.2g",
                    static_cast<double>(*least), static_cast<double>(*most));
      std::printf(
          "display: processes outnumber cores: render queues count at %s of their time (a "
          "core's share each), so tiles stay with their data\n",
          weight);
    }
    for (const auto& peer : ready) {
      if (!peer.detail().empty() && !options.quiet) {
        std::printf("  %s rank %d: %s\n", executableName(peer.role()).c_str(), peer.world_rank(),
                    peer.detail().c_str());
      }
    }
    std::fflush(stdout);
    if (options.serve) process->openService();

    const double displayCpuBefore = processCpuSeconds();
    const auto displayStart = Clock::now();
    if (process) {
      process->run();
    } else {
      stayIdle(options.idleSeconds);
    }
    const double displayCpu = processCpuSeconds() - displayCpuBefore;
    const double displayWall = since(displayStart, Clock::now());

    const bool failed = process && !process->failure().empty();
    if (failed) {
      // The survivors are told at once and given little time: the job must
      // end promptly, and one that does not answer ends itself once the
      // display is gone (it watches the display's heartbeat).
      const double seconds = std::min(options.shutdownTimeoutSeconds, 3.0);
      const std::vector<int> silent = job.shutdownSurvivors(
          "a process was lost", std::chrono::milliseconds(static_cast<long>(seconds * 1000.0)));
      for (int rank : silent) {
        std::fprintf(stderr, "display: %s did not acknowledge shutdown within %.0f s\n",
                     job.describeRank(rank).c_str(), seconds);
      }
    } else {
      job.shutdownAll(
          "job complete",
          std::chrono::milliseconds(static_cast<long>(options.shutdownTimeoutSeconds * 1000.0)));
    }
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
    if (process) {
      process->report(job.lastAcks(), {"display", job.worldRank(), displayCpu, displayWall,
                                       job.activities().totals()});
    }
    if (failed) {
      std::fprintf(stderr, "pointillist-display rank %d: lost process: %s\n", job.worldRank(),
                   process->failure().c_str());
      return 4;
    }
    return 0;
  });
}

}  // namespace pointillist::display
