#pragma once
// Per-frame and per-render-process statistics of a run, printed and written as
// JSON and CSV for benchmarks (deploy/bench-*.sh read them).
#include <cstdint>
#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <vector>

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
  std::map<int, std::uint64_t> splatsPerRender;
  std::map<int, double> busySecondsPerRender;
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
  // Core-seconds per frame by role over the whole run (0 when not known), and
  // of the render processes' time the part spent drawing.
  std::map<std::string, double> cpuPerFrame;
  double drawPerFrame = 0.0;
  double cpuPerFrameTotal = 0.0;
  // role -> activity -> CPU seconds per frame, with "other threads" for what
  // the activities do not cover.
  std::map<std::string, std::map<std::string, double>> cpuPerFrameByActivity;
};

struct RunStats {
  std::string layout;
  std::string dataset;
  std::string cameraPath;
  std::uint32_t width = 0;
  std::uint32_t height = 0;
  std::string mode;
  std::vector<FrameRecord> frames;
  std::map<int, std::vector<RenderSample>> renders;  // by world rank
  std::vector<TileRecord> tiles;                     // in arrival order
  std::uint64_t lateTiles = 0;  // arrived after their frame was done or re-issued
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
  void writeJson(const std::filesystem::path& file) const;
  // Writes DIR/frames.csv, DIR/renders.csv, DIR/per_frame_render.csv and
  // DIR/tiles.csv, DIR/figures.csv (keyFigures() as one line); frame_stats.cpp lists the columns.
  void writeCsv(const std::filesystem::path& dir) const;
  // Human summary of keyFigures(): frame rate (all and steady state), splats/s
  // per render, imbalance, bytes per frame, cache hit rate.
  std::string summary() const;
};

}  // namespace pointillist::display
