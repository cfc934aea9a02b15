// pointillist-preprocess: point clouds, meshes or a generated scene in, a
// dataset directory (octree-cell-array, top-level table, point-array with
// level-splats; seed 003 §4.1) out.
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <atomic>
#include <cctype>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <iostream>
#include <new>
#include <optional>
#include <span>
#include <string>
#include <thread>
#include <vector>

#include "common/dataset.hpp"
#include "common/dataset_writer.hpp"
#include "common/errors.hpp"
#include "common/instanced_section.hpp"
#include "preprocess/dataset_builder.hpp"
#include "preprocess/generator.hpp"
#include "preprocess/out_of_core.hpp"
#include "preprocess/readers.hpp"

namespace pp = pointillist::preprocess;
using pointillist::Error;
using pointillist::InputError;
using pointillist::UsageError;
using Clock = std::chrono::steady_clock;

namespace {

constexpr const char* kTool = "pointillist-preprocess";

std::atomic<int> gInterrupted{0};

extern "C" void onSignal(int sig) {
  // The first signal asks for a clean stop at the next progress report (the
  // temporary dataset directory is removed on the way out); a second one kills.
  if (gInterrupted.exchange(sig) != 0) {
    std::signal(sig, SIG_DFL);
    std::raise(sig);
  }
}

class Interrupted : public Error {
 public:
  using Error::Error;
  const char* kind() const noexcept override { return "interrupted"; }
};

double seconds(Clock::time_point since) {
  return std::chrono::duration<double>(Clock::now() - since).count();
}

std::string humanCount(double v) {
  char buf[32];
  if (v >= 1e9)
    std::snprintf(buf, sizeof buf, "%.2fG", v / 1e9);
  else if (v >= 1e6)
    std::snprintf(buf, sizeof buf, "%.2fM", v / 1e6);
  else if (v >= 1e4)
    std::snprintf(buf, sizeof buf, "%.1fk", v / 1e3);
  else
    std::snprintf(buf, sizeof buf, "%.0f", v);
  return buf;
}

std::string humanBytes(double v) {
  char buf[32];
  if (v >= 1024.0 * 1024 * 1024)
    std::snprintf(buf, sizeof buf, "%.2f GiB", v / (1024.0 * 1024 * 1024));
  else if (v >= 1024.0 * 1024)
    std::snprintf(buf, sizeof buf, "%.1f MiB", v / (1024.0 * 1024));
  else
    std::snprintf(buf, sizeof buf, "%.1f KiB", v / 1024.0);
  return buf;
}

// Progress on stderr: one updating line on a terminal (at most 10 times a
// second), otherwise a plain line every 5 seconds. Also where an interrupt is
// noticed.
class Progress {
 public:
  explicit Progress(bool quiet) : quiet_(quiet), tty_(::isatty(STDERR_FILENO) != 0) {}

  void update(const std::string& stage, std::uint64_t done, std::uint64_t total) {
    // Only the main thread may throw: a worker thread would terminate the process.
    if (const int sig = gInterrupted.load(); sig != 0 && std::this_thread::get_id() == mainThread_)
      throw Interrupted("stopped by signal " + std::to_string(sig) + "; nothing was written");
    if (quiet_ || std::this_thread::get_id() != mainThread_) return;
    const auto now = Clock::now();
    if (stage != stage_) {
      finishStage();
      stage_ = stage;
      stageStart_ = now;
      last_ = {};
    }
    // Terminal: refresh at most 10 times a second. Log: a line every 5 s of a
    // long stage; short stages only get their "done" line.
    if (tty_ ? (now - last_ < std::chrono::milliseconds(100) && done < total)
             : (now - (last_ == Clock::time_point{} ? stageStart_ : last_) <
                std::chrono::seconds(5)))
      return;
    last_ = now;
    // Reading stages count bytes of input, the others points.
    const bool bytes =
        stage == "reading" || stage == "bounds" || stage == "spilling" || stage == "writing";
    const auto amount = [bytes](double v) { return bytes ? humanBytes(v) : humanCount(v); };
    const double elapsed = seconds(stageStart_);
    const double rate = elapsed > 0.2 ? static_cast<double>(done) / elapsed : 0.0;
    std::string line = "  " + stage + ": ";
    if (total > 0) {
      const double share = std::min(1.0, static_cast<double>(done) / static_cast<double>(total));
      constexpr int kBar = 24;
      const int filled = static_cast<int>(share * kBar);
      char pct[16];
      std::snprintf(pct, sizeof pct, "%5.1f%%", 100.0 * share);
      line += "[" + std::string(static_cast<std::size_t>(filled), '#') +
              std::string(static_cast<std::size_t>(kBar - filled), '.') + "] " + pct + " " +
              amount(static_cast<double>(done)) + " / " + amount(static_cast<double>(total));
      if (rate > 0.0) {
        line += ", " + amount(rate) + (bytes ? "/s" : " points/s");
        char eta[32];
        std::snprintf(eta, sizeof eta, ", %.0f s left",
                      static_cast<double>(total - std::min(done, total)) / rate);
        line += eta;
      }
    } else {
      line += amount(static_cast<double>(done));
    }
    if (tty_) {
      std::fprintf(stderr, "\r%s\x1b[K", line.c_str());
      open_ = true;
    } else {
      std::fprintf(stderr, "%s\n", line.c_str());
    }
    std::fflush(stderr);
  }

  // Ends the current stage with its duration.
  void finishStage() {
    if (quiet_ || stage_.empty()) return;
    char buf[64];
    std::snprintf(buf, sizeof buf, "%.2f s", seconds(stageStart_));
    if (tty_ && open_)
      std::fprintf(stderr, "\r  %s: done in %s\x1b[K\n", stage_.c_str(), buf);
    else
      std::fprintf(stderr, "  %s: done in %s\n", stage_.c_str(), buf);
    stage_.clear();
    open_ = false;
  }

  void note(const std::string& text) {
    if (quiet_) return;
    finishStage();
    std::fprintf(stderr, "%s: %s\n", kTool, text.c_str());
  }

  pp::ProgressFn stageFn(const std::string& stage) {
    return [this, stage](std::uint64_t done, std::uint64_t total) { update(stage, done, total); };
  }

 private:
  bool quiet_;
  bool tty_;
  std::thread::id mainThread_ = std::this_thread::get_id();
  bool open_ = false;
  std::string stage_;
  Clock::time_point stageStart_{};
  Clock::time_point last_{};
};

struct Options {
  std::vector<std::string> inputs;
  std::string output;
  std::string generate;
  std::size_t points = 1'000'000;
  int topLevelDepth = -1;
  unsigned maxDepth = pp::OctreeOptions{}.maxDepth;
  std::uint32_t leafPoints = pp::OctreeOptions{}.leafPoints;
  std::uint64_t packetKiB = pp::kDefaultPacketBytes / 1024;
  int neighbours = 12;
  bool knnRadii = false;
  std::string neighbourSearch = "grid";
  std::string normals = "auto";
  double cubePoints = pp::kMomentPointsPerCube;
  bool dropNonFinite = false;
  std::uint64_t seed = 1;
  unsigned threads = 0;
  std::uint64_t memoryMb = 0;  // 0: defaultMemoryMb()
  bool quiet = false;
  bool force = false;
  std::string check;  // verify this dataset instead of building one
  bool instanced = false;
  pp::InstancingOptions instancing;
  bool statistical = false;
  pp::StatisticalOptions statisticalOptions;
};

// New FFT shapes are measured after the run (a few seconds at most) so the
// next --instanced run plans them at once.
void saveWisdom(const Options& o) {
  const auto start = Clock::now();
  const std::size_t measured = pp::saveFftWisdom();
  if (measured > 0 && !o.quiet)
    std::fprintf(stderr, "%s: measured %zu new FFT shapes for later runs in %.1f s\n", kTool,
                 measured, seconds(start));
}

// --instanced's closing lines: coverage and bytes in the paper's accounting.
void printInstancingSummary(const pp::InstancingStats& s, std::uint64_t topLevelCount) {
  const double points = static_cast<double>(std::max<std::uint64_t>(s.points, 1));
  const double covered = static_cast<double>(std::max<std::uint64_t>(s.covered, 1));
  std::printf(
      "%s: instanced: %.1f %% of %s points generated by %llu pools in %llu of %llu instancing "
      "units (%llu vertices, %llu translations); sections %s against %s as plain splats "
      "(%.2fx smaller) -- vertices %s, translations %s, tags %s; colour error on generated "
      "points mean %.2f, max %d of 255; position error max %.3g; FFT %.2f s (%.2f ms per unit, "
      "%zu shapes planned)\n",
      kTool, 100.0 * static_cast<double>(s.covered) / points, humanCount(points).c_str(),
      static_cast<unsigned long long>(s.pools), static_cast<unsigned long long>(s.cellsInstanced),
      static_cast<unsigned long long>(s.cells), static_cast<unsigned long long>(s.vertices),
      static_cast<unsigned long long>(s.translations),
      humanBytes(static_cast<double>(s.sectionBytes)).c_str(),
      humanBytes(static_cast<double>(s.plainBytes)).c_str(),
      static_cast<double>(s.plainBytes) /
          static_cast<double>(std::max<std::uint64_t>(s.sectionBytes, 1)),
      humanBytes(static_cast<double>(s.vertexBytes)).c_str(),
      humanBytes(static_cast<double>(s.translationBytes)).c_str(),
      humanBytes(static_cast<double>(s.tagBytes)).c_str(), s.colorErrorSum / covered,
      s.colorErrorMax, s.positionErrorMax, s.fftSeconds,
      1000.0 * s.fftSeconds / static_cast<double>(std::max<std::uint64_t>(s.cellsInstanced, 1)),
      pp::fftPlansMade());
  const double cells = static_cast<double>(std::max<std::uint64_t>(topLevelCount, 1));
  std::printf(
      "%s: instanced: per top-level cell: points as sections %s (vertices %s, translations %s, "
      "tags %s, plain remainder and headers %s) against %s as plain splats\n",
      kTool, humanBytes(static_cast<double>(s.sectionBytes) / cells).c_str(),
      humanBytes(static_cast<double>(s.vertexBytes) / cells).c_str(),
      humanBytes(static_cast<double>(s.translationBytes) / cells).c_str(),
      humanBytes(static_cast<double>(s.tagBytes) / cells).c_str(),
      humanBytes(
          static_cast<double>(s.sectionBytes - s.vertexBytes - s.translationBytes - s.tagBytes) /
          cells)
          .c_str(),
      humanBytes(static_cast<double>(s.plainBytes) / cells).c_str());
}

// --statistical's closing line: the hierarchy and its bytes in the paper's accounting.
void printStatisticalSummary(const pp::StatisticalStats& s) {
  const double points = static_cast<double>(std::max<std::uint64_t>(s.points, 1));
  const double nodes = static_cast<double>(s.nodes);
  std::printf(
      "%s: statistical: %s nodes (%s leaves, %.1f points per leaf, depth %u, %llu Euclidean "
      "splits) in %s + classes %s: %.2f bits per point for position and normal (13 of 18 bytes "
      "a node), %.2f with colour and flags; decoded mean error rms %.5f, max %.4f of the "
      "parent's sigma (%llu means clamped to their parent's range); sigma error rms %.1f %%; "
      "tree %.2f s, classes %.2f s, encoding %.2f s\n",
      kTool, humanCount(nodes).c_str(), humanCount(static_cast<double>(s.leaves)).c_str(),
      points / static_cast<double>(std::max<std::uint64_t>(s.leaves, 1)), s.maxDepth,
      static_cast<unsigned long long>(s.euclideanSplits),
      humanBytes(static_cast<double>(s.packetBytes)).c_str(),
      humanBytes(static_cast<double>(s.classBytes)).c_str(), nodes * 13 * 8 / points,
      nodes * 18 * 8 / points, s.meanErrorRms, s.meanErrorMax,
      static_cast<unsigned long long>(s.clampedMeans), 100.0 * s.sigmaLogErrorRms, s.treeSeconds,
      s.classSeconds, s.encodeSeconds);
}

// Opens the dataset as a traverse would (manifest, sizes, cell array), then
// reads every packet once and verifies its checksum, one packet in memory at
// a time. Throws InputError naming the file and the problem.
int checkDataset(const std::string& dir) {
  const auto start = Clock::now();
  const auto dataset = pointillist::Dataset::open(dir, pointillist::DatasetParts::Cells);
  // --instanced: every unit's section parses and generates its unit's points,
  // and the sections of a packet tile its section records.
  struct Unit {
    std::uint32_t offset, records, cell;
    bool operator<(const Unit& o) const { return offset < o.offset; }
  };
  const auto table = dataset.topLevelCells();
  const auto cells = dataset.cells();
  std::vector<std::vector<Unit>> units(table.size());
  if (dataset.manifest().file(pointillist::kInstancedSectionsKey) != nullptr) {
    const auto bytes = dataset.readFile(pointillist::kInstancedSectionsKey);
    const std::string file = dir + "/" + pointillist::kInstancedSectionsName;
    if (bytes.size() != cells.size() * sizeof(pointillist::InstancedCellSection))
      throw InputError(file + ": " + std::to_string(bytes.size()) + " bytes for " +
                       std::to_string(cells.size()) + " cells");
    for (std::size_t i = 0; i < cells.size(); ++i) {
      pointillist::InstancedCellSection entry;
      std::memcpy(&entry, bytes.data() + i * sizeof entry, sizeof entry);
      if (entry.records == 0) continue;
      if (cells[i].topLevel >= table.size())
        throw InputError(file + ": cell " + std::to_string(i) + " has a section but no packet");
      units[cells[i].topLevel].push_back(
          {entry.offset, entry.records, static_cast<std::uint32_t>(i)});
    }
  } else if (dataset.manifest().instancedRecordCount > 0) {
    throw InputError(dir + ": instanced records but no " + pointillist::kInstancedSectionsName);
  }
  std::uint64_t records = 0, sections = 0;
  for (std::uint32_t k = 0; k < table.size(); ++k) {
    const std::vector<pointillist::Splat> packet = dataset.readTopLevel(k);
    records += packet.size();
    std::sort(units[k].begin(), units[k].end());
    std::uint64_t next = table[k].levelSplatCount;
    for (const Unit& u : units[k]) {
      const std::string where = dir + ": cell " + std::to_string(u.cell) + "'s section";
      if (u.offset != next || std::uint64_t{u.offset} + u.records > pointsStart(table[k]))
        throw InputError(where + " at records [" + std::to_string(u.offset) + ", +" +
                         std::to_string(u.records) + ") does not follow the one before (" +
                         std::to_string(next) + ") inside the packet's sections");
      const auto view = pointillist::parseInstancedSection(
          std::span<const pointillist::Splat>(packet).subspan(u.offset, u.records), where.c_str());
      if (std::uint64_t{view.header.generatedCount} + view.remainder.size() !=
          cells[u.cell].pointsCount)
        throw InputError(where + " stands for " +
                         std::to_string(view.header.generatedCount + view.remainder.size()) +
                         " points, the cell holds " + std::to_string(cells[u.cell].pointsCount));
      next += u.records;
      ++sections;
    }
    if (!units[k].empty() && next != pointsStart(table[k]))
      throw InputError(dir + ": top-level cell " + std::to_string(k) +
                       "'s sections end at record " + std::to_string(next) +
                       ", its points start at " + std::to_string(pointsStart(table[k])));
  }
  // --statistical: every statistical packet decodes whole against the classes
  // and stands for its top-level cell's points.
  std::uint64_t statisticalNodes = 0;
  if (dataset.hasStatistical()) {
    const pointillist::ClassTables classes = dataset.readStatisticalClasses();
    for (std::uint32_t k = 0; k < table.size(); ++k) {
      const std::uint32_t id = dataset.statisticalPacketId(k);
      const std::vector<pointillist::Splat> packet = dataset.readTopLevel(id);
      records += packet.size();
      const std::string where = dir + "/" + pointillist::kStatisticalPacketsName +
                                ": top-level cell " + std::to_string(k);
      const auto view = pointillist::decodeStatisticalPacket(packet, classes, where);
      if (view.nodes.size() != view.header.nodeCount ||
          view.header.pointCount != table[k].pointCount)
        throw InputError(where + ": " + std::to_string(view.nodes.size()) + " of " +
                         std::to_string(view.header.nodeCount) + " nodes stand for " +
                         std::to_string(view.header.pointCount) + " points, the cell holds " +
                         std::to_string(table[k].pointCount));
      statisticalNodes += view.nodes.size();
    }
  }
  const auto& m = dataset.manifest();
  if (dataset.hasStatistical())
    std::printf("%s: statistical: %llu nodes in %u packets decode against the class tables\n",
                kTool, static_cast<unsigned long long>(statisticalNodes),
                static_cast<unsigned>(table.size()));
  std::printf(
      "%s: %s is a sound dataset (format %u): %llu points, %llu level-splats, %llu instanced "
      "records (%llu sections), %llu cells, %llu top-level cells; every packet's checksum verified "
      "(%llu "
      "records) in %.2f s\n",
      kTool, dir.c_str(), m.formatVersion, static_cast<unsigned long long>(m.pointCount),
      static_cast<unsigned long long>(m.levelSplatCount),
      static_cast<unsigned long long>(m.instancedRecordCount),
      static_cast<unsigned long long>(sections), static_cast<unsigned long long>(m.cellCount),
      static_cast<unsigned long long>(m.topLevelCount), static_cast<unsigned long long>(records),
      seconds(start));
  return 0;
}

// The default cap: 60 % of the machine's memory, leaving room for the page
// cache the spill files and the output go through.
std::uint64_t defaultMemoryMb() {
  const long pages = ::sysconf(_SC_PHYS_PAGES);
  const long pageSize = ::sysconf(_SC_PAGE_SIZE);
  if (pages <= 0 || pageSize <= 0) return 4096;
  return static_cast<std::uint64_t>(pages) * static_cast<std::uint64_t>(pageSize) / 100 * 60 >> 20;
}

// An upper bound of the points the inputs hold without reading them: a point
// takes at least 12 bytes in any format (binary x, y, z floats); a mesh gives
// its sample count.
std::uint64_t estimatePoints(const std::vector<std::string>& inputs, std::uint64_t meshPoints) {
  std::uint64_t points = 0;
  for (const auto& in : inputs) {
    std::error_code ec;
    const std::uint64_t size = std::filesystem::file_size(in, ec);
    std::string ext = std::filesystem::path(in).extension().string();
    for (auto& ch : ext) ch = static_cast<char>(std::tolower(static_cast<unsigned char>(ch)));
    points += ext == ".off" ? meshPoints : (ec ? 0 : size / 12);
  }
  return points;
}

// The closing line of a run: what was written, how big, how fast; `tail`
// adds what the path (in memory or out of core) has to say.
void printSummary(const Options& o, const pointillist::DatasetManifest& m, std::uint64_t bytes,
                  std::uint64_t points, double seconds, const char* tail) {
  std::printf(
      "%s: wrote %s: %llu points, %llu cells (depth %u), %llu top-level cells (depth %u, %s per "
      "packet), %llu level-splats, %s in %.2f s (%s points/s%s)\n",
      kTool, o.output.c_str(), static_cast<unsigned long long>(m.pointCount),
      static_cast<unsigned long long>(m.cellCount), m.treeDepth,
      static_cast<unsigned long long>(m.topLevelCount), m.topLevelDepth,
      humanBytes(static_cast<double>(m.pointCount + m.levelSplatCount) *
                 sizeof(pointillist::Splat) / static_cast<double>(m.topLevelCount))
          .c_str(),
      static_cast<unsigned long long>(m.levelSplatCount),
      humanBytes(static_cast<double>(bytes)).c_str(), seconds,
      humanCount(static_cast<double>(points) / seconds).c_str(), tail);
}

pp::NeighbourSearch neighbourSearchOf(const Options& o) {
  if (o.neighbourSearch == "grid") return pp::NeighbourSearch::Grid;
  if (o.neighbourSearch == "kdtree") return pp::NeighbourSearch::KdTree;
  throw UsageError("--neighbour-search must be grid or kdtree, not '" + o.neighbourSearch + "'");
}

pp::NormalMethod normalMethodOf(const Options& o) {
  if (o.normals == "knn") return pp::NormalMethod::Neighbours;
  if (o.normals == "moments") return pp::NormalMethod::Moments;
  if (o.normals == "auto") return pp::NormalMethod::Auto;
  throw UsageError("--normals must be auto, knn or moments, not '" + o.normals + "'");
}

int runOutOfCore(const Options& o, Progress& progress, Clock::time_point start) {
  pp::OutOfCoreOptions oc;
  oc.build.octree.maxDepth = o.maxDepth;
  oc.build.octree.leafPoints = o.leafPoints;
  oc.build.topLevelDepth = o.topLevelDepth;
  oc.build.targetPacketBytes = o.packetKiB * 1024;
  oc.build.radiusNeighbours = o.neighbours;
  oc.build.threads = o.threads;
  oc.build.neighbourSearch = neighbourSearchOf(o);
  oc.build.normalMethod = normalMethodOf(o);
  oc.build.cubePoints = o.cubePoints;
  pp::InstancingStats instancingStats;
  if (o.instanced) {
    oc.build.instancing = o.instancing;
    oc.build.instancingStats = &instancingStats;
  }
  oc.read.meshSamplePoints = o.points;
  oc.read.seed = o.seed;
  oc.read.dropNonFinite = o.dropNonFinite;
  oc.memoryBytes = o.memoryMb << 20;
  oc.neighbours = o.neighbours;
  oc.knnRadii = o.knnRadii;
  oc.overwrite = o.force;
  oc.createdBy = std::string(kTool) + " (max depth " + std::to_string(o.maxDepth) +
                 ", leaf points " + std::to_string(o.leafPoints) + ")";
  progress.note("out of core under --memory-mb " + std::to_string(o.memoryMb) +
                ": spilling to temporary files next to " + o.output);
  const std::vector<std::filesystem::path> files(o.inputs.begin(), o.inputs.end());
  const pp::OutOfCoreResult r = pp::preprocessOutOfCore(
      files, o.output, oc, [&](const char* stage, std::uint64_t done, std::uint64_t total) {
        progress.update(stage, done, total);
      });
  progress.finishStage();
  if (r.capExceeded)
    std::fprintf(stderr,
                 "%s: warning: a top-level cell held %llu points, more than a chunk under "
                 "--memory-mb %llu may (%llu); memory went above the cap for it\n",
                 kTool, static_cast<unsigned long long>(r.largestChunkPoints),
                 static_cast<unsigned long long>(o.memoryMb),
                 static_cast<unsigned long long>(r.chunkCapacity));
  char tail[160];
  std::snprintf(tail, sizeof tail,
                "; out of core: %llu chunks of at most %s points, %llu spill "
                "files, %s spilled",
                static_cast<unsigned long long>(r.chunks),
                humanCount(static_cast<double>(r.largestChunkPoints)).c_str(),
                static_cast<unsigned long long>(r.spillFiles),
                humanBytes(static_cast<double>(r.spillBytes)).c_str());
  printSummary(o, r.manifest, r.bytesWritten, r.points, seconds(start), tail);
  if (o.instanced) {
    printInstancingSummary(instancingStats, r.manifest.topLevelCount);
    saveWisdom(o);
  }
  return 0;
}

void appendCloud(pp::PointCloud& into, pp::PointCloud&& more) {
  if (into.splats.empty()) {
    into = std::move(more);
    return;
  }
  into.splats.insert(into.splats.end(), more.splats.begin(), more.splats.end());
  into.hasNormals = into.hasNormals && more.hasNormals;
  into.hasRadii = into.hasRadii && more.hasRadii;
  into.hasColors = into.hasColors || more.hasColors;
  into.source += ", " + more.source;
}

int run(const Options& o) {
  if (!o.check.empty()) {
    if (!o.inputs.empty() || !o.generate.empty() || !o.output.empty()) {
      throw UsageError("--check takes a dataset directory and nothing to build");
    }
    return checkDataset(o.check);
  }
  if (o.output.empty())
    throw UsageError("-o/--output is required: the dataset directory to create");
  const auto start = Clock::now();
  if (o.inputs.empty() && o.generate.empty())
    throw UsageError("no input: give INPUT files and/or --generate [NAME] (scenes: " + [] {
      std::string names;
      for (const auto& n : pp::generatorNames()) names += (names.empty() ? "" : ", ") + n;
      return names;
    }() + ")");
  if (o.points == 0) throw UsageError("--points must be positive");
  if (o.memoryMb == 0) throw UsageError("--memory-mb must be positive");
  if (o.neighbours < 3) throw UsageError("--neighbours must be at least 3");
  neighbourSearchOf(o);  // refuses a bad name before any reading
  normalMethodOf(o);
  // Past 64 a block of 27 cubes holds thousands of points: no longer a
  // neighbourhood, and below 0.5 most blocks hold too few for a plane.
  if (!(o.cubePoints >= 0.5 && o.cubePoints <= 64.0))
    throw UsageError("--cube-points must be 0.5..64, not " + std::to_string(o.cubePoints));
  if (o.packetKiB == 0) throw UsageError("--packet-kib must be positive");
  if (o.maxDepth < 1 || o.maxDepth > 21) throw UsageError("--max-depth must be 1..21");
  if (o.leafPoints < 1) throw UsageError("--leaf-points must be positive");
  if (o.topLevelDepth < -1) throw UsageError("--top-level-depth must not be negative");
  const std::filesystem::path output(o.output);
  std::error_code ec;
  if (std::filesystem::exists(std::filesystem::symlink_status(output, ec)) && !o.force)
    throw UsageError("output '" + o.output + "' already exists (use --force to replace it)");

  // A generated scene exists whole in memory (its points depend on the total
  // count): over the cap it is refused before any work, not built past it.
  if (!o.generate.empty()) {
    const std::uint64_t total = estimatePoints(o.inputs, o.points) + o.points;
    if (!pp::fitsInMemory(o.memoryMb << 20, total))
      throw UsageError("--generate builds its scene in memory: " + std::to_string(total) +
                       " points need about " + std::to_string(pp::inMemoryBytes(total) >> 20) +
                       " MiB, more than --memory-mb " + std::to_string(o.memoryMb) +
                       ". Lower --points, raise --memory-mb, or write the scene to a file in "
                       "blocks (pointillist-make-points --generate " +
                       o.generate + ") and preprocess that file, out of core");
  }

  Progress progress(o.quiet);
  if (o.generate.empty() &&
      !pp::fitsInMemory(o.memoryMb << 20, estimatePoints(o.inputs, o.points))) {
    if (o.statistical)
      throw UsageError(
          "--statistical needs the whole input in memory (its class tables are "
          "global); this input may not fit under --memory-mb " +
          std::to_string(o.memoryMb) + ": raise it");
    return runOutOfCore(o, progress, start);
  }
  pp::PointCloud cloud;
  if (!o.inputs.empty()) {
    pp::ReadOptions ro;
    ro.meshSamplePoints = o.points;
    ro.seed = o.seed;
    ro.dropNonFinite = o.dropNonFinite;
    ro.progress = progress.stageFn("reading");
    std::vector<std::filesystem::path> files(o.inputs.begin(), o.inputs.end());
    cloud = pp::readPointClouds(files, ro);
    progress.finishStage();
  }
  if (!o.generate.empty()) {
    progress.update("generating '" + o.generate + "'", 0, o.points);
    appendCloud(cloud, pp::generateScene(o.generate, o.points, o.seed));
    progress.finishStage();
  }
  const std::uint64_t pointCount = cloud.splats.size();
  progress.note(humanCount(static_cast<double>(pointCount)) + " points from " + cloud.source);
  // Normals need the neighbour search, and it gives radii for free; radii
  // alone come from neighbours within the octree leaves unless asked otherwise.
  const bool leafRadii = cloud.hasNormals && !cloud.hasRadii && !o.knnRadii;

  pp::PreprocessOptions po;
  po.octree.maxDepth = o.maxDepth;
  po.octree.leafPoints = o.leafPoints;
  po.topLevelDepth = o.topLevelDepth;
  po.targetPacketBytes = o.packetKiB * 1024;
  po.radiiInLeaves = leafRadii;
  po.estimateNormals = !cloud.hasNormals || (!cloud.hasRadii && !leafRadii);
  po.neighbourSearch = neighbourSearchOf(o);
  po.normalMethod = normalMethodOf(o);
  po.cubePoints = o.cubePoints;
  po.radiusNeighbours = o.neighbours;
  po.threads = o.threads;
  po.source = cloud.source;
  pp::InstancingStats instancingStats;
  if (o.instanced) {
    po.instancing = o.instancing;
    po.instancingStats = &instancingStats;
  }
  pp::StatisticalStats statisticalStats;
  if (o.statistical) {
    po.statistical = o.statisticalOptions;
    po.statisticalStats = &statisticalStats;
  }
  const auto buildStart = Clock::now();
  // Without the stages that add to packets, each packet is written as soon as
  // its level-splats are made, while the other cores make the next ones.
  std::optional<pointillist::DatasetWriter> writer;
  if (!o.instanced && !o.statistical) {
    writer.emplace(output, o.force);
    po.packetSink = [&](std::span<const pointillist::Splat> levelSplats,
                        std::span<const pointillist::Splat> points) {
      writer->appendPacket(levelSplats, {}, points);
    };
  }
  pointillist::DatasetContent content = pp::buildDatasetContent(
      std::move(cloud.splats), po, [&](const char* stage, std::uint64_t done, std::uint64_t total) {
        progress.update(stage, done, total);
      });
  progress.finishStage();
  content.manifest.createdBy = std::string(kTool) + " (max depth " + std::to_string(o.maxDepth) +
                               ", leaf points " + std::to_string(o.leafPoints) + ")";
  if (writer) progress.update("writing", 0, 1);  // the tables and the rename
  const std::uint64_t bytes =
      writer ? writer->commit(content)
             : pointillist::writeDataset(output, content, o.force,
                                         [&](std::uint64_t done, std::uint64_t total) {
                                           progress.update("writing", done, total);
                                         });
  progress.finishStage();
  const double buildSeconds = seconds(buildStart);
  const double total = seconds(start);

  char tail[96];
  std::snprintf(tail, sizeof tail, "; octree, level-splats and writing %.2f s, %s points/s",
                buildSeconds, humanCount(static_cast<double>(pointCount) / buildSeconds).c_str());
  printSummary(o, content.manifest, bytes, pointCount, total, tail);
  if (o.instanced) {
    printInstancingSummary(instancingStats, content.manifest.topLevelCount);
    saveWisdom(o);
  }
  if (o.statistical) printStatisticalSummary(statisticalStats);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "Builds a Pointillist dataset directory -- octree-cell-array, top-level cells and a "
      "point-array "
      "with level-splats (Hubo & Bekaert 2005, section 4.1) -- from point clouds (PLY, XYZ/PTS, "
      "LAS), "
      "meshes (OFF, PLY; sampled) or a built-in generated scene. Normals and radii missing from "
      "the "
      "input are estimated from nearest neighbours.",
      kTool};
  Options o;
  app.add_option("INPUT", o.inputs,
                 "Input files: .ply .xyz .pts .txt .las .off (several are merged)");
  app.add_option("-o,--output", o.output, "Dataset directory to create");
  app.add_option("--check", o.check,
                 "Verify an existing dataset instead (manifest, format version, sizes, cell "
                 "array, every packet's checksum); exit 0 when it is sound");
  app.add_option("--generate", o.generate, "Add a generated scene (NAME defaults to city)")
      ->expected(0, 1)
      ->default_str("city");
  app.add_option("--points", o.points, "Surface samples per mesh / points of a generated scene")
      ->capture_default_str();
  app.add_option(
      "--top-level-depth", o.topLevelDepth,
      "Depth of the top-level cells (default: chosen so a packet is about --packet-kib)");
  app.add_option("--packet-kib", o.packetKiB,
                 "Target average top-level packet size for the automatic depth")
      ->capture_default_str();
  app.add_option("--max-depth", o.maxDepth, "Octree recursion limit (1..21)")
      ->capture_default_str();
  app.add_option("--leaf-points", o.leafPoints, "Split cells with more points than this")
      ->capture_default_str();
  app.add_option("--neighbours", o.neighbours, "Neighbours for normal and radius estimation")
      ->capture_default_str();
  app.add_flag("--knn-radii", o.knnRadii,
               "Radii missing from an input with normals from the nearest neighbours (slower; "
               "no seams at octree leaf faces) instead of a search within each octree leaf");
  app.add_option("--neighbour-search", o.neighbourSearch,
                 "How normals and radii find their nearest neighbours: grid (a uniform grid) or "
                 "kdtree (nanoflann); both exact, the grid is faster on scans")
      ->capture_default_str();
  app.add_option("--normals", o.normals,
                 "How missing normals (and radii) are estimated: knn (over each point's "
                 "--neighbours nearest), moments (over the block of 3x3x3 small cubes around "
                 "each point's own, from per-cube sums: about twice as fast, a few degrees "
                 "farther from true normals on sparse samplings; a cube's points share one) or "
                 "auto (moments from 2 M points up, knn below)")
      ->capture_default_str();
  app.add_option("--cube-points", o.cubePoints,
                 "Moments: the points an occupied cube holds on average, aimed at (0.5..64). "
                 "Coarser cubes are faster and blur curves and creases: on the 10 M bunny scan "
                 "2.4 takes the normals stage from 1.38 to 1.10 s, the mean error from 0.61 to "
                 "0.72 degrees (README, \"Normals from cube moments\")")
      ->capture_default_str();
  app.add_flag("--drop-non-finite", o.dropNonFinite,
               "Drop NaN/Inf points with a warning instead of refusing");
  app.add_option("--seed", o.seed, "Seed for mesh sampling and generation")->capture_default_str();
  app.add_option("--threads", o.threads, "Worker threads (0: all cores)")->capture_default_str();
  o.memoryMb = defaultMemoryMb();
  app.add_option("--memory-mb", o.memoryMb,
                 "Memory cap in MiB: inputs that may not fit are preprocessed out of core, "
                 "chunk by chunk through temporary files next to the output (default: 60 % of "
                 "this machine's memory)")
      ->capture_default_str();
  app.add_flag("--instanced", o.instanced,
               "Also store each top-level cell's points as vertex and transformation streams "
               "(seed 000) for --mode instanced");
  app.add_option("--instanced-bits", o.instancing.maxBits,
                 "Finest instancing grid: 2^BITS voxels along a top-level cell (3..7)")
      ->capture_default_str()
      ->check(CLI::Range(3u, 7u));
  app.add_option("--instanced-step", o.instancing.stepShare,
                 "Instancing grid step as a share of the cell's median splat radius")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  app.add_option("--instanced-translations", o.instancing.poolTranslations,
                 "Translations per pool, the null one included (2..64)")
      ->capture_default_str()
      ->check(CLI::Range(2u, 64u));
  app.add_option("--instanced-unit-points", o.instancing.unitPoints,
                 "Largest subtree (in points) one section stands for: a level of detail draws a "
                 "section whole")
      ->capture_default_str()
      ->check(CLI::Range(64u, 1u << 24));
  app.add_option("--instanced-accept", o.instancing.acceptShare,
                 "A vertex joins a pool when it newly covers more than this share of the pool's "
                 "translations (seed 000: 0.25)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 1.0));
  app.add_option("--instanced-pools", o.instancing.maxPools, "Pools per top-level cell (1..255)")
      ->capture_default_str()
      ->check(CLI::Range(1u, 255u));
  app.add_option("--instanced-colour-tolerance", o.instancing.colorTolerance,
                 "Largest RGBA channel difference a generated point may carry from its source")
      ->capture_default_str()
      ->check(CLI::Range(0, 255));
  app.add_flag("--statistical", o.statistical,
               "Also store each top-level cell's points as a hierarchy of PCA nodes (seed 004) "
               "for --mode statistical");
  app.add_option("--statistical-leaf-points", o.statisticalOptions.leafPoints,
                 "Statistical hierarchy: nodes with fewer points are leaves (seed 004: 6..30)")
      ->capture_default_str()
      ->check(CLI::Range(2u, 1024u));
  app.add_option("--statistical-classes", o.statisticalOptions.positionClasses,
                 "Classes of the position standard deviations (the normal ones get as many, "
                 "colour 64)")
      ->capture_default_str()
      ->check(CLI::Range(16u, 4096u))
      ->each([&o](const std::string&) {
        o.statisticalOptions.normalClasses = o.statisticalOptions.positionClasses;
      });
  app.add_flag("-q,--quiet", o.quiet, "No progress output");
  app.add_flag("-f,--force", o.force, "Replace an existing dataset at the output");
  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    std::fprintf(stderr, "%s: usage error: %s\nRun with --help for more information.\n", kTool,
                 e.what());
    return 2;
  }
  std::signal(SIGINT, onSignal);
  std::signal(SIGTERM, onSignal);
  try {
    return run(o);
  } catch (const Interrupted& e) {
    std::fprintf(stderr, "\n%s: %s: %s\n", kTool, e.kind(), e.what());
    return 130;
  } catch (const UsageError& e) {
    std::fprintf(stderr, "%s: %s: %s\n", kTool, e.kind(), e.what());
    return 2;
  } catch (const Error& e) {
    std::fprintf(stderr, "%s: %s: %s\n", kTool, e.kind(), e.what());
    return 1;
  } catch (const std::bad_alloc&) {
    std::fprintf(stderr, "%s: error: out of memory\n", kTool);
    return 1;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "%s: error: %s\n", kTool, e.what());
    return 1;
  }
}
