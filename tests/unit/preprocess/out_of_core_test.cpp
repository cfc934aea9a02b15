// The out-of-core preprocess writes, chunk by chunk through temporary files,
// the same dataset bit for bit as the in-memory build of the same input, in
// every shape of plan: several chunks, spill files split deeper, units above
// the spill depth (outlier leaves), units held to a shallow top-level depth,
// a shallow max depth, stacks of identical points. Streaming readers give the
// points the whole-file readers give, and nothing temporary is left behind.
#include <gtest/gtest.h>
#include <sys/resource.h>
#include <unistd.h>

#include <csignal>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <random>
#include <span>
#include <string>
#include <vector>

#include "common/dataset.hpp"
#include "common/dataset_writer.hpp"
#include "common/errors.hpp"
#include "preprocess/dataset_builder.hpp"
#include "preprocess/generator.hpp"
#include "preprocess/out_of_core.hpp"
#include "preprocess/readers.hpp"

namespace fs = std::filesystem;
using pointillist::DatasetContent;
using pointillist::Splat;
using namespace pointillist::preprocess;

namespace {

class TempDir {
 public:
  TempDir() {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    path_ = fs::temp_directory_path() /
            ("pointillist-ooc-" + std::to_string(::getpid()) + "-" + info->name());
    fs::remove_all(path_);
    fs::create_directories(path_);
  }
  ~TempDir() {
    std::error_code ec;
    fs::remove_all(path_, ec);
  }
  const fs::path& path() const { return path_; }

 private:
  fs::path path_;
};

// Binary little-endian PLY: x y z nx ny nz [radius] red green blue alpha.
void writePly(const fs::path& file, const std::vector<Splat>& splats, bool radii) {
  std::ofstream out(file, std::ios::binary);
  out << "ply\nformat binary_little_endian 1.0\nelement vertex " << splats.size()
      << "\nproperty float x\nproperty float y\nproperty float z\n"
         "property float nx\nproperty float ny\nproperty float nz\n"
      << (radii ? "property float radius\n" : "")
      << "property uchar red\nproperty uchar green\nproperty uchar blue\n"
         "property uchar alpha\nend_header\n";
  for (const Splat& s : splats) {
    out.write(reinterpret_cast<const char*>(s.position), 12);
    out.write(reinterpret_cast<const char*>(s.normal), 12);
    if (radii) out.write(reinterpret_cast<const char*>(&s.radius), 4);
    out.write(reinterpret_cast<const char*>(s.color), 4);
  }
}

std::string fileBytes(const fs::path& file) {
  std::ifstream in(file, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

// Files and directories directly in `dir`.
std::size_t entriesIn(const fs::path& dir) {
  std::size_t entries = 0;
  for ([[maybe_unused]] const auto& e : fs::directory_iterator(dir)) ++entries;
  return entries;
}

// A cap that gives chunks of about `chunkPoints` for a cloud of `points`.
std::uint64_t capFor(std::uint64_t points, std::uint64_t chunkPoints,
                     bool estimateNormals = false) {
  std::uint64_t cap = std::uint64_t{1} << 20;
  while (chunkCapacity(cap, points, estimateNormals) < chunkPoints) cap += std::uint64_t{1} << 16;
  return cap;
}

struct Case {
  std::vector<Splat> splats;
  bool radii = false;
  PreprocessOptions build;
  std::uint64_t chunkPoints = 10000;
  std::size_t shapeCellLimit = 0;
};

// Builds `c` in memory and out of core; expects equal files, returns the
// out-of-core result.
OutOfCoreResult expectSameDataset(const Case& c) {
  TempDir dir;
  const fs::path input = dir.path() / "in.ply";
  writePly(input, c.splats, c.radii);

  ReadOptions read;
  PointCloud cloud = readPointCloud(input, read);
  PreprocessOptions inMemory = c.build;
  inMemory.radiiInLeaves = cloud.hasNormals && !cloud.hasRadii;
  inMemory.source = cloud.source;
  DatasetContent content = buildDatasetContent(std::move(cloud.splats), inMemory);
  content.manifest.createdBy = "test";
  pointillist::writeDataset(dir.path() / "memory", content);

  OutOfCoreOptions oc;
  oc.build = c.build;
  oc.memoryBytes = capFor(c.splats.size(), c.chunkPoints);
  oc.createdBy = "test";
  oc.shapeCellLimit = c.shapeCellLimit;
  const OutOfCoreResult r = preprocessOutOfCore({input}, dir.path() / "chunked", oc, {});

  for (const char* name :
       {"manifest.txt", "cells.bin", "top-level.bin", "packet-checksums.bin", "points.bin"}) {
    const std::string a = fileBytes(dir.path() / "memory" / name);
    const std::string b = fileBytes(dir.path() / "chunked" / name);
    EXPECT_EQ(a.size(), b.size()) << name;
    EXPECT_TRUE(a == b) << name << " differs";
  }
  // It opens and verifies as any dataset.
  EXPECT_NO_THROW(pointillist::Dataset::open(dir.path() / "chunked"));
  // Only the input and the two datasets are left.
  EXPECT_EQ(entriesIn(dir.path()), 3u);
  EXPECT_EQ(r.points, c.splats.size());
  return r;
}

std::vector<Splat> city(std::size_t points, std::uint64_t seed = 3) {
  return generateScene("city", points, seed).splats;
}

}  // namespace

TEST(OutOfCore, SeveralChunksGiveTheInMemoryDataset) {
  Case c;
  c.splats = city(60000);
  c.chunkPoints = 9000;
  const OutOfCoreResult r = expectSameDataset(c);
  EXPECT_GE(r.chunks, 4u);
  EXPECT_LE(r.largestChunkPoints, r.chunkCapacity);
  EXPECT_FALSE(r.capExceeded);
}

TEST(OutOfCore, TheTopLevelDepthFromSpillCountsOrFromTheChunksTrees) {
  // Counted while spilling (the usual way), and with counting given up, from
  // the chunks' trees built once: the same depth, the same dataset.
  for (const std::size_t limit : {std::size_t{0}, std::size_t{1}}) {
    Case c;
    c.splats = city(80000, 13);
    c.chunkPoints = 12000;
    c.shapeCellLimit = limit;
    c.build.targetPacketBytes = 16 * 1024;  // small packets: a deeper choice
    const OutOfCoreResult r = expectSameDataset(c);
    EXPECT_EQ(r.shapeCounted, limit == 0);
    EXPECT_GE(r.manifest.topLevelDepth, 4u) << "deep enough to test the choice";
  }
}

TEST(OutOfCore, SpillFilesSplitDeeperStillGiveTheSameDataset) {
  // Chunks far below a depth-3 cell's share: files are split to depth 4 and 5.
  Case c;
  c.splats = city(60000, 5);
  c.chunkPoints = 1500;
  c.build.octree.leafPoints = 32;
  const OutOfCoreResult r = expectSameDataset(c);
  EXPECT_GT(r.spillFiles, 64u);
  EXPECT_GE(r.chunks, 30u);
}

TEST(OutOfCore, GivenRadiiAndAGivenTopLevelDepth) {
  Case c;
  c.splats = city(40000, 7);
  for (std::size_t i = 0; i < c.splats.size(); ++i)
    c.splats[i].radius = 0.01f + 0.001f * static_cast<float>(i % 7);
  c.radii = true;
  c.build.topLevelDepth = 5;
  c.chunkPoints = 5000;
  EXPECT_GE(expectSameDataset(c).chunks, 3u);
}

TEST(OutOfCore, AShallowTopLevelDepthKeepsPacketsWholeAboveTheCap) {
  // Depth 2: a top-level cell holds more than a chunk may; it is built whole
  // (and the result says the cap was exceeded) rather than split.
  Case c;
  c.splats = city(40000, 9);
  c.build.topLevelDepth = 2;
  c.chunkPoints = 3000;
  const OutOfCoreResult r = expectSameDataset(c);
  EXPECT_TRUE(r.capExceeded);
  EXPECT_EQ(r.manifest.topLevelDepth, 2u);
}

TEST(OutOfCore, OutlierLeavesAboveTheSpillDepth) {
  // A sphere and a handful of far points: the far corner is a leaf of the
  // final tree at depth 1 or 2 whose points fall in several depth-3 files.
  Case c;
  c.splats = generateScene("sphere", 30000, 2).splats;
  std::mt19937 rng(4);
  std::uniform_real_distribution<float> jitter(0.0f, 40.0f);
  for (int i = 0; i < 20; ++i) {
    Splat s = c.splats[static_cast<std::size_t>(i)];
    s.position[0] = 300.0f + jitter(rng);
    s.position[1] = 300.0f + jitter(rng);
    s.position[2] = 300.0f + jitter(rng);
    c.splats.push_back(s);
  }
  c.chunkPoints = 4000;
  EXPECT_GE(expectSameDataset(c).chunks, 3u);
}

TEST(OutOfCore, ShallowMaxDepthAndStacksOfEqualPoints) {
  Case c;
  c.splats = city(20000, 11);
  // Many copies of a few points: cells at max depth hold far more than a leaf.
  for (std::size_t i = 0; i < 3000; ++i) c.splats.push_back(c.splats[i % 5]);
  c.build.octree.maxDepth = 2;
  c.chunkPoints = 6000;
  expectSameDataset(c);
}

TEST(OutOfCore, TooSmallACapIsAUsageErrorAndLeavesNothing) {
  TempDir dir;
  const fs::path input = dir.path() / "in.ply";
  writePly(input, city(5000), false);
  OutOfCoreOptions oc;
  oc.memoryBytes = std::uint64_t{8} << 20;
  EXPECT_THROW(preprocessOutOfCore({input}, dir.path() / "out", oc, {}), pointillist::UsageError);
  EXPECT_EQ(entriesIn(dir.path()), 1u);
}

// A 30 k-point city written to `input`, and options that build it in chunks
// of about 4000 points.
OutOfCoreOptions cityInChunksOf4000(const fs::path& input) {
  const auto splats = city(30000);
  writePly(input, splats, false);
  OutOfCoreOptions oc;
  oc.memoryBytes = capFor(splats.size(), 4000);
  return oc;
}

// Files may not grow past `bytes` while it lives (a write past it fails with
// EFBIG, as on a full disk, instead of raising SIGXFSZ).
class FileSizeLimit {
 public:
  explicit FileSizeLimit(rlim_t bytes) : oldHandler_(std::signal(SIGXFSZ, SIG_IGN)) {
    EXPECT_EQ(getrlimit(RLIMIT_FSIZE, &before_), 0);
    rlimit small = before_;
    small.rlim_cur = bytes;
    EXPECT_EQ(setrlimit(RLIMIT_FSIZE, &small), 0);
  }
  ~FileSizeLimit() {
    setrlimit(RLIMIT_FSIZE, &before_);
    std::signal(SIGXFSZ, oldHandler_);
  }
  FileSizeLimit(const FileSizeLimit&) = delete;
  FileSizeLimit& operator=(const FileSizeLimit&) = delete;

 private:
  rlimit before_{};
  void (*oldHandler_)(int);
};

TEST(OutOfCore, AFailureMidwayRemovesTheTemporaryFiles) {
  TempDir dir;
  const fs::path input = dir.path() / "in.ply";
  const OutOfCoreOptions oc = cityInChunksOf4000(input);
  int building = 0;
  bool sawSpillFiles = false;
  EXPECT_THROW(
      preprocessOutOfCore({input}, dir.path() / "out", oc,
                          [&](const char* stage, std::uint64_t, std::uint64_t) {
                            if (std::strcmp(stage, "building") != 0) return;
                            for (const auto& e : fs::directory_iterator(dir.path()))
                              if (e.path().filename().string().find(".spill-") != std::string::npos)
                                sawSpillFiles = !fs::is_empty(e.path());
                            if (++building == 3) throw pointillist::Error("stop");
                          }),
      pointillist::Error);
  EXPECT_TRUE(sawSpillFiles);
  EXPECT_EQ(entriesIn(dir.path()), 1u);  // the input alone
}

// The spill's writing thread fails (files may not grow past 64 KiB here, a
// full disk as the kernel reports it): the error reaches the caller, naming
// the file, and nothing is left behind.
TEST(OutOfCore, ASpillWriteThatFailsIsAnErrorAndLeavesNothing) {
  TempDir dir;
  const fs::path input = dir.path() / "in.ply";
  const OutOfCoreOptions oc = cityInChunksOf4000(input);
  std::string message;
  try {
    const FileSizeLimit limit(64 << 10);
    preprocessOutOfCore({input}, dir.path() / "out", oc, {});
  } catch (const pointillist::Error& e) {
    message = e.what();
  }
  EXPECT_NE(message.find("cannot write temporary file"), std::string::npos) << message;
  EXPECT_NE(message.find(".spill-"), std::string::npos) << message;
  EXPECT_EQ(entriesIn(dir.path()), 1u);  // the input alone
}

// A spill file cut short under the run (read on all cores into the chunk):
// the error reaches the caller from the reading thread, and nothing is left.
TEST(OutOfCore, ASpillFileCutShortIsAnErrorAndLeavesNothing) {
  TempDir dir;
  const fs::path input = dir.path() / "in.ply";
  const OutOfCoreOptions oc = cityInChunksOf4000(input);
  bool cut = false;
  std::string message;
  try {
    preprocessOutOfCore({input}, dir.path() / "out", oc,
                        [&](const char* stage, std::uint64_t, std::uint64_t) {
                          if (cut || std::strcmp(stage, "building") != 0) return;
                          // The first chunk is loaded (its files are being
                          // removed): the later chunks' files lose their end.
                          for (const auto& e : fs::directory_iterator(dir.path())) {
                            if (e.path().filename().string().find(".spill-") == std::string::npos)
                              continue;
                            std::error_code gone;  // removed meanwhile
                            for (const auto& f : fs::directory_iterator(e.path(), gone)) {
                              const auto size = fs::file_size(f.path(), gone);
                              if (!gone) fs::resize_file(f.path(), size / 2, gone);
                            }
                          }
                          cut = true;
                        });
  } catch (const pointillist::Error& e) {
    message = e.what();
  }
  EXPECT_TRUE(cut);
  EXPECT_NE(message.find("cannot read temporary file"), std::string::npos) << message;
  EXPECT_NE(message.find("short read"), std::string::npos) << message;
  EXPECT_EQ(entriesIn(dir.path()), 1u);
}

// In memory, preprocess writes each packet as soon as its level-splats are
// made (PreprocessOptions::packetSink): the dataset must be the one written
// from the whole content, and a failure midway must leave nothing behind.
TEST(StreamedPackets, WriteTheDatasetTheWholeContentWrites) {
  TempDir dir;
  PreprocessOptions o;
  o.threads = 2;
  o.topLevelDepth = 3;
  o.radiiInLeaves = true;
  DatasetContent whole = buildDatasetContent(city(40000), o);
  whole.manifest.createdBy = "test";
  pointillist::writeDataset(dir.path() / "whole", whole);

  std::size_t packets = 0;
  {
    pointillist::DatasetWriter writer(dir.path() / "streamed");
    PreprocessOptions streamed = o;
    streamed.packetSink = [&](std::span<const Splat> levelSplats, std::span<const Splat> points) {
      writer.appendPacket(levelSplats, {}, points);
      ++packets;
    };
    DatasetContent content = buildDatasetContent(city(40000), streamed);
    EXPECT_TRUE(content.levelSplats.empty());  // written, not gathered
    content.manifest.createdBy = "test";
    writer.commit(content);
  }
  EXPECT_EQ(packets, whole.topLevel.size());
  for (const char* name :
       {"manifest.txt", "cells.bin", "top-level.bin", "packet-checksums.bin", "points.bin"}) {
    const std::string a = fileBytes(dir.path() / "whole" / name);
    const std::string b = fileBytes(dir.path() / "streamed" / name);
    EXPECT_EQ(a.size(), b.size()) << name;
    EXPECT_TRUE(a == b) << name << " differs";
  }
  EXPECT_NO_THROW(pointillist::Dataset::open(dir.path() / "streamed"));

  // A write that fails midway stops the build and leaves no files.
  {
    PreprocessOptions failing = o;
    pointillist::DatasetWriter writer(dir.path() / "failed");
    failing.packetSink = [&](std::span<const Splat> levelSplats, std::span<const Splat> points) {
      if (writer.packetsAppended() == 5) throw pointillist::Error("disk full");
      writer.appendPacket(levelSplats, {}, points);
    };
    EXPECT_THROW(buildDatasetContent(city(40000), failing), pointillist::Error);
  }
  EXPECT_EQ(entriesIn(dir.path()), 2u);  // the two datasets alone

  // Instancing adds to packets afterwards: streaming is refused with it.
  PreprocessOptions instanced = o;
  instanced.instancing = InstancingOptions{};
  instanced.packetSink = [](std::span<const Splat>, std::span<const Splat>) {};
  EXPECT_THROW(buildDatasetContent(city(2000), instanced), pointillist::Error);
}

TEST(StreamPointClouds, BlocksHoldWhatTheWholeReaderReads) {
  TempDir dir;
  const auto splats = city(7000);
  writePly(dir.path() / "a.ply", splats, false);
  {
    std::ofstream xyz(dir.path() / "b.xyz");
    for (std::size_t i = 0; i < 3000; ++i)
      xyz << splats[i].position[0] << ' ' << splats[i].position[1] << ' ' << splats[i].position[2]
          << '\n';
  }
  const std::vector<fs::path> files = {dir.path() / "a.ply", dir.path() / "b.xyz"};
  ReadOptions read;
  const PointCloud whole = readPointClouds(files, read);
  read.sinkBlock = 1000;
  std::vector<Splat> streamed;
  std::size_t largestBlock = 0;
  std::uint64_t count = 0;
  const PointCloud flags = streamPointClouds(
      files, read,
      [&](std::span<const Splat> block) {
        largestBlock = std::max(largestBlock, block.size());
        streamed.insert(streamed.end(), block.begin(), block.end());
      },
      count);
  EXPECT_EQ(count, whole.splats.size());
  EXPECT_LE(largestBlock, 1000u);
  ASSERT_EQ(streamed.size(), whole.splats.size());
  EXPECT_EQ(std::memcmp(streamed.data(), whole.splats.data(), streamed.size() * sizeof(Splat)), 0);
  EXPECT_TRUE(flags.splats.empty());
  EXPECT_EQ(flags.hasNormals, whole.hasNormals);
  EXPECT_FALSE(flags.hasNormals);  // the XYZ has none
  EXPECT_EQ(flags.hasRadii, whole.hasRadii);
  EXPECT_EQ(flags.source, whole.source);
}

// Without normals in the input, each chunk estimates its own; its border
// points take neighbours and sides from the chunks before it, and pieces no
// border reaches take the side of the whole cloud oriented at a coarser
// sampling. Every point keeps the side the in-memory build gives it (a
// chunk's piece of a closed surface turned by its own shape came out inside
// out before), and directions differ only near chunk borders.
class OutOfCoreNormals : public ::testing::TestWithParam<NormalMethod> {};

namespace {

// `splats` without normals in memory and out of core in chunks of each of
// `chunkSizes` points: the same points, none on the other side (with cube
// moments, one in 20,000), and at most 2 % of the normals apart (near chunk
// faces).
void expectChunksKeepTheInMemorySides(std::vector<Splat> splats, NormalMethod method,
                                      std::initializer_list<std::uint64_t> chunkSizes) {
  TempDir dir;
  for (Splat& s : splats) s.normal[0] = s.normal[1] = s.normal[2] = 0.0f;
  const fs::path input = dir.path() / "in.ply";
  writePly(input, splats, false);

  PointCloud cloud = readPointCloud(input, ReadOptions{});
  ASSERT_FALSE(cloud.hasNormals);
  PreprocessOptions build;
  build.estimateNormals = true;
  build.normalMethod = method;
  build.source = cloud.source;
  DatasetContent content = buildDatasetContent(std::move(cloud.splats), build);
  pointillist::writeDataset(dir.path() / "memory", content);

  for (const std::uint64_t chunkPoints : chunkSizes) {
    OutOfCoreOptions oc;
    oc.build = build;
    oc.memoryBytes = capFor(splats.size(), chunkPoints, true);
    const fs::path out = dir.path() / ("chunked-" + std::to_string(chunkPoints));
    const OutOfCoreResult r = preprocessOutOfCore({input}, out, oc, {});
    EXPECT_GE(r.chunks, 3u);
    const auto memory = pointillist::Dataset::open(dir.path() / "memory");
    const auto chunked = pointillist::Dataset::open(out);
    const auto top = memory.topLevelCells();
    ASSERT_EQ(top.size(), chunked.topLevelCells().size());
    std::size_t points = 0, opposite = 0, apart = 0;
    for (std::uint32_t k = 0; k < top.size(); ++k) {
      const auto a = memory.packet(k), b = chunked.packet(k);
      ASSERT_EQ(a.size(), b.size());
      for (std::size_t i = a.size() - top[k].pointCount; i < a.size(); ++i) {
        ASSERT_EQ(std::memcmp(a[i].position, b[i].position, sizeof a[i].position), 0);
        float d = 0.0f;
        for (int c = 0; c < 3; ++c) d += a[i].normal[c] * b[i].normal[c];
        ++points;
        opposite += d < 0.0f ? 1u : 0u;
        apart += d < 0.999f ? 1u : 0u;
      }
    }
    EXPECT_EQ(points, splats.size());
    // Cube moments: a point or two where a cube holds both faces of an ear
    // and the chunk's and the whole cloud's orientation differ there.
    EXPECT_LE(opposite, method == NormalMethod::Moments ? points / 20000 : 0u)
        << "chunks of " << chunkPoints;
    EXPECT_LT(apart, points / 50) << "chunks of " << chunkPoints;
  }
}

}  // namespace

TEST_P(OutOfCoreNormals, WithoutNormalsTheSidesAreTheInMemoryOnes) {
  std::vector<Splat> splats = generateScene("torus", 40000, 1).splats;
  for (const Splat& s : generateScene("sphere", 20000, 2).splats) {
    Splat moved = s;
    moved.position[0] += 4.0f;
    splats.push_back(moved);
  }
  expectChunksKeepTheInMemorySides(std::move(splats), GetParam(), {6000, 20000});
}

// A real shape with thin parts (the bunny's ears): chunk faces cut through
// them, and cubes there hold both faces of an ear.
TEST_P(OutOfCoreNormals, ThinPartsAcrossChunksKeepTheInMemorySides) {
  const fs::path mesh = fs::path(POINTILLIST_TEST_DATA_DIR) / "data" / "meshes" / "bunny00.off";
  if (!fs::exists(mesh)) GTEST_SKIP() << "run `bash deploy/fetch-test-data.sh`";
  ReadOptions read;
  read.meshSamplePoints = 200000;
  expectChunksKeepTheInMemorySides(readPointCloud(mesh, read).splats, GetParam(), {30000, 70000});
}

// Both methods; with cube moments every chunk is given the whole cloud's
// lattice, so inside a chunk its cubes are the in-memory run's.
INSTANTIATE_TEST_SUITE_P(Methods, OutOfCoreNormals,
                         ::testing::Values(NormalMethod::Neighbours, NormalMethod::Moments),
                         [](const ::testing::TestParamInfo<NormalMethod>& method) {
                           return method.param == NormalMethod::Moments ? "Moments" : "Neighbours";
                         });
