#include "display/core/frame_assembly.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <numeric>

#include "common/image.hpp"
#include "common/image_compression.hpp"
#include "common/pixel_runs.hpp"
#include "common/run_settings.hpp"
#include "display/core/tiling.hpp"

namespace pointillist::display {

FrameAssembly::FrameAssembly(FrameAssemblyConfig config, PeerRanks peers, TimePoint start)
    : config_(std::move(config)),
      peers_(std::move(peers)),
      start_(start),
      frames_(config_.framesInFlight, config_.tileTimeout, config_.maxAttempts),
      planner_(config_.plan),
      runScheduler_(config_.plan.scheduler) {
  stats_.layout = peers_.layout().toString();
  const bool splitting = config_.plan.scheduler == SchedulerKind::Cost ||
                         config_.plan.scheduler == SchedulerKind::Regions;
  tunePartSize_ = config_.tunePartSize && splitting && config_.run.tile_part_splats() == 0 &&
                  !config_.run.tile_part_untuned() &&
                  tileSplitAllowed(config_.run, v1::FrameSettings());
  partTuner_ = FrameRateTuner(config_.partTuning);
  tuneTileCount_ = config_.tuneTileCount && config_.plan.scheduler == SchedulerKind::Cost &&
                   config_.plan.balancedTiles;
  tileTuner_ = FrameRateTuner(config_.tileTuning);
  admitFrames();
}

namespace {

// "0.5 per render process by the frame rate (2: 371.1, 1: 405.2, 0.5: 401.3
// frames/s; 3 trials)".
std::string tileCountSummary(double perRender, const FrameRateTuner& tuner) {
  const auto perRenderAt = [perRender](std::uint64_t divisor) {
    char text[32];
    std::snprintf(text, sizeof text, "%g", perRender / static_cast<double>(divisor));
    return std::string(text);
  };
  return perRenderAt(tuner.factor()) + " per render process by the frame rate (" +
         tuner.ratesText([&](std::uint64_t divisor) { return perRenderAt(divisor) + ": "; }) + ")";
}

}  // namespace

// Frames are laid out when they enter the window, so a re-split from the last
// completed frame applies to the next one.
void FrameAssembly::admitFrames() {
  while (framesAdded_ < config_.cameras.size() &&
         framesAdded_ < stats_.frameCount() + std::max<std::uint32_t>(1, config_.framesInFlight)) {
    const std::uint64_t index = framesAdded_++;
    const Camera& camera = config_.cameras[index];
    if (const auto settings = frameSettings_.find(index);
        settings != frameSettings_.end() && settings->second.has_scheduler()) {
      planner_.setScheduler(schedulerKindOf(settings->second.scheduler()));
    }
    // The tuners take turns: a trial starts only while the other measures nothing.
    if (tuneTileCount_) tileTuner_.frameAdmitted(index, !partTuner_.measuring());
    if (tunePartSize_) partTuner_.frameAdmitted(index, !tileTuner_.measuring());
    std::vector<TileRect> tiles;
    if (const auto area =
            boxOfInterest(camera, config_.bounds.min, config_.bounds.max, config_.marginWorld)) {
      const auto planning = Clock::now();
      tiles = planner_.plan(*area, tuneTileCount_ ? tileTuner_.factorFor(index) : 1);
      stats_.planSeconds += secondsBetween(planning, Clock::now());
    }
    std::vector<std::uint32_t> order;
    if (const auto priority = tilePriority_.find(index); priority != tilePriority_.end()) {
      std::vector<double> value(tiles.size());
      for (std::size_t i = 0; i < tiles.size(); ++i) value[i] = priority->second(tiles[i]);
      order.resize(tiles.size());
      std::iota(order.begin(), order.end(), 0u);
      std::stable_sort(order.begin(), order.end(),
                       [&](std::uint32_t a, std::uint32_t b) { return value[a] > value[b]; });
      tilePriority_.erase(priority);
    }
    if (!planner_.homes().empty()) homes_[index] = planner_.homes();
    feedback_[index].assign(tiles.size(), TileFeedback{});
    frames_.addFrame(index, camera, std::move(tiles), std::move(order));
  }
}

void FrameAssembly::appendCamera(const Camera& camera, const v1::FrameSettings& settings,
                                 TilePriority priority) {
  if (settings.ByteSizeLong() > 0) frameSettings_[config_.cameras.size()] = settings;
  if (priority) tilePriority_[config_.cameras.size()] = std::move(priority);
  config_.cameras.push_back(camera);
  admitFrames();
}

void FrameAssembly::workRequested(int traverseRank, const v1::WorkRequest& request) {
  peers_.indexOf(v1::ROLE_TRAVERSE, traverseRank);  // throws for a stranger
  for (const v1::TilePlacement& placement : request.placements()) {
    if (placement.render() >= peers_.renders.size()) {
      throw ProtocolError("traverse rank " + std::to_string(traverseRank) + " placed tile " +
                          std::to_string(placement.tile_id()) + " on render " +
                          std::to_string(placement.render()) + " of " +
                          std::to_string(peers_.renders.size()));
    }
    frames_.tilePlaced(placement.frame_id(), placement.tile_id(), placement.attempt(),
                       placement.render());
  }
  idleTraverses_.push_back(traverseRank);
}

std::uint32_t FrameAssembly::dispatch(TimePoint now, Outbox& out) {
  const std::uint32_t requeued = frames_.checkTimeouts(now);
  const std::vector<std::uint32_t> suspects = frames_.suspectRenders(now);
  while (!idleTraverses_.empty()) {
    const auto task = frames_.nextTask(now);
    if (!task) break;
    const FrameState* state = frames_.frame(task->frame);
    v1::TileTask message;
    message.set_frame_id(task->frame);
    message.set_tile_id(task->tile);
    *message.mutable_camera() = state->camera;
    *message.mutable_rect() = state->tiles.at(task->tile).rect;
    message.set_timestamp_ns(
        std::chrono::duration_cast<std::chrono::nanoseconds>(now.time_since_epoch()).count());
    message.set_attempt(task->attempt);
    // The scheduler in force now is the one assign() below follows.
    const SchedulerKind scheduler = planner_.options().scheduler;
    if (const auto settings = frameSettings_.find(task->frame); settings != frameSettings_.end()) {
      *message.mutable_frame_settings() = settings->second;
      message.mutable_frame_settings()->clear_scheduler();
    }
    if (scheduler != runScheduler_) {
      message.mutable_frame_settings()->set_scheduler(schedulerMessage(scheduler));
    }
    const bool choosesByCost =
        scheduler == SchedulerKind::Cost || scheduler == SchedulerKind::Regions;
    if (choosesByCost && config_.prefetchFrames > 0 &&
        task->frame + config_.prefetchFrames < config_.cameras.size()) {
      *message.mutable_lookahead_camera() = config_.cameras[task->frame + config_.prefetchFrames];
    }
    // Assigned as the tile is handed out: round-robin deals in that order.
    // A region's render was fixed when the frame was planned.
    const auto homes = homes_.find(task->frame);
    message.set_assigned_render(homes != homes_.end() ? homes->second.at(task->tile)
                                                      : planner_.assign(task->tile).value_or(0));
    message.set_part_splats(partSplatsFor(task->frame, message.rect()));
    for (const std::uint32_t render : suspects) message.add_avoid_renders(render);
    if (!suspects.empty()) ++stats_.avoidingTasks;
    dispatchedAt_[{task->frame, task->tile}] = since(now);
    out.send(idleTraverses_.front(), std::move(message));
    idleTraverses_.pop_front();
  }
  // Spans when tiles wait for a traverse to ask: the traverses (walks or
  // request round trips) hold the frames there.
  if (tilesWaitForRequests()) {
    if (requestWaitSince_ < 0.0) requestWaitSince_ = since(now);
  } else if (requestWaitSince_ >= 0.0) {
    requestWaitSeconds_ += since(now) - requestWaitSince_;
    requestWaitSince_ = -1.0;
    stats_.requestWaitSeconds = requestWaitSeconds_;
  }
  return requeued;
}

TileArrival FrameAssembly::tileArrived(const v1::TileImageHeader& header, TimePoint now) {
  if (header.format() == v1::PIXEL_FORMAT_BACKGROUND) return backgroundArrived(header, now);
  const int render = header.render_rank();
  frames_.renderAnswered(static_cast<std::uint32_t>(
      peers_.indexOf(v1::ROLE_RENDER, render)));  // throws for a stranger
  const bool part = header.part_count() > 1;
  if (part && header.part_index() >= header.part_count()) {
    throw ProtocolError("tile image from rank " + std::to_string(render) + " is part " +
                        std::to_string(header.part_index()) + " of " +
                        std::to_string(header.part_count()));
  }
  RenderSample sample;
  sample.seconds = since(now);
  sample.frame = header.frame_id();
  sample.workloadSplats = header.workload_splats();
  sample.cacheBytes = header.cache_bytes();
  sample.peakCacheBytes = header.peak_cache_bytes();
  sample.cacheHits = header.cache_hits();
  sample.cacheMisses = header.cache_misses();
  sample.evictions = header.evictions();
  sample.dataBytesReceived = header.data_bytes_received();
  stats_.addRenderSample(render, sample);

  const TileRecord tile = recordTile(header, render, /*keepDispatch=*/part, now);

  if (!frames_.tileWaiting(header.frame_id(), header.tile_id(), header.rect())) {
    ++stats_.lateTiles;
    return TileArrival::Late;
  }
  std::uint64_t tileSplats = header.splats_rendered();
  double tileSeconds = tile.renderSeconds;
  if (part) {
    const auto key = std::make_tuple(header.frame_id(), header.tile_id(), header.attempt());
    PartsInFlight& parts = parts_[key];
    if (parts.received.empty()) {
      parts.received.assign(header.part_count(), false);
      parts.missing = header.part_count();
    }
    if (parts.received.size() != header.part_count() || parts.received[header.part_index()]) {
      ++stats_.lateTiles;  // a copy, or a count that disagrees with its first part's
      return TileArrival::Late;
    }
    parts.received[header.part_index()] = true;
    --parts.missing;
    parts.splats += header.splats_rendered();
    parts.seconds += tile.renderSeconds;
    ++stats_.tileParts;
    tileSplats = parts.splats;
    tileSeconds = parts.seconds;
  }
  FrameRecord& record = pending_[header.frame_id()];
  record.splats += header.splats_rendered();
  record.bytesOrdered += header.ordered_bytes() + header.prefetch_bytes();
  record.bytesPrefetched += header.prefetch_bytes();
  record.bytesOrderedHeldElsewhere += header.ordered_bytes_held_elsewhere();
  record.imageBytes += tileImageBytes(header);
  record.imageBytesUncompressed +=
      header.compressed_bytes() != 0 ? header.uncompressed_bytes() : tileImageBytes(header);
  record.splatsPerRender[render] += header.splats_rendered();
  record.busySecondsPerRender[render] += tile.renderSeconds;
  if (part && parts_.at({header.frame_id(), header.tile_id(), header.attempt()}).missing > 0) {
    return TileArrival::Part;
  }
  if (part) {
    ++stats_.splitTiles;
    ++record.splitTiles;
    dropParts(header.frame_id(), header.tile_id());
    dispatchedAt_.erase({header.frame_id(), header.tile_id()});
  }
  frames_.tileArrived(header.frame_id(), header.tile_id(), header.rect());
  feedback_.at(header.frame_id()).at(header.tile_id()) =
      TileFeedback{header.rect(), tileSeconds, tileSplats};
  return TileArrival::Complete;
}

TileArrival FrameAssembly::backgroundArrived(const v1::TileImageHeader& header, TimePoint now) {
  peers_.indexOf(v1::ROLE_TRAVERSE, header.traverse_rank());  // throws for a stranger
  if (header.part_count() > 1) {
    throw ProtocolError("background tile from traverse rank " +
                        std::to_string(header.traverse_rank()) + " is a part of a split tile");
  }
  // In tiles.csv as render -1 (no render drew it); no render's work.
  recordTile(header, -1, /*keepDispatch=*/false, now);
  if (!frames_.tileWaiting(header.frame_id(), header.tile_id(), header.rect())) {
    ++stats_.lateTiles;
    return TileArrival::Late;
  }
  ++stats_.backgroundTiles;
  dropParts(header.frame_id(), header.tile_id());
  frames_.tileArrived(header.frame_id(), header.tile_id(), header.rect());
  feedback_.at(header.frame_id()).at(header.tile_id()) = TileFeedback{header.rect(), 0.0, 0};
  return TileArrival::Complete;
}

TileRecord FrameAssembly::recordTile(const v1::TileImageHeader& header, int render,
                                     bool keepDispatch, TimePoint now) {
  TileRecord tile;
  tile.frame = header.frame_id();
  tile.tile = header.tile_id();
  tile.attempt = header.attempt();
  tile.renderRank = render;
  tile.traverseRank = header.traverse_rank();
  tile.arrivedSeconds = since(now);
  if (const auto found = dispatchedAt_.find({header.frame_id(), header.tile_id()});
      found != dispatchedAt_.end()) {
    tile.dispatchedSeconds = found->second;
    if (!keepDispatch) dispatchedAt_.erase(found);
  }
  tile.queuedSeconds = static_cast<double>(header.queued_time_us()) * 1e-6;
  tile.dataWaitSeconds = static_cast<double>(header.data_wait_us()) * 1e-6;
  tile.renderSeconds = static_cast<double>(header.render_time_us()) * 1e-6;
  tile.splats = header.splats_rendered();
  tile.pixels = static_cast<std::uint64_t>(header.rect().width()) * header.rect().height();
  tile.orderedBytes = header.ordered_bytes();
  tile.prefetchBytes = header.prefetch_bytes();
  stats_.addTile(tile);
  return tile;
}

void FrameAssembly::dropParts(std::uint64_t frame, std::uint32_t tile) {
  parts_.erase(parts_.lower_bound({frame, tile, 0}),
               parts_.upper_bound({frame, tile, ~std::uint32_t{0}}));
}

std::uint64_t FrameAssembly::partSplatsFor(std::uint64_t frame, const TileRect& rect) const {
  const SchedulerKind scheduler = planner_.options().scheduler;
  if (scheduler != SchedulerKind::Cost && scheduler != SchedulerKind::Regions) return 0;
  const auto settings = frameSettings_.find(frame);
  if (!tileSplitAllowed(
          config_.run, settings != frameSettings_.end() ? settings->second : v1::FrameSettings())) {
    return 0;
  }
  if (config_.run.tile_part_splats() > 0) return config_.run.tile_part_splats();
  // Chosen here: only where cutting the screen has run out (a tile too small
  // to halve); a larger heavy tile is cut by the next frame's plan, which
  // moves no data.
  const std::uint32_t minSide = std::max<std::uint32_t>(1, planner_.options().minTileSize);
  if (std::max(rect.width(), rect.height()) >= 2 * minSide) return 0;
  // Before a frame is measured: about a splat per pixel at the level of detail.
  const Camera& camera = config_.cameras.at(frame);
  const float lod = settings != frameSettings_.end() && settings->second.lod_pixels() > 0.0f
                        ? settings->second.lod_pixels()
                        : (config_.run.lod_pixels() > 0.0f ? config_.run.lod_pixels() : 1.0f);
  const double pixels = static_cast<double>(camera.image_width()) * camera.image_height();
  const std::uint64_t share =
      planner_.partSplats(kDefaultMinTilePartSplats,
                          static_cast<std::uint64_t>(pixels / static_cast<double>(lod * lod)));
  return tunePartSize_ ? share * partTuner_.factorFor(frame) : share;
}

std::uint32_t FrameAssembly::tileLevelCap(const FrameRecord& record) {
  // Dividing the tiles by 2^k leaves the renders that get one about 2^k times
  // as busy: where they would pass half of the frame, the renders are the
  // limit and fewer tiles cannot make frames faster (it would only move
  // data), so the level stays at most log2(0.5 / mean busy share).
  // The busiest render holds the frame where work is uneven (its share is 4
  // to 6 times the mean at 64 to 128 renders): where 2^k times its work would
  // fill the frame, fewer tiles only move data, so also at most
  // log2(1 / busiest share), its share taken back to the tiles given (this
  // frame's divisor: fewer tiles made it busier). Not where tiles wait for
  // the traverses most of the time: fewer tiles are fewer walks there, and
  // the busiest render is busy (45 to 80 % at 1024 renders) because it has
  // the traverses' leftovers to draw.
  double busy = 0.0, busiest = 0.0;
  for (const auto& [rank, seconds] : record.busySecondsPerRender) {
    busy += seconds;
    busiest = std::max(busiest, seconds);
  }
  busiest /= static_cast<double>(tileTuner_.factorFor(record.frame));
  const double waited =
      requestWaitSeconds_ +
      (requestWaitSince_ >= 0.0 ? std::max(0.0, record.endSeconds - requestWaitSince_) : 0.0);
  const double waitedSinceLast = waited - requestWaitAtLastFrame_;
  requestWaitAtLastFrame_ = waited;
  // Not the warm-up's frames: the first ones wait for cells (the first one
  // here took 60 times a later one), and would make the renders look idle.
  if (record.frame >= config_.tileTuning.warmupFrames && lastFrameEnd_ >= 0.0 &&
      record.endSeconds > lastFrameEnd_) {
    constexpr double kWeight = 0.1;
    busySecondsSmoothed_ += kWeight * (busy - busySecondsSmoothed_);
    busiestSecondsSmoothed_ += kWeight * (busiest - busiestSecondsSmoothed_);
    requestWaitSmoothed_ += kWeight * (waitedSinceLast - requestWaitSmoothed_);
    frameSecondsSmoothed_ += kWeight * (record.endSeconds - lastFrameEnd_ - frameSecondsSmoothed_);
  }
  lastFrameEnd_ = record.endSeconds;
  const double renders = std::max<double>(1.0, planner_.liveRenders());
  const double share =
      frameSecondsSmoothed_ > 0.0 ? busySecondsSmoothed_ / (renders * frameSecondsSmoothed_) : 0.0;
  if (!(share > 0.0)) return ~std::uint32_t{0};
  double room = std::log2(0.5 / share);
  // Simulated, tiles wait 15 to 41 % of the time where the renders hold the
  // frames (the bunny at 4K, R = 64 and 128; the city at 720p, R = 16 and
  // 32) and 62 to 100 % where the traverses or their requests do (the city
  // at 720p, R >= 64; at 4K, R >= 128).
  constexpr double kTraversesHoldShare = 0.5;
  if (requestWaitSmoothed_ / frameSecondsSmoothed_ < kTraversesHoldShare) {
    room = std::min(room, std::log2(frameSecondsSmoothed_ / busiestSecondsSmoothed_));
  }
  return room < 0.0 ? 0u : static_cast<std::uint32_t>(std::min(room, 31.0));
}

std::pair<std::uint32_t, std::uint32_t> FrameAssembly::tileProgress(std::uint64_t frame) {
  const FrameState* state = frames_.frame(frame);
  if (state == nullptr) return {0, 0};
  const auto tiles = static_cast<std::uint32_t>(state->tiles.size());
  return {tiles - state->remaining, tiles};
}

std::vector<FinishedFrame> FrameAssembly::finishFrames(TimePoint now) {
  std::vector<FinishedFrame> finished;
  while (auto state = frames_.popCompleteFrame()) {
    FinishedFrame frame;
    FrameRecord& record = frame.record;
    record = std::move(pending_[state->index]);
    pending_.erase(state->index);
    record.frame = state->index;
    record.startSeconds = state->hasStarted ? since(state->started) : since(now);
    record.endSeconds = since(now);
    record.tiles = static_cast<std::uint32_t>(state->tiles.size());
    record.reissuedTiles = frames_.reissued(state->index);
    record.failedTiles = frames_.failed(state->index);
    for (int render : peers_.renders) {
      record.splatsPerRender.try_emplace(render, 0);
      record.busySecondsPerRender.try_emplace(render, 0.0);
    }
    // A frame with failed tiles has no measurement for them: no re-split from it.
    if (record.failedTiles == 0) planner_.frameDone(feedback_.at(state->index));
    feedback_.erase(state->index);
    homes_.erase(state->index);
    parts_.erase(parts_.lower_bound({state->index, 0, 0}),
                 parts_.lower_bound({state->index + 1, 0, 0}));
    frameSettings_.erase(state->index);
    for (const TileState& tile : state->tiles) {
      if (!tile.failed) continue;
      frame.failedTiles.push_back(tile.rect);
      for (const std::uint32_t holder : tile.holders) {
        frame.failedTileRenders.push_back(peers_.renders.at(holder));
      }
    }
    std::sort(frame.failedTileRenders.begin(), frame.failedTileRenders.end());
    frame.failedTileRenders.erase(
        std::unique(frame.failedTileRenders.begin(), frame.failedTileRenders.end()),
        frame.failedTileRenders.end());
    if (tunePartSize_) {
      partTuner_.frameFinished(record.frame, record.endSeconds, record.splitTiles > 0);
      stats_.partSizeFactor = partTuner_.factor();
      if (partTuner_.trials() > 0) stats_.partSizeTuning = partTuner_.summary();
    }
    if (tuneTileCount_) {
      tileTuner_.setLevelCap(tileLevelCap(record));
      tileTuner_.frameFinished(record.frame, record.endSeconds);
      const double perRender = config_.plan.tilesPerRender;
      stats_.tilesPerRenderTuned = perRender / static_cast<double>(tileTuner_.factor());
      if (tileTuner_.trials() > 0) stats_.tileCountTuning = tileCountSummary(perRender, tileTuner_);
    }
    stats_.addFrame(record);
    finished.push_back(std::move(frame));
  }
  if (!finished.empty()) admitFrames();
  return finished;
}

std::optional<TimePoint> FrameAssembly::nextDeadline() const {
  return frames_.nextDeadline();
}

std::uint32_t FrameAssembly::renderLost(int renderRank, TimePoint now, const std::string& reason) {
  const auto render = static_cast<std::uint32_t>(peers_.indexOf(v1::ROLE_RENDER, renderRank));
  planner_.retireRender(render);
  stats_.lost.push_back({"render", renderRank, since(now), reason, true});
  return frames_.renderLost(render);
}

std::uint64_t tileImageBytes(const v1::TileImageHeader& header) {
  if (header.format() == v1::PIXEL_FORMAT_BACKGROUND) return 0;
  if (header.compressed_bytes() != 0) return header.compressed_bytes();
  if (header.runs_bytes() != 0) return header.runs_bytes();
  const bool words = header.format() == v1::PIXEL_FORMAT_POINT_WORDS64;
  const v1::TileRect& sent = header.has_drawn_rect() ? header.drawn_rect() : header.rect();
  const std::uint64_t pixels = std::uint64_t{sent.width()} * sent.height();
  return pixels * (words ? 8 : 4) * (header.depth() == v1::DEPTH_FORMAT_EYE_FLOAT32 ? 2 : 1);
}

std::span<const std::byte> tileImagePayload(const v1::TileImageHeader& header,
                                            std::span<const std::byte> payload,
                                            std::vector<std::byte>& storage, int sourceRank) {
  if (header.compressed_bytes() == 0) {
    if (header.uncompressed_bytes() != 0)
      throw ProtocolError("tile image from rank " + std::to_string(sourceRank) +
                          " says it expands to " + std::to_string(header.uncompressed_bytes()) +
                          " bytes but is not compressed");
    return payload;
  }
  const std::string what = "tile image from rank " + std::to_string(sourceRank);
  if (payload.size() != header.compressed_bytes())
    throw ProtocolError(what + " has " + std::to_string(payload.size()) + " bytes, its header " +
                        std::to_string(header.compressed_bytes()) + " compressed");
  // The most any image of the rect carries: 8 bytes a pixel (words, or RGBA
  // and depth), and runs only where fewer than the box's bytes. Checked before
  // anything is allocated.
  const v1::TileRect& rect = header.rect();
  const std::uint64_t most = std::uint64_t{rect.width()} * rect.height() * 8;
  if (header.uncompressed_bytes() == 0 || header.uncompressed_bytes() > most)
    throw ProtocolError(what + " would expand to " + std::to_string(header.uncompressed_bytes()) +
                        " bytes; its " + std::to_string(rect.width()) + "x" +
                        std::to_string(rect.height()) + " tile holds at most " +
                        std::to_string(most));
  storage =
      decompressImageBytes(payload, static_cast<std::size_t>(header.uncompressed_bytes()), what);
  return storage;
}

std::uint64_t tileImagePixelBytes(const v1::TileImageHeader& header, std::size_t payloadBytes,
                                  int sourceRank) {
  const v1::TileRect& rect = header.rect();
  const bool withDepth = header.depth() == v1::DEPTH_FORMAT_EYE_FLOAT32;
  if (header.depth() != v1::DEPTH_FORMAT_NONE && !withDepth) {
    throw ProtocolError("tile image from rank " + std::to_string(sourceRank) +
                        " has an unknown depth format " + std::to_string(header.depth()));
  }
  if (header.format() == v1::PIXEL_FORMAT_BACKGROUND) {
    if (payloadBytes != 0 || withDepth || header.part_count() > 1) {
      throw ProtocolError(
          "background tile from rank " + std::to_string(sourceRank) + " carries " +
          std::to_string(payloadBytes) + " bytes" + (withDepth ? ", a depth image" : "") +
          (header.part_count() > 1 ? ", a part count" : "") + "; it may carry none");
    }
    return 0;
  }
  const bool words = header.format() == v1::PIXEL_FORMAT_POINT_WORDS64;
  if (words && withDepth) {
    throw ProtocolError("tile image from rank " + std::to_string(sourceRank) +
                        " has point words and a depth image");
  }
  if (header.has_drawn_rect()) {
    const v1::TileRect& d = header.drawn_rect();
    if (withDepth || !rectWithin(d, rect)) {
      throw ProtocolError("tile image from rank " + std::to_string(sourceRank) + " drew " +
                          std::to_string(d.width()) + "x" + std::to_string(d.height()) + " at (" +
                          std::to_string(d.x()) + "," + std::to_string(d.y()) + ")" +
                          (withDepth ? " with a depth image" : ", outside its tile"));
    }
  }
  if (header.runs_bytes() != 0) {
    if (!header.has_drawn_rect() || withDepth ||
        (header.format() != v1::PIXEL_FORMAT_RGBA8 && !words) ||
        payloadBytes != header.runs_bytes()) {
      throw ProtocolError("tile image from rank " + std::to_string(sourceRank) + " has " +
                          std::to_string(payloadBytes) + " bytes for " +
                          std::to_string(header.runs_bytes()) + " bytes of runs" +
                          (header.has_drawn_rect() ? "" : " and no drawn rectangle") +
                          (withDepth ? " and a depth image" : ""));
    }
    return payloadBytes;
  }
  // Only the box drawn in travels. In 64 bits: two 32-bit sides times 8
  // bytes cannot wrap.
  const v1::TileRect& sent = header.has_drawn_rect() ? header.drawn_rect() : rect;
  const std::uint64_t pixelBytes =
      static_cast<std::uint64_t>(sent.width()) * sent.height() * (words ? 8 : 4);
  const std::uint64_t expectedBytes = pixelBytes * (withDepth ? 2 : 1);
  if ((header.format() != v1::PIXEL_FORMAT_RGBA8 && !words) || payloadBytes != expectedBytes) {
    throw ProtocolError("tile image from rank " + std::to_string(sourceRank) + " has " +
                        std::to_string(payloadBytes) + " bytes, expected " +
                        std::to_string(expectedBytes));
  }
  return pixelBytes;
}

std::span<const std::byte> tileImagePixels(const v1::TileImageHeader& header,
                                           std::span<const std::byte> payload,
                                           std::uint64_t pixelBytes,
                                           std::vector<std::byte>& storage) {
  const std::span<const std::byte> pixels = payload.first(static_cast<std::size_t>(pixelBytes));
  if (header.runs_bytes() == 0) return pixels;
  const bool words = header.format() == v1::PIXEL_FORMAT_POINT_WORDS64;
  const std::array<std::uint8_t, 8> emptyWord{0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF};
  const std::span<const std::byte> empty =
      words ? std::span<const std::byte>(std::as_bytes(std::span(emptyWord)))
            : std::span<const std::byte>(std::as_bytes(std::span(kFrameBackground)));
  const v1::TileRect& box = header.drawn_rect();
  storage = decodePixelRuns(pixels, words ? 8 : 4, std::size_t{box.width()} * box.height(), empty);
  return storage;
}

}  // namespace pointillist::display
