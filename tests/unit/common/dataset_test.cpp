// Dataset directory: manifest, writer, validating loader.
#include "common/dataset.hpp"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>

#include "common/checksum.hpp"
#include "common/errors.hpp"

namespace pointillist {
namespace {

namespace fs = std::filesystem;

Splat makeSplat(float x, float y, float z, float r = 0.5f) {
  Splat s{};
  s.position[0] = x;
  s.position[1] = y;
  s.position[2] = z;
  s.normal[2] = 1.0f;
  s.radius = r;
  s.color[0] = static_cast<std::uint8_t>(x * 10.0f);
  s.color[3] = 255;
  return s;
}

OctreeCell makeCell(std::uint8_t depth, std::uint8_t level, std::uint8_t children,
                    std::uint32_t next, std::uint32_t top) {
  OctreeCell c{};
  c.depth = depth;
  c.level = level;
  c.childCount = children;
  c.flags = children == 0 ? kCellFlagLeaf : 0;
  c.nextSibling = next;
  c.topLevel = top;
  c.coneCos = -32767;
  c.maxSplatRadius = 2.0f;
  return c;
}

// Root (above the top-level depth 1) with a leaf A (top-level 0, 3 points) and
// an inner cell B (top-level 1) with leaves B1 (2 points) and B2 (3 points).
DatasetContent makeContent() {
  DatasetContent c;
  c.cells = {makeCell(0, 3, 2, kNoIndex, kNoIndex), makeCell(1, 1, 0, 2, 0),
             makeCell(1, 2, 2, kNoIndex, 1), makeCell(2, 1, 0, 4, 1),
             makeCell(2, 1, 0, kNoIndex, 1)};
  c.points = {makeSplat(0, 0, 0), makeSplat(1, 0, 0), makeSplat(0, 1, 0),   // A
              makeSplat(5, 5, 5), makeSplat(6, 5, 5),                       // B1
              makeSplat(5, 6, 6), makeSplat(6, 6, 6), makeSplat(7, 7, 7)};  // B2
  c.levelSplats = {makeSplat(0.3f, 0.3f, 0, 1.5f),                          // A
                   makeSplat(6, 6, 6, 2.0f), makeSplat(5.5f, 5, 5, 1.0f),   // B, B1
                   makeSplat(6, 6.3f, 6.3f, 1.5f)};                         // B2
  auto setRange = [&](std::size_t i, std::uint32_t po, std::uint32_t pc, std::uint32_t so) {
    c.cells[i].pointsOffset = po;
    c.cells[i].pointsCount = pc;
    c.cells[i].splatsOffset = so;
    c.cells[i].splatsCount = 1;
  };
  // Packets are layered: level-splats by level (B before B1, B2), then points.
  setRange(1, 1, 3, 0);
  setRange(2, 3, 5, 0);
  setRange(3, 3, 2, 1);
  setRange(4, 5, 3, 2);
  const float lo[5][3] = {{0, 0, 0}, {0, 0, 0}, {5, 5, 5}, {5, 5, 5}, {5, 6, 6}};
  const float hi[5][3] = {{7, 7, 7}, {1, 1, 0}, {7, 7, 7}, {6, 5, 5}, {7, 7, 7}};
  for (std::size_t i = 0; i < 5; ++i)
    for (int a = 0; a < 3; ++a) {
      c.cells[i].boundsMin[a] = lo[i][a];
      c.cells[i].boundsMax[a] = hi[i][a];
    }
  c.topLevel = {{1, 3, 1, 0, 0, 0}, {2, 5, 3, 0, 0, 0}};
  c.manifest.topLevelDepth = 1;
  c.manifest.source = "unit test";
  c.manifest.createdBy = "dataset_test";
  c.manifest.maxDepth = 2;
  c.manifest.leafPoints = 3;
  c.manifest.levelSplatReduction = 4;
  return c;
}

class DatasetTest : public ::testing::Test {
 protected:
  void SetUp() override {
    root_ = fs::temp_directory_path() /
            ("pointillist-dataset-test-" + std::to_string(::getpid()) + "-" +
             ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(root_);
    fs::create_directories(root_);
    dir_ = root_ / "ds";
  }
  void TearDown() override { fs::remove_all(root_); }

  void write(DatasetContent content) { writeDataset(dir_, content); }

  static std::string errorOf(const fs::path& dir, DatasetParts parts = DatasetParts::All) {
    try {
      Dataset::open(dir, parts);
    } catch (const InputError& e) {
      return e.what();
    }
    return "";
  }

  void flipByte(const fs::path& file, std::uint64_t offset) {
    std::fstream f(file, std::ios::in | std::ios::out | std::ios::binary);
    f.seekg(static_cast<std::streamoff>(offset));
    char c = 0;
    f.read(&c, 1);
    c = static_cast<char>(c ^ 0x5a);
    f.seekp(static_cast<std::streamoff>(offset));
    f.write(&c, 1);
  }

  void replaceInManifest(const std::string& from, const std::string& to) {
    std::ifstream in(dir_ / "manifest.txt");
    std::string text((std::istreambuf_iterator<char>(in)), {});
    const auto pos = text.find(from);
    ASSERT_NE(pos, std::string::npos) << from;
    text.replace(pos, from.size(), to);
    std::ofstream(dir_ / "manifest.txt", std::ios::trunc) << text;
  }

  fs::path root_;
  fs::path dir_;
};

TEST(Checksum64, KnownVectorAndStreaming) {
  EXPECT_EQ(checksum64("", 0), 0x2d06800538d394c2ull);  // XXH3-64 of nothing, seed 0
  std::vector<unsigned char> bytes(5000);
  for (std::size_t i = 0; i < bytes.size(); ++i) bytes[i] = static_cast<unsigned char>(i * 131 + 7);
  // Pieces across XXH3's internal block and stripe sizes give the one-shot value.
  for (const std::size_t cut : {std::size_t{0}, std::size_t{1}, std::size_t{239}, std::size_t{240},
                                std::size_t{1024}, std::size_t{4999}}) {
    ChecksumStream stream;
    stream.update(bytes.data(), cut);
    stream.update(bytes.data() + cut, bytes.size() - cut);
    EXPECT_EQ(stream.digest(), checksum64(bytes.data(), bytes.size())) << cut;
  }
  EXPECT_NE(checksum64(bytes.data(), 4999), checksum64(bytes.data(), 5000));
}

TEST(DatasetRecords, Sizes) {
  EXPECT_EQ(sizeof(Splat), 32u);
  EXPECT_EQ(sizeof(OctreeCell), 64u);
  EXPECT_EQ(sizeof(TopLevelCell), 32u);
}

TEST_F(DatasetTest, RoundTripIsBitIdentical) {
  DatasetContent content = makeContent();
  DatasetContent written = content;
  const std::uint64_t bytes = writeDataset(dir_, written);
  EXPECT_GT(bytes, 0u);
  const Dataset ds = Dataset::open(dir_, DatasetParts::All);

  ASSERT_EQ(ds.cells().size(), content.cells.size());
  EXPECT_EQ(std::memcmp(ds.cells().data(), content.cells.data(),
                        content.cells.size() * sizeof(OctreeCell)),
            0);
  ASSERT_EQ(ds.topLevelCells().size(), 2u);
  EXPECT_EQ(
      std::memcmp(ds.topLevelCells().data(), written.topLevel.data(), 2 * sizeof(TopLevelCell)), 0);
  EXPECT_EQ(ds.topLevelCells()[0].byteOffset, 0u);
  EXPECT_EQ(ds.topLevelCells()[0].byteSize, 4u * 32);
  EXPECT_EQ(ds.topLevelCells()[1].byteOffset, 4u * 32);

  // Packet = the level-splats of the cell's subtree (coarse first), then its points.
  std::vector<Splat> expected0 = {content.levelSplats[0], content.points[0], content.points[1],
                                  content.points[2]};
  std::vector<Splat> expected1(content.levelSplats.begin() + 1, content.levelSplats.end());
  expected1.insert(expected1.end(), content.points.begin() + 3, content.points.end());
  for (std::uint32_t k = 0; k < 2; ++k) {
    const auto& expected = k == 0 ? expected0 : expected1;
    const auto packet = ds.packet(k);
    ASSERT_EQ(packet.size(), expected.size());
    EXPECT_EQ(std::memcmp(packet.data(), expected.data(), expected.size() * sizeof(Splat)), 0);
    const auto read = ds.readTopLevel(k);
    ASSERT_EQ(read.size(), expected.size());
    EXPECT_EQ(std::memcmp(read.data(), expected.data(), expected.size() * sizeof(Splat)), 0);
    EXPECT_EQ(ds.packetChecksum(k), checksum64(expected.data(), expected.size() * sizeof(Splat)));
  }

  const DatasetManifest& m = ds.manifest();
  EXPECT_EQ(m.formatVersion, kDatasetFormatVersion);
  EXPECT_EQ(m.pointCount, 8u);
  EXPECT_EQ(m.levelSplatCount, 4u);
  EXPECT_EQ(m.cellCount, 5u);
  EXPECT_EQ(m.topLevelCount, 2u);
  EXPECT_EQ(m.topLevelDepth, 1u);
  EXPECT_EQ(m.treeDepth, 2u);
  EXPECT_EQ(m.maxLevel, 3u);
  EXPECT_EQ(m.source, "unit test");
  EXPECT_EQ(m.boundsMax[2], 7.0f);
  EXPECT_EQ(m.maxSplatRadius, 2.0f);
  // The manifest text itself round-trips.
  EXPECT_EQ(DatasetManifest::parse(m.toText(), "x").toText(), m.toText());
  // Nothing temporary is left next to the dataset.
  std::size_t entries = 0;
  for ([[maybe_unused]] const auto& e : fs::directory_iterator(root_)) ++entries;
  EXPECT_EQ(entries, 1u);
}

TEST_F(DatasetTest, LoadsOnlyTheRequestedParts) {
  write(makeContent());
  const Dataset table = Dataset::open(dir_, DatasetParts::TopLevel);
  EXPECT_TRUE(table.cells().empty());
  EXPECT_TRUE(table.points().empty());
  EXPECT_EQ(table.topLevelCells().size(), 2u);
  EXPECT_EQ(table.readTopLevel(1).size(), 8u);
  EXPECT_THROW(table.packet(0), UsageError);

  const Dataset cells = Dataset::open(dir_, DatasetParts::Cells);
  EXPECT_EQ(cells.cells().size(), 5u);
  EXPECT_TRUE(cells.points().empty());
  EXPECT_EQ(Dataset::open(dir_, DatasetParts::Manifest).manifest().cellCount, 5u);
}

TEST_F(DatasetTest, CorruptPointByteIsRefusedNamingTheFile) {
  write(makeContent());
  flipByte(dir_ / "points.bin", 4 * 32 + 3);  // inside top-level cell 1
  const std::string msg = errorOf(dir_);
  EXPECT_NE(msg.find("points.bin"), std::string::npos) << msg;
  EXPECT_NE(msg.find("checksum mismatch"), std::string::npos) << msg;
  EXPECT_NE(msg.find("top-level cell 1"), std::string::npos) << msg;
  // A data-send process that owns only cell 0 is not bothered; cell 1 is refused.
  const Dataset ds = Dataset::open(dir_, DatasetParts::Cells);
  EXPECT_EQ(ds.readTopLevel(0).size(), 4u);
  EXPECT_THROW(ds.readTopLevel(1), InputError);
}

TEST_F(DatasetTest, CorruptCellByteIsRefused) {
  write(makeContent());
  flipByte(dir_ / "cells.bin", 64 * 2 + 40);
  const std::string msg = errorOf(dir_, DatasetParts::Cells);
  EXPECT_NE(msg.find("cells.bin"), std::string::npos) << msg;
  EXPECT_NE(msg.find("checksum mismatch"), std::string::npos) << msg;
  // Loaders that do not read the cells are unaffected.
  EXPECT_NO_THROW(Dataset::open(dir_, DatasetParts::TopLevel));
}

TEST_F(DatasetTest, TruncatedFileIsRefusedForEveryPart) {
  write(makeContent());
  fs::resize_file(dir_ / "points.bin", 7 * 32);
  for (DatasetParts parts : {DatasetParts::Manifest, DatasetParts::Cells, DatasetParts::All}) {
    const std::string msg = errorOf(dir_, parts);
    EXPECT_NE(msg.find("points.bin"), std::string::npos) << msg;
    EXPECT_NE(msg.find("truncated"), std::string::npos) << msg;
  }
}

// 2^58 cells of 64 bytes wrap a 64-bit size to 0, which an emptied cells.bin
// would match: the counts must be refused, not read as an empty dataset.
TEST_F(DatasetTest, AbsurdCountsAreRefusedInsteadOfWrapping) {
  const DatasetContent content = makeContent();
  write(content);
  const std::string cells = std::to_string(content.cells.size());
  const std::string cellBytes = std::to_string(content.cells.size() * sizeof(OctreeCell));
  fs::resize_file(dir_ / "cells.bin", 0);
  replaceInManifest("cell_count = " + cells + "\n", "cell_count = 288230376151711744\n");
  replaceInManifest("cells.bin " + cellBytes + " ", "cells.bin 0 ");
  for (DatasetParts parts : {DatasetParts::Manifest, DatasetParts::TopLevel, DatasetParts::Cells}) {
    const std::string msg = errorOf(dir_, parts);
    EXPECT_NE(msg.find("manifest.txt"), std::string::npos) << msg;
    EXPECT_NE(msg.find("cell_count 288230376151711744"), std::string::npos) << msg;
  }
}

TEST_F(DatasetTest, MissingFileIsRefused) {
  write(makeContent());
  fs::remove(dir_ / "top-level.bin");
  const std::string msg = errorOf(dir_, DatasetParts::Manifest);
  EXPECT_NE(msg.find("top-level.bin"), std::string::npos) << msg;
  EXPECT_NE(msg.find("missing"), std::string::npos) << msg;
  fs::remove(dir_ / "manifest.txt");
  EXPECT_NE(errorOf(dir_).find("manifest.txt: missing"), std::string::npos);
  EXPECT_NE(errorOf(root_ / "nowhere").find("does not exist"), std::string::npos);
}

std::string versionLine(std::uint32_t version) {
  return "format_version = " + std::to_string(version);
}

TEST_F(DatasetTest, WrongVersionIsRefused) {
  write(makeContent());
  replaceInManifest(versionLine(kDatasetFormatVersion), versionLine(kDatasetFormatVersion + 1));
  const std::string msg = errorOf(dir_);
  EXPECT_NE(msg.find("manifest.txt"), std::string::npos) << msg;
  EXPECT_NE(msg.find("unsupported format version " + std::to_string(kDatasetFormatVersion + 1)),
            std::string::npos)
      << msg;
}

// A dataset of format 1 (no max_splat_radius) as the previous preprocess wrote it.
TEST_F(DatasetTest, OlderVersionIsRefusedAskingToPreprocessAgain) {
  write(makeContent());
  replaceInManifest(versionLine(kDatasetFormatVersion), versionLine(1));
  replaceInManifest("max_splat_radius = 2\n", "");
  for (DatasetParts parts : {DatasetParts::Manifest, DatasetParts::Cells, DatasetParts::All}) {
    const std::string msg = errorOf(dir_, parts);
    EXPECT_NE(msg.find((dir_ / "manifest.txt").string()), std::string::npos) << msg;
    EXPECT_NE(msg.find("unsupported format version 1"), std::string::npos) << msg;
    EXPECT_NE(msg.find("run pointillist-preprocess again"), std::string::npos) << msg;
  }
}

TEST_F(DatasetTest, ManifestRadiusIsTheRootsLargestSplatRadius) {
  DatasetContent content = makeContent();
  content.cells[0].maxSplatRadius = 2.5f;  // the root's differs from every other cell's
  write(content);
  const Dataset cells = Dataset::open(dir_, DatasetParts::Cells);
  EXPECT_EQ(cells.manifest().maxSplatRadius, 2.5f);
  EXPECT_EQ(cells.manifest().maxSplatRadius, cells.cells()[0].maxSplatRadius);
  EXPECT_EQ(Dataset::open(dir_, DatasetParts::Manifest).manifest().maxSplatRadius, 2.5f);

  // A manifest that disagrees with cells.bin is refused wherever the cells are read.
  replaceInManifest("max_splat_radius = 2.5", "max_splat_radius = 3");
  const std::string msg = errorOf(dir_, DatasetParts::Cells);
  EXPECT_NE(msg.find("cells.bin"), std::string::npos) << msg;
  EXPECT_NE(msg.find("max_splat_radius 3"), std::string::npos) << msg;
  EXPECT_NO_THROW(Dataset::open(dir_, DatasetParts::TopLevel));
}

TEST_F(DatasetTest, BadManifestRadiusIsRefused) {
  write(makeContent());
  for (const char* bad : {"-1", "inf", "nan", "big", ""}) {
    replaceInManifest("max_splat_radius = 2\n", std::string("max_splat_radius = ") + bad + "\n");
    const std::string msg = errorOf(dir_, DatasetParts::Manifest);
    EXPECT_NE(msg.find("manifest.txt:"), std::string::npos) << msg;
    EXPECT_NE(msg.find("max_splat_radius"), std::string::npos) << msg;
    replaceInManifest(std::string("max_splat_radius = ") + bad + "\n", "max_splat_radius = 2\n");
  }
  replaceInManifest("max_splat_radius = 2\n", "");
  EXPECT_NE(errorOf(dir_).find("missing key 'max_splat_radius'"), std::string::npos);
}

TEST_F(DatasetTest, ManifestSyntaxErrorsNameTheLine) {
  EXPECT_THROW(DatasetManifest::parse("format = something-else\n", "m"), InputError);
  const std::string start =
      "format = pointillist-dataset\n" + versionLine(kDatasetFormatVersion) + "\n";
  try {
    DatasetManifest::parse(start + "no equals sign\n", "m.txt");
    FAIL();
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("m.txt:3:"), std::string::npos) << e.what();
  }
  try {
    DatasetManifest::parse(start, "m.txt");
    FAIL();
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("missing key"), std::string::npos) << e.what();
  }
}

TEST_F(DatasetTest, InconsistentCellArrayIsRefused) {
  DatasetContent base = makeContent();
  finalizeDatasetContent(base);
  auto expectRefused = [&](const char* what, auto mutate) {
    DatasetContent c = base;
    mutate(c);
    try {
      validateDatasetStructure(c.manifest, c.cells, c.topLevel, "ds");
      ADD_FAILURE() << "accepted: " << what;
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find(what), std::string::npos) << e.what();
    }
  };
  EXPECT_NO_THROW(validateDatasetStructure(base.manifest, base.cells, base.topLevel, "ds"));
  expectRefused("nextSibling", [](DatasetContent& c) { c.cells[1].nextSibling = 99; });
  expectRefused("nextSibling", [](DatasetContent& c) { c.cells[3].nextSibling = 1; });
  expectRefused("nextSibling", [](DatasetContent& c) { c.cells[3].nextSibling = kNoIndex; });
  expectRefused("topLevel", [](DatasetContent& c) { c.cells[4].topLevel = 7; });
  expectRefused("outside its packet", [](DatasetContent& c) { c.cells[4].pointsCount = 9; });
  expectRefused("outside its packet", [](DatasetContent& c) { c.cells[3].splatsOffset = 3; });
  // Layers: coarse first, no overlaps, no gaps.
  expectRefused("coarse-first", [](DatasetContent& c) {
    c.cells[2].splatsOffset = 1;
    c.cells[3].splatsOffset = 0;
  });
  expectRefused("overlap", [](DatasetContent& c) { c.cells[4].splatsOffset = 1; });
  expectRefused("2 of its 3 level-splats", [](DatasetContent& c) { c.cells[4].splatsCount = 0; });
  expectRefused("level", [](DatasetContent& c) { c.cells[2].level = 5; });
  expectRefused("leaf flag", [](DatasetContent& c) { c.cells[2].flags = kCellFlagLeaf; });
  expectRefused("depth", [](DatasetContent& c) { c.cells[3].depth = 4; });
  expectRefused("bounds", [](DatasetContent& c) { c.cells[3].boundsMax[0] = 100; });
  expectRefused("maxSplatRadius", [](DatasetContent& c) { c.cells[3].maxSplatRadius = 9; });
  expectRefused("max_splat_radius", [](DatasetContent& c) { c.manifest.maxSplatRadius = 1; });
  expectRefused("contiguous", [](DatasetContent& c) { c.topLevel[1].byteOffset += 32; });
  expectRefused("whose topLevel", [](DatasetContent& c) { c.cells[1].topLevel = kNoIndex; });
}

TEST_F(DatasetTest, InconsistentCellFileIsRefusedAtLoad) {
  write(makeContent());
  // Damage the structure but keep the checksum right: the validator must catch it.
  DatasetContent c = makeContent();
  c.cells[1].nextSibling = 3;
  std::ofstream(dir_ / "cells.bin", std::ios::binary | std::ios::trunc)
      .write(reinterpret_cast<const char*>(c.cells.data()),
             static_cast<std::streamsize>(c.cells.size() * 64));
  const Dataset before = Dataset::open(dir_, DatasetParts::Manifest);
  const auto* f = before.manifest().file("cells");
  char old[17], now[17];
  std::snprintf(old, sizeof old, "%016llx", static_cast<unsigned long long>(*f->checksum));
  std::snprintf(now, sizeof now, "%016llx",
                static_cast<unsigned long long>(checksum64(c.cells.data(), c.cells.size() * 64)));
  replaceInManifest(old, now);
  const std::string msg = errorOf(dir_, DatasetParts::Cells);
  EXPECT_NE(msg.find("cells.bin: cell 1: nextSibling"), std::string::npos) << msg;
}

TEST_F(DatasetTest, WriterRefusesToClobberAndCleansUp) {
  write(makeContent());
  DatasetContent again = makeContent();
  EXPECT_THROW(writeDataset(dir_, again), UsageError);
  // Overwrite replaces a dataset ...
  again = makeContent();
  again.manifest.source = "second";
  writeDataset(dir_, again, true);
  EXPECT_EQ(Dataset::open(dir_).manifest().source, "second");
  // ... but never a directory that is not one.
  fs::create_directories(root_ / "precious");
  std::ofstream(root_ / "precious" / "keep.txt") << "x";
  again = makeContent();
  EXPECT_THROW(writeDataset(root_ / "precious", again, true), UsageError);
  EXPECT_TRUE(fs::exists(root_ / "precious" / "keep.txt"));
  // Inconsistent content fails before anything is left behind.
  again = makeContent();
  again.cells[1].level = 9;
  EXPECT_THROW(writeDataset(root_ / "bad", again), Error);
  EXPECT_FALSE(fs::exists(root_ / "bad"));
  std::size_t entries = 0;
  for ([[maybe_unused]] const auto& e : fs::directory_iterator(root_)) ++entries;
  EXPECT_EQ(entries, 2u);  // ds and precious
}

TEST_F(DatasetTest, FailureWhileWritingRemovesTheTemporaryDirectory) {
  DatasetContent c = makeContent();
  int calls = 0;
  EXPECT_THROW(writeDataset(root_ / "late", c, false,
                            [&](std::uint64_t, std::uint64_t) {
                              if (++calls == 2) throw Error("interrupted");
                            }),
               Error);
  EXPECT_EQ(calls, 2);
  EXPECT_TRUE(fs::is_empty(root_));
}

TEST_F(DatasetTest, ExtraFilesAreWrittenAndVerified) {
  DatasetContent c = makeContent();
  c.extraFiles.push_back({"pca", "pca.bin", {std::byte{1}, std::byte{2}, std::byte{3}}});
  write(c);
  const Dataset ds = Dataset::open(dir_, DatasetParts::Manifest);
  const auto bytes = ds.readFile("pca");
  ASSERT_EQ(bytes.size(), 3u);
  EXPECT_EQ(bytes[2], std::byte{3});
  flipByte(dir_ / "pca.bin", 1);
  EXPECT_THROW(ds.readFile("pca"), InputError);
  EXPECT_THROW(ds.readFile("nope"), InputError);
}

}  // namespace
}  // namespace pointillist
