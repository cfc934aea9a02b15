#pragma once
// Every decision of the display (seed 003 §4.2), without MPI: which frames are
// in flight, how each is split into tiles (TilePlanner), which tile goes to
// which idle traverse process and when, re-issue of tiles that do not come
// back, feedback of measured work to the planner, and the run's statistics.
//
// The core is told what arrived and `now` and appends what to send to an
// Outbox; it keeps no pixels (the caller composes accepted tiles). The MPI
// display and the simulator both drive this class.
#include <chrono>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <optional>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include "common/camera.hpp"
#include "common/camera_path.hpp"
#include "common/clock.hpp"
#include "common/messages.hpp"
#include "common/peer_ranks.hpp"
#include "display/core/frame_rate_tuner.hpp"
#include "display/core/frame_scheduler.hpp"
#include "display/core/frame_stats.hpp"
#include "display/core/tile_planner.hpp"

namespace pointillist::display {

struct FrameAssemblyConfig {
  std::vector<Camera> cameras;  // one per frame
  SceneBounds bounds;
  // The box of interest grows by this much (largest splat radius x size scale).
  float marginWorld = 0.0f;
  std::uint32_t framesInFlight = 3;
  std::chrono::milliseconds tileTimeout{10'000};
  std::uint32_t maxAttempts = 3;
  TilePlanOptions plan;
  // Cost scheduler: tiles carry the camera this many frames on (0: none).
  std::uint32_t prefetchFrames = 0;
  // The run's settings, for splitting heavy tiles by their data
  // (no_tile_split, tile_part_splats, and what tileSplitAllowed reads).
  v1::RunSettings run;
  // The display's part size tuned on the frame rate it sees
  // (frame_rate_tuner.hpp) where the run leaves the size to the display
  // (--tile-split auto); not in serve mode, where clients set the pace.
  bool tunePartSize = true;
  FrameRateTunerOptions partTuning;
  // The cost scheduler's tile count tuned the same way, divided by 1, 2,
  // 4, ... (fewer walks for the traverse processes) where the run leaves
  // --tiles-per-render at its default; tile count and part size take turns.
  bool tuneTileCount = true;
  FrameRateTunerOptions tileTuning;
};

// What became of a tile image that arrived.
enum class TileArrival {
  Late,      // a late copy, or a part of a tile already in: counted only
  Part,      // a part of a split tile, kept: the caller composes its words
  Complete,  // the tile is in (a whole one, or its attempt's last part)
};

// How much a tile matters to draw early; higher first.
using TilePriority = std::function<double(const TileRect&)>;

struct FinishedFrame {
  FrameRecord record;                 // also appended to stats().frames
  std::vector<TileRect> failedTiles;  // never came back: the caller marks them
  // World ranks of the render processes the failed tiles' last attempts went
  // to, as the traverses said (sorted, once each; empty when none said).
  std::vector<int> failedTileRenders;
};

// The bytes a tile image's header says its payload holds (pixels and depth,
// or the zstd frame of them), as checked by tileImagePixelBytes and
// tileImagePayload: what it moved into the display.
std::uint64_t tileImageBytes(const v1::TileImageHeader& header);
// A tile image's payload as its other fields describe it: one that came
// compressed (compressed_bytes) expanded into `storage`, after checking that
// it is those bytes and expands to uncompressed_bytes, no more than its rect
// could carry; any other payload as it is. Throws ProtocolError naming
// `sourceRank`.
std::span<const std::byte> tileImagePayload(const v1::TileImageHeader& header,
                                            std::span<const std::byte> payload,
                                            std::vector<std::byte>& storage, int sourceRank);
// The bytes of a TileImage's pixels (RGBA8 rows of its rect, or the point
// kernel's words for a part of a split tile: of its drawn_rect where given),
// checked against its payload (`payloadBytes`: the pixels, then as many again
// of float depth when the header says so). Throws ProtocolError naming
// `sourceRank`.
std::uint64_t tileImagePixelBytes(const v1::TileImageHeader& header, std::size_t payloadBytes,
                                  int sourceRank);
// The pixels of the box the payload covers (drawn_rect, or the rect), dense:
// runs (TileImageHeader.runs_bytes) expanded into `storage`, empty pixels
// the background or the empty word. `pixelBytes` from tileImagePixelBytes.
// ProtocolError for runs that do not cover the box.
std::span<const std::byte> tileImagePixels(const v1::TileImageHeader& header,
                                           std::span<const std::byte> payload,
                                           std::uint64_t pixelBytes,
                                           std::vector<std::byte>& storage);

class FrameAssembly {
 public:
  // `start` is the time the run's statistics count from.
  FrameAssembly(FrameAssemblyConfig config, PeerRanks peers, TimePoint start);

  // Adds a frame after those given at construction (serve mode: frames come
  // as clients ask); it enters the window at once when there is room. Its
  // tiles carry `settings` to the traverse and render processes; a scheduler
  // named there holds for this frame and the ones after it.
  // `priority`, when given, orders its tiles: the highest go out first
  // (serve mode: where the render cache could not fill the interim frame).
  void appendCamera(const Camera& camera, const v1::FrameSettings& settings = {},
                    TilePriority priority = {});
  // Frames admitted and not yet finished.
  std::size_t framesInFlight() const { return framesAdded_ - stats_.frameCount(); }

  // A traverse process asked for work, telling where its last task went.
  void workRequested(int traverseRank, const v1::WorkRequest& request = {});
  // Re-queues tiles past their deadline (or gives them up after maxAttempts),
  // then hands waiting tiles to idle traverse processes. Returns how many
  // tiles were re-queued.
  std::uint32_t dispatch(TimePoint now, Outbox& out);
  // A tile image arrived (its pixels already checked against its rect).
  // Complete when its frame was waiting for it: the caller composes it then.
  // A part of a split tile is Part until the last part of the same attempt
  // arrives, which is Complete; the caller composes every part it is given
  // (TilePartCompositor). Late for a late copy of a re-issued tile, or a part
  // of a tile already in, which is only counted. Each part counts as its
  // render's work. ProtocolError for a part index out of its count.
  // A background tile (PIXEL_FORMAT_BACKGROUND) comes from the traverse
  // that found nothing to draw there: complete, and no render's work.
  TileArrival tileArrived(const v1::TileImageHeader& header, TimePoint now);
  // The part size the traverse processes split this tile `rect` of a frame
  // into when it is heavy (TileTask.part_splats); 0: not split. A size the
  // run fixed holds for every tile; the display's own choice
  // (TilePlanner::partSplats, times the tuner's factor for the frame) only
  // for tiles too small to halve.
  std::uint64_t partSplatsFor(std::uint64_t frame, const TileRect& rect) const;
  // Tiles of an admitted frame done (arrived or given up) and in all; {0, 0}
  // for a frame not in the window.
  std::pair<std::uint32_t, std::uint32_t> tileProgress(std::uint64_t frame);
  // Frames whose every tile arrived or was given up, in order; later frames
  // enter the window as these leave it.
  std::vector<FinishedFrame> finishFrames(TimePoint now);

  // A render process is gone: it gets no more tiles, the tiles it holds (as
  // the traverses' work requests placed them) are re-issued at once, and so
  // is one placed on it after this (FrameScheduler::renderLost); the run's
  // statistics record the loss. Returns the tiles re-issued now. UsageError
  // when it was the last render process.
  std::uint32_t renderLost(int renderRank, TimePoint now, const std::string& reason);
  // When the oldest tile out is due back (the simulator wakes up then).
  std::optional<TimePoint> nextDeadline() const;
  bool done() const { return framesAdded_ == config_.cameras.size() && frames_.finished(); }
  std::size_t frameCount() const { return config_.cameras.size(); }
  std::size_t idleTraverses() const { return idleTraverses_.size(); }
  // Tiles wait to be handed out and no traverse has a request in (after dispatch).
  bool tilesWaitForRequests() const { return idleTraverses_.empty() && frames_.tasksQueued(); }
  const RunStats& stats() const { return stats_; }
  RunStats& stats() { return stats_; }
  const TilePlanner& planner() const { return planner_; }
  // Whether the part size is tuned in this run, and how that went.
  bool tunesPartSize() const { return tunePartSize_; }
  const FrameRateTuner& partSizeTuner() const { return partTuner_; }
  bool tunesTileCount() const { return tuneTileCount_; }
  const FrameRateTuner& tileCountTuner() const { return tileTuner_; }

 private:
  void admitFrames();
  std::uint32_t tileLevelCap(const FrameRecord& record);
  TileArrival backgroundArrived(const v1::TileImageHeader& header, TimePoint now);
  // The tiles.csv record of an arrival, whatever becomes of it; the tile's
  // dispatch time stays while more parts of it may come (`keepDispatch`).
  TileRecord recordTile(const v1::TileImageHeader& header, int render, bool keepDispatch,
                        TimePoint now);
  // Parts of the tile from any attempt: late from now on, the tile is in.
  void dropParts(std::uint64_t frame, std::uint32_t tile);
  double since(TimePoint time) const { return secondsBetween(start_, time); }

  FrameAssemblyConfig config_;
  PeerRanks peers_;
  TimePoint start_;
  FrameScheduler frames_;
  TilePlanner planner_;
  SchedulerKind runScheduler_;
  // Served frames' own settings (mode, level of detail), by frame; the
  // scheduler part is applied to the planner as the frame is admitted.
  std::map<std::uint64_t, v1::FrameSettings> frameSettings_;
  std::map<std::uint64_t, TilePriority> tilePriority_;
  std::uint64_t framesAdded_ = 0;
  std::deque<int> idleTraverses_;
  std::map<std::uint64_t, std::vector<TileFeedback>> feedback_;
  // Regions scheduler: each admitted frame's tiles' home render processes.
  std::map<std::uint64_t, std::vector<std::uint32_t>> homes_;
  std::map<std::pair<std::uint64_t, std::uint32_t>, double> dispatchedAt_;
  // Split tiles whose parts are coming in, by (frame, tile, attempt).
  struct PartsInFlight {
    std::vector<bool> received;
    std::uint32_t missing = 0;
    std::uint64_t splats = 0;
    double seconds = 0.0;
  };
  std::map<std::tuple<std::uint64_t, std::uint32_t, std::uint32_t>, PartsInFlight> parts_;
  std::map<std::uint64_t, FrameRecord> pending_;
  RunStats stats_;
  bool tunePartSize_ = false;
  FrameRateTuner partTuner_;
  bool tuneTileCount_ = false;
  FrameRateTuner tileTuner_;
  // The renders' mean and busiest busy share of a frame and the time tiles
  // waited for a traverse to ask, smoothed over the last frames: fewer tiles
  // are only tried where the renders that keep one stay under half busy and,
  // unless the traverses hold the frames, the busiest would not be the limit
  // (tileLevelCap).
  double busySecondsSmoothed_ = 0.0;
  double busiestSecondsSmoothed_ = 0.0;
  double requestWaitSmoothed_ = 0.0;
  double frameSecondsSmoothed_ = 0.0;
  double lastFrameEnd_ = -1.0;
  // Seconds (since the run began) tiles waited for requests, and when the
  // open span began (negative: none open).
  double requestWaitSeconds_ = 0.0;
  double requestWaitSince_ = -1.0;
  double requestWaitAtLastFrame_ = 0.0;
};

}  // namespace pointillist::display
