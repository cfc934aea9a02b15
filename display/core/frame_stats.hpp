#pragma once
// Per-frame and per-render-process statistics of a run, printed and written as
// JSON and CSV for benchmarks (deploy/bench-*.sh read them).
#include <algorithm>
#include <cstdint>
#include <filesystem>
#include <map>
#include <optional>
#include <ostream>
#include <span>
#include <string>
#include <vector>

#include <boost/container/flat_map.hpp>

namespace pointillist::display {

struct FrameRecord {
  std::uint64_t frame = 0;
  double startSeconds = 0.0;  // since the run began
  double endSeconds = 0.0;
  std::uint64_t splats = 0;
  std::uint32_t tiles = 0;
  std::uint32_t reissuedTiles = 0;
  std::uint32_t failedTiles = 0;
  std::uint64_t bytesOrdered = 0;     // top-level cell data sent to render processes
  std::uint64_t bytesPrefetched = 0;  // of that, ordered ahead along the camera path
  // Of bytesOrdered, those another render held when ordered (work moved).
  std::uint64_t bytesOrderedHeldElsewhere = 0;
  std::uint64_t imageBytes = 0;  // tile images into the display (pixels and depth)
  // What those tile images expand to where they came compressed (all of them otherwise).
  std::uint64_t imageBytesUncompressed = 0;
  std::uint32_t splitTiles = 0;  // tiles that came in parts
  // By render rank. Flat: a run keeps up to --stats-frames of these records,
  // and a map node per render process cost three times the memory.
  boost::container::flat_map<int, std::uint64_t> splatsPerRender;
  boost::container::flat_map<int, double> busySecondsPerRender;
};

struct RenderSample {
  double seconds = 0.0;  // since the run began
  std::uint64_t frame = 0;
  std::uint64_t workloadSplats = 0;
  std::uint64_t cacheBytes = 0;
  std::uint64_t peakCacheBytes = 0;
  std::uint64_t cacheHits = 0;
  std::uint64_t cacheMisses = 0;
  std::uint64_t evictions = 0;
  std::uint64_t dataBytesReceived = 0;
};

// One tile's trip: handed to a traverse, queued and drawn on a render, back.
struct TileRecord {
  std::uint64_t frame = 0;
  std::uint32_t tile = 0;
  std::uint32_t attempt = 0;
  int renderRank = 0;
  int traverseRank = 0;
  double dispatchedSeconds = 0.0;  // since the run began
  double arrivedSeconds = 0.0;
  double queuedSeconds = 0.0;    // on the render: arrival of the packet to drawn
  double dataWaitSeconds = 0.0;  // of that, waiting for cell data
  double renderSeconds = 0.0;
  std::uint64_t splats = 0;
  std::uint64_t pixels = 0;
  std::uint64_t orderedBytes = 0;
  std::uint64_t prefetchBytes = 0;
};

// What one process spent between Ready and Shutdown (from its ShutdownAck):
// where the CPU of a run goes.
struct ProcessCpu {
  std::string role;  // display, traverse, datasend, render
  int rank = 0;
  double cpuSeconds = 0.0;
  double wallSeconds = 0.0;
  // The main thread's CPU seconds per activity (receive, handle <message>,
  // poll, ...); cpuSeconds minus their sum went to other threads.
  std::map<std::string, double> activities;
};

// A process the job lost while running (display/display_role.cpp).
struct LostProcess {
  std::string role;  // render, traverse, datasend
  int rank = 0;
  double seconds = 0.0;  // since the run began
  std::string reason;    // "no word from it for 5.0 s"
  bool jobWentOn = false;
};

// How evenly one frame's work was spread over the render processes: max/mean
// over all render processes of the job (1 is perfect balance).
struct FrameBalance {
  double maxBusySeconds = 0.0;
  double meanBusySeconds = 0.0;
  std::optional<double> busy;    // none when no render process was busy
  std::optional<double> splats;  // none when no splat was drawn
};

struct RenderFigures {
  std::uint64_t splats = 0;  // whole run
  double busySeconds = 0.0;
  double splatsPerSecond = 0.0;        // of wall time, whole run
  double splatsPerSecondSteady = 0.0;  // of wall time, steady-state frames
  double splatsPerBusySecond = 0.0;
  double busyFraction = 0.0;  // of the whole run
};

// The key figures of a run; the printed summary and the benchmarks use these.
// "Steady" means frames from steadyFrom on (caches warm).
struct KeyFigures {
  std::size_t frames = 0;
  std::size_t steadyFrom = 0;
  std::size_t renderProcesses = 0;
  double totalSeconds = 0.0;
  double framesPerSecond = 0.0;
  double framesPerSecondSteady = 0.0;
  double splatsPerFrame = 0.0;
  double splatsPerSecond = 0.0;          // all render processes, whole run
  std::map<int, RenderFigures> renders;  // by world rank
  // Steady splats/s of wall time per render process, over all render
  // processes of the job (one that drew nothing counts as 0).
  double renderSplatsPerSecondMean = 0.0;
  double renderSplatsPerSecondMin = 0.0;
  double renderSplatsPerSecondMax = 0.0;
  // Means over steady frames of the per-frame max/mean (FrameBalance).
  std::size_t imbalanceFrames = 0;
  double imbalanceBusy = 0.0;
  double imbalanceSplats = 0.0;
  // Max/mean of each render process's busy time summed over the steady frames:
  // with frames in flight a render may draw frame f+1 while another draws f,
  // so this is the share of the machine left idle, which per frame is not.
  double imbalanceBusyRun = 0.0;
  std::uint64_t bytesTotal = 0;
  std::uint64_t bytesFirstFrame = 0;
  double bytesPerFrameSteady = 0.0;
  double bytesHeldElsewherePerFrameSteady = 0.0;  // of it, held by another render
  double imageBytesPerFrameSteady = 0.0;          // FrameRecord::imageBytes
  double imageBytesUncompressedPerFrameSteady = 0.0;
  // A path played more than once (RunStats::loopFrames): the frames from the
  // second loop on, where every view's data was sent in the first.
  std::size_t laterLoopsFrom = 0;  // 0: one loop
  double framesPerSecondLaterLoops = 0.0;
  double bytesPerFrameLaterLoops = 0.0;
  double bytesHeldElsewherePerFrameLaterLoops = 0.0;
  double imageBytesPerFrameLaterLoops = 0.0;
  double imbalanceBusyLaterLoops = 0.0;
  std::uint64_t cacheHits = 0;
  std::uint64_t cacheMisses = 0;
  std::uint64_t cacheHitsSteady = 0;
  std::uint64_t cacheMissesSteady = 0;
  std::uint64_t evictions = 0;
  std::uint64_t peakCacheBytes = 0;  // largest on one render process
  double cacheHitRate = 0.0;         // 0..1, whole run
  double cacheHitRateSteady = 0.0;   // 0..1, during steady frames
  std::uint64_t reissuedTiles = 0;
  std::uint64_t failedTiles = 0;
  std::uint64_t lateTiles = 0;
  std::uint64_t splitTiles = 0;       // tiles drawn as parts by several renders
  std::uint64_t partSizeFactor = 0;   // RunStats::partSizeFactor
  double tilesPerRenderTuned = 0.0;   // RunStats::tilesPerRenderTuned
  double requestWaitShare = 0.0;      // RunStats::requestWaitSeconds of totalSeconds
  double planMsPerFrame = 0.0;        // RunStats::planSeconds per frame, milliseconds
  std::uint64_t tileParts = 0;        // their parts
  std::uint64_t backgroundTiles = 0;  // found empty by a traverse, drawn by no render
  std::uint64_t avoidingTasks = 0;    // tiles handed out naming renders to avoid
  // Core-seconds per frame by role over the whole run (0 when not known), and
  // of the render processes' time the part spent drawing.
  std::map<std::string, double> cpuPerFrame;
  double drawPerFrame = 0.0;
  double cpuPerFrameTotal = 0.0;
  // role -> activity -> CPU seconds per frame, with "other threads" for what
  // the activities do not cover.
  std::map<std::string, std::map<std::string, double>> cpuPerFrameByActivity;
};

// Keeps a long run's detail (frames, tiles, render samples) bounded. Past
// `limit` records every other one goes and from then on only every stride-th
// is kept, so the detail thins evenly over the whole run; the latest record is
// always the last one (counters in it are cumulative). The vector never holds
// more than limit + 1 records, nor has room for more.
struct DetailThinning {
  std::uint64_t seen = 0;
  std::uint64_t stride = 1;
  bool lastIsExtra = false;  // the last record kept is off the stride

  bool thinned() const { return stride > 1; }

  template <class T>
  void append(std::vector<T>& kept, const T& value, std::size_t limit) {
    limit = std::max<std::size_t>(limit, 4);
    ++seen;
    if (lastIsExtra) kept.pop_back();
    if (kept.size() == kept.capacity()) {
      kept.reserve(std::min(std::max<std::size_t>(2 * kept.capacity(), 16), limit + 1));
    }
    kept.push_back(value);
    lastIsExtra = seen % stride != 0;
    if (kept.size() <= limit) return;
    // kept[i] is record (i + 1) * stride, the extra one aside: keep the odd i.
    const std::size_t onStride = kept.size() - (lastIsExtra ? 1 : 0);
    std::size_t out = 0;
    for (std::size_t i = 1; i < onStride; i += 2) kept[out++] = std::move(kept[i]);
    if (lastIsExtra || onStride % 2 == 1) kept[out++] = std::move(kept.back());
    kept.resize(out);
    stride *= 2;
    lastIsExtra = seen % stride != 0;
  }
};

// Sums over a set of frames, for the key figures.
struct FrameSums {
  std::uint64_t frames = 0;
  std::uint64_t splats = 0;
  std::uint64_t bytesOrdered = 0;
  std::uint64_t bytesOrderedHeldElsewhere = 0;
  std::uint64_t imageBytes = 0;
  std::uint64_t imageBytesUncompressed = 0;
  std::uint64_t reissuedTiles = 0;
  std::uint64_t failedTiles = 0;
  double busySeconds = 0.0;  // all render processes
  std::map<int, std::uint64_t> splatsPerRender;
  std::map<int, double> busySecondsPerRender;
  // Sums of the per-frame imbalances, over the frames where each is defined.
  double imbalanceBusy = 0.0;
  std::size_t busyFrames = 0;
  double imbalanceSplats = 0.0;
  std::size_t splatFrames = 0;

  void add(const FrameRecord& frame, const FrameBalance& balance);
  void add(const FrameSums& other);
};

// Every frame of a run, summed as it is added, so the key figures stay exact
// however thinly the per-frame detail is kept.
struct FrameTotals {
  // Steady state begins at frame min(3, frames / 4) (RunStats::steadyStart).
  static constexpr std::size_t kSteadyFromAtMost = 3;
  std::vector<FrameRecord> first;  // the first kSteadyFromAtMost frames, whole
  FrameSums all;
  FrameSums afterFirst;                 // frames from kSteadyFromAtMost on
  FrameSums laterLoops;                 // frames from RunStats::loopFrames on, when set
  double laterLoopsBeginSeconds = 0.0;  // the first loop's last frame's end
  double lastEndSeconds = 0.0;
  std::size_t mostRendersInFrame = 0;
};

struct RunStats {
  std::string layout;
  std::string dataset;
  std::string cameraPath;
  std::uint32_t width = 0;
  std::uint32_t height = 0;
  std::string mode;
  // Per-frame detail in completion order: every frame, or past frameLimit an
  // even thinning of them (FrameTotals keeps the sums exact).
  std::vector<FrameRecord> frames;
  FrameTotals totals;
  std::map<int, std::vector<RenderSample>> renders;  // by world rank
  std::vector<TileRecord> tiles;                     // in arrival order
  // Bounds on the detail kept; past them it is thinned evenly
  // (DetailThinning). frameLimit 0 keeps every frame (the simulator's runs).
  std::size_t frameLimit = 0;
  std::size_t sampleLimit = 8192;
  std::size_t tileLimit = 32768;
  // Frames of one loop of the camera path when it is played several times
  // (--loops), else 0: the later loops get figures of their own.
  std::size_t loopFrames = 0;
  DetailThinning frameThinning;
  std::map<int, DetailThinning> sampleThinning;
  DetailThinning tileThinning;
  // A finished frame: into the totals, and into the detail.
  void addFrame(const FrameRecord& record);
  // The totals again from `frames`, after the caller changed records in
  // place; UsageError once frames were thinned.
  void recountFrames();
  std::uint64_t frameCount() const { return totals.all.frames; }
  // Room for the detail's bounds at once (frames, tiles, these render
  // processes' samples), with the pages touched: a long-running display
  // reaches its footprint at the start, and a run that would not fit fails
  // there and not hours in.
  void reserveDetail(std::span<const int> renderRanks);
  void addRenderSample(int rank, const RenderSample& sample) {
    sampleThinning[rank].append(renders[rank], sample, sampleLimit);
  }
  void addTile(const TileRecord& tile) { tileThinning.append(tiles, tile, tileLimit); }
  std::uint64_t lateTiles = 0;        // arrived after their frame was done or re-issued
  std::uint64_t splitTiles = 0;       // tiles drawn as parts by several renders, composed
  std::uint64_t tileParts = 0;        // parts accepted
  std::uint64_t backgroundTiles = 0;  // answered by a traverse: nothing to draw
  // The part size's factor the display chose on the frame rate and what it
  // measured (FrameRateTuner::summary); 0 and empty where it was not tuned.
  std::uint64_t partSizeFactor = 0;
  std::string partSizeTuning;
  // The cost scheduler's tiles per render process as the display tuned them
  // and what it measured; 0 and empty where it was not tuned.
  double tilesPerRenderTuned = 0.0;
  std::string tileCountTuning;
  // Time tiles waited to be handed out with no traverse's request in: the
  // traverse processes (their walks or request round trips) held the frames.
  double requestWaitSeconds = 0.0;
  // Wall time the display spent laying out frames' tiles (TilePlanner::plan):
  // its own CPU, on the frames' path, which the simulator does not charge.
  double planSeconds = 0.0;
  // Tiles handed out while a render held a tile past its deadline (the task
  // named it to avoid: FrameScheduler::suspectRenders).
  std::uint64_t avoidingTasks = 0;
  double totalSeconds = 0.0;
  std::vector<ProcessCpu> processes;  // filled once the job has shut down
  std::vector<LostProcess> lost;

  // Frames per second over frames [first, end).
  double framesPerSecond(std::size_t first) const;
  // First steady-state frame: the first few frames warm the caches.
  std::size_t steadyStart() const;
  // Render processes of the job (from the layout, else those that reported).
  std::size_t renderProcessCount() const;
  FrameBalance balance(const FrameRecord& frame) const;
  KeyFigures keyFigures() const;

  std::string toJson() const;
  void writeJsonTo(std::ostream& out) const;
  void writeJson(const std::filesystem::path& file) const;
  // Writes DIR/frames.csv, DIR/renders.csv, DIR/per_frame_render.csv and
  // DIR/tiles.csv, DIR/figures.csv (keyFigures() as one line); frame_stats.cpp lists the columns.
  void writeCsv(const std::filesystem::path& dir) const;
  // Human summary of keyFigures(): frame rate (all and steady state), splats/s
  // per render, imbalance, bytes per frame, cache hit rate.
  std::string summary() const;
};

}  // namespace pointillist::display
