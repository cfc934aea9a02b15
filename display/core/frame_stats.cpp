#include "display/core/frame_stats.hpp"

#include <algorithm>
#include <cstdio>
#include <fstream>
#include <limits>
#include <sstream>

#include "common/errors.hpp"
#include "common/job_layout.hpp"

namespace pointillist::display {
namespace {

std::string number(double value) {
  char text[64];
  std::snprintf(text, sizeof text, "%.9g", value);
  return text;
}

std::string optionalNumber(const std::optional<double>& value) {
  return value ? number(*value) : std::string();
}

double ratio(double numerator, double denominator) {
  return denominator > 0.0 ? numerator / denominator : 0.0;
}

double ratio(std::uint64_t numerator, std::uint64_t denominator) {
  return ratio(static_cast<double>(numerator), static_cast<double>(denominator));
}

// Writes next to the target and renames, so readers never see half a file.
std::string jsonEscaped(const std::string& text) {
  std::string escaped;
  for (const char c : text) {
    if (c == '"' || c == '\\') {
      escaped += '\\';
      escaped += c;
    } else if (static_cast<unsigned char>(c) < 0x20) {
      escaped += ' ';
    } else {
      escaped += c;
    }
  }
  return escaped;
}

// Written straight to the file, not built in memory first: a long run's
// statistics are megabytes, and a checkpoint must not cost that much again.
class AtomicFile {
 public:
  AtomicFile(std::filesystem::path file, const char* what)
      : file_(std::move(file)), temporary_(file_.string() + ".tmp"), out_(temporary_), what_(what) {
    if (!out_) throw Error(file_.string() + ": cannot write " + what_);
  }
  std::ostream& stream() { return out_; }
  void commit() {
    out_.close();
    if (!out_) throw Error(file_.string() + ": cannot write " + what_);
    std::filesystem::rename(temporary_, file_);
  }

 private:
  std::filesystem::path file_;
  std::filesystem::path temporary_;
  std::ofstream out_;
  const char* what_;
};

void writeFile(const std::filesystem::path& file, const std::string& text, const char* what) {
  AtomicFile out(file, what);
  out.stream() << text;
  out.commit();
}

// The key figures by name, in the order of figures.csv and "key_figures" in
// stats.json: rates per second, bytes and splats as counts, hit rates 0..1.
double cpuOf(const KeyFigures& k, const std::string& role) {
  const auto found = k.cpuPerFrame.find(role);
  return found == k.cpuPerFrame.end() ? 0.0 : found->second;
}

std::vector<std::pair<std::string, std::string>> keyFigureFields(const KeyFigures& k) {
  const auto count = [](std::uint64_t value) { return std::to_string(value); };
  return {
      {"frames", count(k.frames)},
      {"steady_from", count(k.steadyFrom)},
      {"render_processes", count(k.renderProcesses)},
      {"total_seconds", number(k.totalSeconds)},
      {"frames_per_second", number(k.framesPerSecond)},
      {"frames_per_second_steady", number(k.framesPerSecondSteady)},
      {"splats_per_frame", number(k.splatsPerFrame)},
      {"splats_per_second", number(k.splatsPerSecond)},
      {"render_splats_per_second_mean", number(k.renderSplatsPerSecondMean)},
      {"render_splats_per_second_min", number(k.renderSplatsPerSecondMin)},
      {"render_splats_per_second_max", number(k.renderSplatsPerSecondMax)},
      {"imbalance_frames", count(k.imbalanceFrames)},
      {"imbalance_busy", number(k.imbalanceBusy)},
      {"imbalance_splats", number(k.imbalanceSplats)},
      {"imbalance_busy_run", number(k.imbalanceBusyRun)},
      {"bytes_total", count(k.bytesTotal)},
      {"bytes_first_frame", count(k.bytesFirstFrame)},
      {"bytes_per_frame_steady", number(k.bytesPerFrameSteady)},
      {"bytes_held_elsewhere_per_frame_steady", number(k.bytesHeldElsewherePerFrameSteady)},
      {"image_bytes_per_frame_steady", number(k.imageBytesPerFrameSteady)},
      {"image_bytes_uncompressed_per_frame_steady", number(k.imageBytesUncompressedPerFrameSteady)},
      {"later_loops_from", count(k.laterLoopsFrom)},
      {"frames_per_second_later_loops", number(k.framesPerSecondLaterLoops)},
      {"bytes_per_frame_later_loops", number(k.bytesPerFrameLaterLoops)},
      {"bytes_held_elsewhere_per_frame_later_loops",
       number(k.bytesHeldElsewherePerFrameLaterLoops)},
      {"image_bytes_per_frame_later_loops", number(k.imageBytesPerFrameLaterLoops)},
      {"imbalance_busy_later_loops", number(k.imbalanceBusyLaterLoops)},
      {"cache_hits", count(k.cacheHits)},
      {"cache_misses", count(k.cacheMisses)},
      {"cache_hit_rate", number(k.cacheHitRate)},
      {"cache_hit_rate_steady", number(k.cacheHitRateSteady)},
      {"evictions", count(k.evictions)},
      {"peak_cache_bytes", count(k.peakCacheBytes)},
      {"reissued_tiles", count(k.reissuedTiles)},
      {"failed_tiles", count(k.failedTiles)},
      {"late_tiles", count(k.lateTiles)},
      {"split_tiles", count(k.splitTiles)},
      {"tile_parts", count(k.tileParts)},
      {"part_size_factor", count(k.partSizeFactor)},
      {"tiles_per_render_tuned", number(k.tilesPerRenderTuned)},
      {"request_wait_share", number(k.requestWaitShare)},
      {"plan_ms_per_frame", number(k.planMsPerFrame)},
      {"background_tiles", count(k.backgroundTiles)},
      {"tasks_avoiding_silent_renders", count(k.avoidingTasks)},
      {"cpu_per_frame_display", number(cpuOf(k, "display"))},
      {"cpu_per_frame_traverse", number(cpuOf(k, "traverse"))},
      {"cpu_per_frame_datasend", number(cpuOf(k, "datasend"))},
      {"cpu_per_frame_render", number(cpuOf(k, "render"))},
      {"draw_per_frame", number(k.drawPerFrame)},
      {"cpu_per_frame_total", number(k.cpuPerFrameTotal)},
  };
}

}  // namespace

void FrameSums::add(const FrameRecord& frame, const FrameBalance& balance) {
  ++frames;
  splats += frame.splats;
  bytesOrdered += frame.bytesOrdered;
  bytesOrderedHeldElsewhere += frame.bytesOrderedHeldElsewhere;
  imageBytes += frame.imageBytes;
  imageBytesUncompressed += frame.imageBytesUncompressed;
  reissuedTiles += frame.reissuedTiles;
  failedTiles += frame.failedTiles;
  for (const auto& [rank, s] : frame.splatsPerRender) splatsPerRender[rank] += s;
  for (const auto& [rank, b] : frame.busySecondsPerRender) {
    busySecondsPerRender[rank] += b;
    busySeconds += b;
  }
  if (balance.busy) {
    imbalanceBusy += *balance.busy;
    ++busyFrames;
  }
  if (balance.splats) {
    imbalanceSplats += *balance.splats;
    ++splatFrames;
  }
}

void FrameSums::add(const FrameSums& other) {
  frames += other.frames;
  splats += other.splats;
  bytesOrdered += other.bytesOrdered;
  bytesOrderedHeldElsewhere += other.bytesOrderedHeldElsewhere;
  imageBytes += other.imageBytes;
  imageBytesUncompressed += other.imageBytesUncompressed;
  reissuedTiles += other.reissuedTiles;
  failedTiles += other.failedTiles;
  busySeconds += other.busySeconds;
  for (const auto& [rank, s] : other.splatsPerRender) splatsPerRender[rank] += s;
  for (const auto& [rank, b] : other.busySecondsPerRender) busySecondsPerRender[rank] += b;
  imbalanceBusy += other.imbalanceBusy;
  busyFrames += other.busyFrames;
  imbalanceSplats += other.imbalanceSplats;
  splatFrames += other.splatFrames;
}

void RunStats::addFrame(const FrameRecord& record) {
  // A frame's imbalance is judged now: renders lost later had their share in it.
  totals.mostRendersInFrame =
      std::max(totals.mostRendersInFrame, record.busySecondsPerRender.size());
  totals.lastEndSeconds = record.endSeconds;
  const std::uint64_t index = totals.all.frames;
  const bool laterLoop = loopFrames > 0 && index >= loopFrames;
  if (loopFrames > 0 && index + 1 == loopFrames) totals.laterLoopsBeginSeconds = record.endSeconds;
  if (totals.first.size() < FrameTotals::kSteadyFromAtMost) {
    totals.first.push_back(record);
    totals.all.add(record, {});
    if (laterLoop) totals.laterLoops.add(record, balance(record));
  } else {
    const FrameBalance b = balance(record);
    totals.all.add(record, b);
    totals.afterFirst.add(record, b);
    if (laterLoop) totals.laterLoops.add(record, b);
  }
  if (frameLimit == 0) {
    frames.push_back(record);
  } else {
    frameThinning.append(frames, record, frameLimit);
  }
}

void RunStats::recountFrames() {
  if (frameThinning.thinned() || frames.size() != frameCount()) {
    throw UsageError("the frames of a run were thinned; their totals cannot be counted again");
  }
  const std::vector<FrameRecord> records = std::move(frames);
  frames.clear();
  totals = FrameTotals{};
  frameThinning = DetailThinning{};
  for (const FrameRecord& record : records) addFrame(record);
}

void RunStats::reserveDetail(std::span<const int> renderRanks) {
  const auto touch = [](auto& records, std::size_t limit) {
    if (limit == 0 || !records.empty()) return;
    records.resize(std::max<std::size_t>(limit, 4) + 1);
    records.clear();
  };
  touch(frames, frameLimit);
  touch(tiles, tileLimit);
  for (int rank : renderRanks) touch(renders[rank], sampleLimit);
}

double RunStats::framesPerSecond(std::size_t first) const {
  const std::uint64_t count = frameCount();
  if (count <= first || first > totals.first.size()) return 0.0;
  const double start = first == 0 ? 0.0 : totals.first[first - 1].endSeconds;
  const double span = totals.lastEndSeconds - start;
  return span > 0.0 ? static_cast<double>(count - first) / span : 0.0;
}

std::size_t RunStats::steadyStart() const {
  const std::uint64_t count = frameCount();
  return count > 4 ? static_cast<std::size_t>(
                         std::min<std::uint64_t>(FrameTotals::kSteadyFromAtMost, count / 4))
                   : 0;
}

std::size_t RunStats::renderProcessCount() const {
  std::size_t count = std::max(renders.size(), totals.mostRendersInFrame);
  try {
    if (!layout.empty()) count = std::max<std::size_t>(count, JobLayout::parse(layout).render);
  } catch (const Error&) {
    // Not a D,T,S,R layout: count the render processes that reported.
  }
  return count;
}

FrameBalance RunStats::balance(const FrameRecord& frame) const {
  FrameBalance result;
  // Render processes lost before the frame began had no share in it.
  std::size_t gone = 0;
  for (const LostProcess& p : lost) {
    if (p.role == "render" && p.jobWentOn && p.seconds <= frame.startSeconds) ++gone;
  }
  const std::size_t all = renderProcessCount();
  const auto count = static_cast<double>(all - std::min(gone, all));
  if (count == 0.0) return result;
  double sumBusy = 0.0, maxSplats = 0.0, sumSplats = 0.0;
  for (const auto& [rank, busy] : frame.busySecondsPerRender) {
    result.maxBusySeconds = std::max(result.maxBusySeconds, busy);
    sumBusy += busy;
  }
  for (const auto& [rank, splats] : frame.splatsPerRender) {
    maxSplats = std::max(maxSplats, static_cast<double>(splats));
    sumSplats += static_cast<double>(splats);
  }
  result.meanBusySeconds = sumBusy / count;
  if (sumBusy > 0.0) result.busy = result.maxBusySeconds / result.meanBusySeconds;
  if (sumSplats > 0.0) result.splats = maxSplats / (sumSplats / count);
  return result;
}

KeyFigures RunStats::keyFigures() const {
  KeyFigures k;
  k.frames = frameCount();
  k.steadyFrom = steadyStart();
  k.renderProcesses = renderProcessCount();
  k.totalSeconds = totalSeconds;
  k.framesPerSecond = framesPerSecond(0);
  k.framesPerSecondSteady = framesPerSecond(k.steadyFrom);
  k.lateTiles = lateTiles;
  k.splitTiles = splitTiles;
  k.partSizeFactor = partSizeFactor;
  k.tilesPerRenderTuned = tilesPerRenderTuned;
  k.requestWaitShare = totalSeconds > 0.0 ? requestWaitSeconds / totalSeconds : 0.0;
  k.planMsPerFrame = frameCount() > 0 ? 1e3 * planSeconds / static_cast<double>(frameCount()) : 0.0;
  k.tileParts = tileParts;
  k.backgroundTiles = backgroundTiles;
  k.avoidingTasks = avoidingTasks;
  const FrameSums& all = totals.all;
  if (k.frames > 0) {
    const auto frameCount = static_cast<double>(k.frames);
    for (const ProcessCpu& process : processes) {
      k.cpuPerFrame[process.role] += process.cpuSeconds / frameCount;
      k.cpuPerFrameTotal += process.cpuSeconds / frameCount;
      if (!process.activities.empty()) {
        auto& byActivity = k.cpuPerFrameByActivity[process.role];
        double covered = 0.0;
        for (const auto& [activity, seconds] : process.activities) {
          byActivity[activity] += seconds / frameCount;
          covered += seconds;
        }
        byActivity["other threads"] += std::max(0.0, process.cpuSeconds - covered) / frameCount;
      }
    }
    k.drawPerFrame = all.busySeconds / frameCount;
  }

  // The steady frames: those past the first three, and of those the ones
  // from steadyFrom on (a short run's steady state begins earlier).
  FrameSums steady = totals.afterFirst;
  for (std::size_t i = k.steadyFrom; i < totals.first.size(); ++i) {
    steady.add(totals.first[i], balance(totals.first[i]));
  }
  const double steadyBegins = k.steadyFrom == 0 ? 0.0 : totals.first[k.steadyFrom - 1].endSeconds;
  const double steadySpan = k.frames == 0 ? 0.0 : totals.lastEndSeconds - steadyBegins;
  k.bytesTotal = all.bytesOrdered;
  k.reissuedTiles = all.reissuedTiles;
  k.failedTiles = all.failedTiles;
  for (const auto& [rank, s] : all.splatsPerRender) k.renders[rank].splats = s;
  for (const auto& [rank, b] : all.busySecondsPerRender) k.renders[rank].busySeconds = b;
  k.splatsPerFrame = ratio(static_cast<double>(all.splats), static_cast<double>(k.frames));
  k.splatsPerSecond = ratio(static_cast<double>(all.splats), totalSeconds);
  k.imbalanceFrames = std::max(steady.busyFrames, steady.splatFrames);
  k.imbalanceBusy = ratio(steady.imbalanceBusy, static_cast<double>(steady.busyFrames));
  k.imbalanceSplats = ratio(steady.imbalanceSplats, static_cast<double>(steady.splatFrames));
  {
    double most = 0.0, total = 0.0;
    for (const auto& [rank, busy] : steady.busySecondsPerRender) {
      most = std::max(most, busy);
      total += busy;
    }
    const double renderCount =
        static_cast<double>(std::max(k.renderProcesses, steady.busySecondsPerRender.size()));
    k.imbalanceBusyRun = total > 0.0 ? most * renderCount / total : 0.0;
  }
  if (!totals.first.empty()) k.bytesFirstFrame = totals.first.front().bytesOrdered;
  k.bytesPerFrameSteady = ratio(steady.bytesOrdered, steady.frames);
  k.bytesHeldElsewherePerFrameSteady = ratio(steady.bytesOrderedHeldElsewhere, steady.frames);
  k.imageBytesPerFrameSteady = ratio(steady.imageBytes, steady.frames);
  k.imageBytesUncompressedPerFrameSteady = ratio(steady.imageBytesUncompressed, steady.frames);
  if (const FrameSums& later = totals.laterLoops; later.frames > 0) {
    k.laterLoopsFrom = loopFrames;
    const double span = totals.lastEndSeconds - totals.laterLoopsBeginSeconds;
    k.framesPerSecondLaterLoops = ratio(static_cast<double>(later.frames), span);
    k.bytesPerFrameLaterLoops = ratio(later.bytesOrdered, later.frames);
    k.bytesHeldElsewherePerFrameLaterLoops = ratio(later.bytesOrderedHeldElsewhere, later.frames);
    k.imageBytesPerFrameLaterLoops = ratio(later.imageBytes, later.frames);
    k.imbalanceBusyLaterLoops = ratio(later.imbalanceBusy, static_cast<double>(later.busyFrames));
  }

  double sumRate = 0.0;
  double minRate = std::numeric_limits<double>::infinity();
  for (auto& [rank, r] : k.renders) {
    const auto steadySplats = steady.splatsPerRender.find(rank);
    r.splatsPerSecond = ratio(static_cast<double>(r.splats), totalSeconds);
    r.splatsPerSecondSteady = ratio(steadySplats == steady.splatsPerRender.end()
                                        ? 0.0
                                        : static_cast<double>(steadySplats->second),
                                    steadySpan);
    r.splatsPerBusySecond = ratio(static_cast<double>(r.splats), r.busySeconds);
    r.busyFraction = ratio(r.busySeconds, totalSeconds);
    sumRate += r.splatsPerSecondSteady;
    minRate = std::min(minRate, r.splatsPerSecondSteady);
    k.renderSplatsPerSecondMax = std::max(k.renderSplatsPerSecondMax, r.splatsPerSecondSteady);
  }
  // A render process of the job that never drew counts with 0 splats/s.
  if (k.renders.size() < k.renderProcesses) minRate = 0.0;
  k.renderSplatsPerSecondMin = k.renders.empty() ? 0.0 : minRate;
  k.renderSplatsPerSecondMean = ratio(sumRate, static_cast<double>(k.renderProcesses));

  for (const auto& [rank, samples] : renders) {
    if (samples.empty()) continue;
    const RenderSample& last = samples.back();
    k.cacheHits += last.cacheHits;
    k.cacheMisses += last.cacheMisses;
    k.evictions += last.evictions;
    k.peakCacheBytes = std::max(k.peakCacheBytes, last.peakCacheBytes);
    // The counters are cumulative: subtract those reported before steady state.
    RenderSample before;
    for (const RenderSample& s : samples) {
      if (k.steadyFrom == 0 || s.seconds > steadyBegins) break;
      before = s;
    }
    k.cacheHitsSteady += last.cacheHits - std::min(last.cacheHits, before.cacheHits);
    k.cacheMissesSteady += last.cacheMisses - std::min(last.cacheMisses, before.cacheMisses);
  }
  k.cacheHitRate = ratio(k.cacheHits, k.cacheHits + k.cacheMisses);
  k.cacheHitRateSteady = ratio(k.cacheHitsSteady, k.cacheHitsSteady + k.cacheMissesSteady);
  return k;
}

std::string RunStats::toJson() const {
  std::ostringstream out;
  writeJsonTo(out);
  return out.str();
}

void RunStats::writeJsonTo(std::ostream& out) const {
  out << "{\n  \"layout\": \"" << layout << "\",\n  \"dataset\": \"" << dataset
      << "\",\n  \"camera_path\": \"" << cameraPath << "\",\n  \"width\": " << width
      << ",\n  \"height\": " << height << ",\n  \"mode\": \"" << mode
      << "\",\n  \"total_seconds\": " << number(totalSeconds)
      << ",\n  \"late_tiles\": " << lateTiles << ",\n  \"part_size_tuning\": \""
      << jsonEscaped(partSizeTuning) << "\",\n  \"tile_count_tuning\": \""
      << jsonEscaped(tileCountTuning) << '"'
      << ",\n  \"frames_kept_every\": " << frameThinning.stride << ",\n  \"key_figures\": {";
  bool firstField = true;
  for (const auto& [name, value] : keyFigureFields(keyFigures())) {
    out << (firstField ? "" : ", ") << '"' << name << "\": " << value;
    firstField = false;
  }
  out << "},\n  \"frames\": [\n";
  for (std::size_t i = 0; i < frames.size(); ++i) {
    const FrameRecord& f = frames[i];
    out << "    {\"frame\": " << f.frame << ", \"start\": " << number(f.startSeconds)
        << ", \"end\": " << number(f.endSeconds)
        << ", \"seconds\": " << number(f.endSeconds - f.startSeconds)
        << ", \"splats\": " << f.splats << ", \"tiles\": " << f.tiles
        << ", \"reissued_tiles\": " << f.reissuedTiles << ", \"failed_tiles\": " << f.failedTiles
        << ", \"bytes_sent\": " << f.bytesOrdered << ", \"image_bytes\": " << f.imageBytes
        << ", \"splats_per_render\": {";
    bool first = true;
    for (const auto& [rank, splats] : f.splatsPerRender) {
      out << (first ? "" : ", ") << '"' << rank << "\": " << splats;
      first = false;
    }
    out << "}, \"busy_seconds_per_render\": {";
    first = true;
    for (const auto& [rank, busy] : f.busySecondsPerRender) {
      out << (first ? "" : ", ") << '"' << rank << "\": " << number(busy);
      first = false;
    }
    out << "}}" << (i + 1 < frames.size() ? "," : "") << "\n";
  }
  out << "  ],\n  \"renders\": {\n";
  std::size_t index = 0;
  for (const auto& [rank, samples] : renders) {
    out << "    \"" << rank << "\": [";
    for (std::size_t i = 0; i < samples.size(); ++i) {
      const RenderSample& s = samples[i];
      out << (i ? ", " : "") << "{\"t\": " << number(s.seconds) << ", \"frame\": " << s.frame
          << ", \"workload\": " << s.workloadSplats << ", \"cache_bytes\": " << s.cacheBytes
          << ", \"peak_cache_bytes\": " << s.peakCacheBytes << ", \"hits\": " << s.cacheHits
          << ", \"misses\": " << s.cacheMisses << ", \"evictions\": " << s.evictions
          << ", \"data_bytes\": " << s.dataBytesReceived << "}";
    }
    out << "]" << (++index < renders.size() ? "," : "") << "\n";
  }
  out << "  },\n  \"processes\": [";
  for (std::size_t i = 0; i < processes.size(); ++i) {
    const ProcessCpu& p = processes[i];
    out << (i ? ", " : "") << "{\"role\": \"" << p.role << "\", \"rank\": " << p.rank
        << ", \"cpu_seconds\": " << number(p.cpuSeconds)
        << ", \"wall_seconds\": " << number(p.wallSeconds) << ", \"activities\": {";
    bool first = true;
    for (const auto& [activity, seconds] : p.activities) {
      out << (first ? "" : ", ") << "\"" << activity << "\": " << number(seconds);
      first = false;
    }
    out << "}}";
  }
  out << "],\n  \"lost_processes\": [";
  for (std::size_t i = 0; i < lost.size(); ++i) {
    const LostProcess& p = lost[i];
    out << (i ? ", " : "") << "{\"role\": \"" << p.role << "\", \"rank\": " << p.rank
        << ", \"seconds\": " << number(p.seconds) << ", \"reason\": \"" << jsonEscaped(p.reason)
        << "\", \"job_went_on\": " << (p.jobWentOn ? "true" : "false") << "}";
  }
  out << "]\n}\n";
}

void RunStats::writeJson(const std::filesystem::path& file) const {
  AtomicFile out(file, "statistics");
  writeJsonTo(out.stream());
  out.commit();
}

// Four CSV files with a header line each; times in seconds since the run
// began, bytes and splats as counts. An imbalance is empty when undefined (no
// render process was busy in that frame).
//   frames.csv: frame,start,end,seconds,splats,tiles,reissued,failed,bytes_sent,
//               max_render_busy,mean_render_busy,imbalance_busy,imbalance_splats
//   renders.csv: t,frame,render_rank,workload,cache_bytes,hits,misses,evictions,
//                data_bytes (one line per tile that came back, grouped by render
//                rank, in time order; hits, misses, evictions and data_bytes are
//                totals since the start)
//   per_frame_render.csv: frame,render_rank,splats,busy_seconds
//   figures.csv: one line of keyFigures(), the columns of keyFigureFields()
void RunStats::writeCsv(const std::filesystem::path& dir) const {
  AtomicFile framesFile(dir / "frames.csv", "frame statistics");
  AtomicFile rendersFile(dir / "renders.csv", "render statistics");
  AtomicFile perFrameFile(dir / "per_frame_render.csv", "per-frame render statistics");
  AtomicFile tilesFile(dir / "tiles.csv", "tile statistics");
  std::ostream& framesCsv = framesFile.stream();
  std::ostream& rendersCsv = rendersFile.stream();
  std::ostream& perFrameCsv = perFrameFile.stream();
  std::ostream& tilesCsv = tilesFile.stream();
  framesCsv << "frame,start,end,seconds,splats,tiles,reissued,failed,bytes_sent,max_render_busy,"
               "mean_render_busy,imbalance_busy,imbalance_splats,bytes_prefetched,image_bytes\n";
  perFrameCsv << "frame,render_rank,splats,busy_seconds\n";
  for (const FrameRecord& f : frames) {
    const FrameBalance b = balance(f);
    framesCsv << f.frame << ',' << number(f.startSeconds) << ',' << number(f.endSeconds) << ','
              << number(f.endSeconds - f.startSeconds) << ',' << f.splats << ',' << f.tiles << ','
              << f.reissuedTiles << ',' << f.failedTiles << ',' << f.bytesOrdered << ','
              << number(b.maxBusySeconds) << ',' << number(b.meanBusySeconds) << ','
              << optionalNumber(b.busy) << ',' << optionalNumber(b.splats) << ','
              << f.bytesPrefetched << ',' << f.imageBytes << '\n';
    std::map<int, std::pair<std::uint64_t, double>> perRender;
    for (const auto& [rank, s] : f.splatsPerRender) perRender[rank].first = s;
    for (const auto& [rank, busy] : f.busySecondsPerRender) perRender[rank].second = busy;
    for (const auto& [rank, work] : perRender) {
      perFrameCsv << f.frame << ',' << rank << ',' << work.first << ',' << number(work.second)
                  << '\n';
    }
  }
  rendersCsv << "t,frame,render_rank,workload,cache_bytes,hits,misses,evictions,data_bytes\n";
  for (const auto& [rank, samples] : renders) {
    for (const RenderSample& s : samples) {
      rendersCsv << number(s.seconds) << ',' << s.frame << ',' << rank << ',' << s.workloadSplats
                 << ',' << s.cacheBytes << ',' << s.cacheHits << ',' << s.cacheMisses << ','
                 << s.evictions << ',' << s.dataBytesReceived << '\n';
    }
  }
  tilesCsv << "frame,tile,attempt,render_rank,traverse_rank,dispatched,arrived,queued_seconds,"
              "data_wait_seconds,render_seconds,splats,pixels,ordered_bytes,prefetch_bytes\n";
  for (const TileRecord& t : tiles) {
    tilesCsv << t.frame << ',' << t.tile << ',' << t.attempt << ',' << t.renderRank << ','
             << t.traverseRank << ',' << number(t.dispatchedSeconds) << ','
             << number(t.arrivedSeconds) << ',' << number(t.queuedSeconds) << ','
             << number(t.dataWaitSeconds) << ',' << number(t.renderSeconds) << ',' << t.splats
             << ',' << t.pixels << ',' << t.orderedBytes << ',' << t.prefetchBytes << '\n';
  }
  std::string header, row;
  for (const auto& [name, value] : keyFigureFields(keyFigures())) {
    header += (header.empty() ? "" : ",") + name;
    row += (row.empty() ? "" : ",") + value;
  }
  framesFile.commit();
  rendersFile.commit();
  perFrameFile.commit();
  tilesFile.commit();
  writeFile(dir / "figures.csv", header + "\n" + row + "\n", "key figures");
}

std::string RunStats::summary() const {
  const KeyFigures k = keyFigures();
  std::ostringstream out;
  char line[512];
  std::snprintf(
      line, sizeof line,
      "frames: %zu in %.2f s: %.2f frames/s overall, %.2f frames/s steady (from frame %zu)\n",
      k.frames, k.totalSeconds, k.framesPerSecond, k.framesPerSecondSteady, k.steadyFrom);
  out << line;
  std::snprintf(line, sizeof line, "splats: %.2f M per frame, %.2f M splats/s overall\n",
                k.splatsPerFrame / 1e6, k.splatsPerSecond / 1e6);
  out << line;
  for (const auto& [rank, r] : k.renders) {
    std::snprintf(line, sizeof line,
                  "  render rank %d: %.2f M splats, %.2f M splats/s of wall time (%.2f M steady), "
                  "%.2f M splats/s while busy (%.0f%% busy)\n",
                  rank, static_cast<double>(r.splats) / 1e6, r.splatsPerSecond / 1e6,
                  r.splatsPerSecondSteady / 1e6, r.splatsPerBusySecond / 1e6,
                  100.0 * r.busyFraction);
    out << line;
  }
  std::snprintf(line, sizeof line,
                "splats/s per render (steady, wall time): mean %.2f M, min %.2f M, max %.2f M "
                "over %zu render processes\n",
                k.renderSplatsPerSecondMean / 1e6, k.renderSplatsPerSecondMin / 1e6,
                k.renderSplatsPerSecondMax / 1e6, k.renderProcesses);
  out << line;
  if (k.imbalanceFrames > 0) {
    std::snprintf(line, sizeof line,
                  "imbalance (steady, max/mean per frame): busy time %.2f, splats %.2f; "
                  "busy time over the run %.2f\n",
                  k.imbalanceBusy, k.imbalanceSplats, k.imbalanceBusyRun);
    out << line;
  }
  std::snprintf(line, sizeof line,
                "bytes sent: %.2f MiB total, first frame %.2f MiB, %.3f MiB per frame steady "
                "(%.3f MiB another render held: work moved); tile images %.3f MiB per frame "
                "steady",
                static_cast<double>(k.bytesTotal) / 1048576.0,
                static_cast<double>(k.bytesFirstFrame) / 1048576.0,
                k.bytesPerFrameSteady / 1048576.0, k.bytesHeldElsewherePerFrameSteady / 1048576.0,
                k.imageBytesPerFrameSteady / 1048576.0);
  out << line;
  if (k.imageBytesUncompressedPerFrameSteady > k.imageBytesPerFrameSteady) {
    std::snprintf(line, sizeof line, " (compressed from %.3f MiB, %.2f times)",
                  k.imageBytesUncompressedPerFrameSteady / 1048576.0,
                  k.imageBytesUncompressedPerFrameSteady / k.imageBytesPerFrameSteady);
    out << line;
  }
  out << '\n';
  if (k.laterLoopsFrom > 0) {
    std::snprintf(line, sizeof line,
                  "later loops (from frame %zu, every view seen once): %.2f frames/s, %.3f MiB "
                  "per frame (%.3f MiB another render held), tile images %.3f MiB per frame, "
                  "imbalance %.2f\n",
                  k.laterLoopsFrom, k.framesPerSecondLaterLoops,
                  k.bytesPerFrameLaterLoops / 1048576.0,
                  k.bytesHeldElsewherePerFrameLaterLoops / 1048576.0,
                  k.imageBytesPerFrameLaterLoops / 1048576.0, k.imbalanceBusyLaterLoops);
    out << line;
  }
  std::snprintf(line, sizeof line,
                "cache: hit rate %.1f%% (%llu hits, %llu misses), %.1f%% steady, %llu evictions, "
                "peak %.2f MiB on one render\n",
                100.0 * k.cacheHitRate, static_cast<unsigned long long>(k.cacheHits),
                static_cast<unsigned long long>(k.cacheMisses), 100.0 * k.cacheHitRateSteady,
                static_cast<unsigned long long>(k.evictions),
                static_cast<double>(k.peakCacheBytes) / 1048576.0);
  out << line;
  std::snprintf(
      line, sizeof line,
      "tiles: %llu re-issued, %llu failed, %llu late, %llu split into %llu parts, %llu empty "
      "(background from the traverse), %llu handed out avoiding a silent render\n",
      static_cast<unsigned long long>(k.reissuedTiles),
      static_cast<unsigned long long>(k.failedTiles), static_cast<unsigned long long>(k.lateTiles),
      static_cast<unsigned long long>(k.splitTiles), static_cast<unsigned long long>(k.tileParts),
      static_cast<unsigned long long>(k.backgroundTiles),
      static_cast<unsigned long long>(k.avoidingTasks));
  out << line;
  if (k.requestWaitShare > 0.0) {
    std::snprintf(line, sizeof line,
                  "tiles: waited for a traverse process to ask %.1f%% of the run\n",
                  100.0 * k.requestWaitShare);
    out << line;
  }
  if (k.planMsPerFrame > 0.0) {
    std::snprintf(line, sizeof line, "tiles: laid out in %.3f ms a frame on the display\n",
                  k.planMsPerFrame);
    out << line;
  }
  if (!tileCountTuning.empty()) out << "tiles: " << tileCountTuning << "\n";
  if (!partSizeTuning.empty()) out << "parts: " << partSizeTuning << "\n";
  for (const LostProcess& p : lost) {
    std::snprintf(line, sizeof line, "lost: %s rank %d at %.2f s (%s)%s\n", p.role.c_str(), p.rank,
                  p.seconds, p.reason.c_str(),
                  p.jobWentOn ? "; the job went on without it" : "; the job ended");
    out << line;
  }
  if (!processes.empty()) {
    std::snprintf(line, sizeof line,
                  "cpu per frame: %.1f core-ms in all: display %.1f, traverse %.1f, data-send "
                  "%.1f, render %.1f (of which drawing %.1f)\n",
                  1e3 * k.cpuPerFrameTotal, 1e3 * cpuOf(k, "display"), 1e3 * cpuOf(k, "traverse"),
                  1e3 * cpuOf(k, "datasend"), 1e3 * cpuOf(k, "render"), 1e3 * k.drawPerFrame);
    out << line;
    for (const auto& [role, activities] : k.cpuPerFrameByActivity) {
      // Largest first: where the role's CPU goes.
      std::vector<std::pair<double, std::string>> sorted;
      for (const auto& [activity, seconds] : activities) sorted.emplace_back(seconds, activity);
      std::sort(sorted.rbegin(), sorted.rend());
      out << "  " << role << " core-ms per frame:";
      for (std::size_t i = 0; i < sorted.size(); ++i) {
        std::snprintf(line, sizeof line, "%s %s %.1f", i == 0 ? "" : ",", sorted[i].second.c_str(),
                      1e3 * sorted[i].first);
        out << line;
      }
      out << "\n";
    }
  }
  return out.str();
}

}  // namespace pointillist::display
