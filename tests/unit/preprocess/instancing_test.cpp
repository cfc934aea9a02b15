// Seed 000: transformation palettes by FFT, vertex-transformation pools, and
// the instanced section that carries them.
#include "preprocess/instancing.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <map>
#include <numeric>
#include <random>

#include <unistd.h>

#include "common/dataset.hpp"
#include "common/errors.hpp"
#include "common/instanced_section.hpp"
#include "preprocess/dataset_builder.hpp"
#include "preprocess/generator.hpp"
#include "preprocess/readers.hpp"

namespace pointillist::preprocess {
namespace {

Splat pointAt(float x, float y, float z, float radius = 2.0f) {
  Splat s{};
  s.position[0] = x;
  s.position[1] = y;
  s.position[2] = z;
  s.normal[2] = 1.0f;
  s.radius = radius;
  s.color[0] = 200;
  s.color[1] = 100;
  s.color[2] = 50;
  s.color[3] = 255;
  return s;
}

// Sections are read from 32-byte records in a packet: keep the bytes aligned.
InstancedSectionView parse(const std::vector<std::byte>& bytes, std::vector<Splat>& storage) {
  storage.assign(bytes.size() / sizeof(Splat), Splat{});
  std::memcpy(storage.data(), bytes.data(), bytes.size());
  return parseInstancedSection(std::span<const Splat>(storage), "test");
}

// The voxel of every input point on the section's grid, as quantizeCell puts it.
Voxel voxelOnGrid(const InstancedHeader& h, const Splat& s) {
  Voxel v{};
  for (int a = 0; a < 3; ++a)
    v.q[a] = static_cast<std::int32_t>(
        std::lround((double{s.position[a]} - double{h.origin[a]}) / double{h.step}));
  return v;
}

// Nothing lost, nothing invented: the pools' voxels plus the remainder's are
// the quantized input, point for point.
void expectSameQuantizedSet(std::span<const Splat> points, const InstancedSectionView& view,
                            const InstancingOptions& options) {
  const QuantizedCell grid = quantizeCell(points, options);
  std::vector<Voxel> expected = grid.voxels;
  std::vector<Voxel> got = generatedVoxels(view);
  for (const Splat& s : view.remainder) got.push_back(voxelOnGrid(view.header, s));
  std::sort(expected.begin(), expected.end());
  std::sort(got.begin(), got.end());
  EXPECT_EQ(got.size(), points.size());
  EXPECT_TRUE(got == expected);
}

// Seed 000 figure 3: four source vertices and four translations (the null
// one included) generate the 16-point set exactly.
TEST(Instancing, PaperFigure3FactorsExactly) {
  std::vector<Splat> points;
  for (int sx : {0, 1})
    for (int sy : {0, 1}) points.push_back(pointAt(float(sx), float(sy), 0.0f));
  for (int x = 0; x < 4; ++x)
    for (int y = 0; y < 4; ++y)
      if (x > 1 || y > 1) points.push_back(pointAt(float(x), float(y), 0.0f));
  ASSERT_EQ(points.size(), 16u);
  InstancingOptions options;
  options.stepShare = 0.5;  // radius 2: a step of 1, one voxel per point
  options.minPoolPoints = 1;
  const QuantizedCell grid = quantizeCell(points, options);
  EXPECT_EQ(grid.step, 1.0f);
  EXPECT_EQ(grid.dims, (std::array<std::int32_t, 3>{4, 4, 1}));
  const std::vector<TranslationCount> palette = {{{2, 0, 0}, 8}, {{0, 2, 0}, 8}, {{2, 2, 0}, 4}};
  InstancingStats stats;
  const auto bytes = encodeInstancedCell(points, grid, palette, options, stats);
  ASSERT_FALSE(bytes.empty());
  std::vector<Splat> storage;
  const InstancedSectionView view = parse(bytes, storage);
  ASSERT_EQ(view.pools.size(), 1u);
  EXPECT_EQ(view.pools[0].vertices.size(), 4u);
  EXPECT_EQ(view.pools[0].translations.size(), 4u);
  EXPECT_TRUE(view.remainder.empty());
  EXPECT_EQ(view.header.generatedCount, 16u);
  for (const InstancedVertex& v : view.pools[0].vertices) {
    EXPECT_LE(v.q[0], 1);
    EXPECT_LE(v.q[1], 1);
    EXPECT_EQ(v.tag[0], 0xFu);  // every translation applies to every white vertex
  }
  expectSameQuantizedSet(points, view, options);
  EXPECT_EQ(stats.covered, 16u);
  EXPECT_EQ(stats.colorErrorMax, 0);
}

// The FFT autocorrelation counts every translation as comparing all pairs does.
TEST(Instancing, FftTranslationCountsEqualBruteForce) {
  std::mt19937 random(7);
  for (const std::array<std::int32_t, 3> dims :
       {std::array<std::int32_t, 3>{20, 13, 7}, {33, 1, 5}, {64, 64, 3}}) {
    SCOPED_TRACE(dims[0]);
    std::vector<Voxel> voxels;
    // A repeated motif and random clutter, all distinct.
    for (std::int32_t x = 0; x + 3 < dims[0]; x += 4)
      for (std::int32_t y = 0; y < dims[1]; y += 3) voxels.push_back({{x, y, 0}});
    for (int i = 0; i < 150; ++i)
      voxels.push_back({{std::int32_t(random() % std::uint32_t(dims[0])),
                         std::int32_t(random() % std::uint32_t(dims[1])),
                         std::int32_t(random() % std::uint32_t(dims[2]))}});
    std::sort(voxels.begin(), voxels.end());
    voxels.erase(std::unique(voxels.begin(), voxels.end()), voxels.end());

    std::vector<TranslationCount> expected;
    for (const TranslationCount& c : bruteForceTranslationCounts(voxels))
      if (c.count >= 2) expected.push_back(c);
    std::sort(expected.begin(), expected.end(), [](const auto& a, const auto& b) {
      return a.count != b.count ? a.count > b.count : a.t < b.t;
    });
    ASSERT_FALSE(expected.empty());
    // No window: every translation between voxels of the grid.
    EXPECT_EQ(translationPalette(voxels, dims, 1000000, 1 << 20), expected);
    // A window keeps the translations within it, counted the same.
    std::vector<TranslationCount> windowed;
    for (const TranslationCount& c : expected)
      if (std::abs(c.t[0]) <= 9 && std::abs(c.t[1]) <= 9 && std::abs(c.t[2]) <= 9)
        windowed.push_back(c);
    EXPECT_EQ(translationPalette(voxels, dims, 1000000, 9), windowed);
    // The palette is the strongest translations.
    const auto top = translationPalette(voxels, dims, 16, 1 << 20);
    ASSERT_EQ(top.size(), std::min<std::size_t>(16, expected.size()));
    EXPECT_TRUE(std::equal(top.begin(), top.end(), expected.begin()));
  }
}

// A façade of identical windows: the palette finds the window spacing and the
// pools generate most points; the decoded set is the quantized input.
TEST(Instancing, RepeatedGeometryIsCoveredByPoolsAndNothingIsLost) {
  std::vector<Splat> points;
  std::mt19937 random(3);
  std::uniform_real_distribution<float> jitter(-0.2f, 0.2f);
  for (int wx = 0; wx < 6; ++wx)
    for (int wy = 0; wy < 4; ++wy)
      for (int x = 0; x < 8; ++x)
        for (int y = 0; y < 10; ++y) {
          // A window frame: only the border of an 8 x 10 patch.
          if (x != 0 && x != 7 && y != 0 && y != 9) continue;
          points.push_back(pointAt(float(wx * 12 + x), float(wy * 15 + y), 0.0f));
        }
  for (int i = 0; i < 200; ++i)  // unique clutter that nothing repeats
    points.push_back(pointAt(70.0f + jitter(random) * 40.0f, 70.0f + jitter(random) * 40.0f,
                             5.0f + jitter(random) * 10.0f));
  InstancingOptions options;
  InstancingStats stats;
  const auto bytes = instanceCell(points, options, stats);
  ASSERT_FALSE(bytes.empty());
  std::vector<Splat> storage;
  const InstancedSectionView view = parse(bytes, storage);
  EXPECT_GE(view.pools.size(), 1u);
  EXPECT_GT(stats.covered, points.size() * 7 / 10);
  EXPECT_LT(stats.sectionBytes, stats.plainBytes / 2);
  expectSameQuantizedSet(points, view, options);
  const auto expanded = expandInstancedSection(view);
  EXPECT_EQ(expanded.size(), points.size());
}

// Real scans and meshes, and the built-in city: every point survives, within
// the grid's error and the colour tolerance.
TEST(Instancing, RealDataDecodesToTheQuantizedInput) {
  std::vector<std::pair<std::string, std::vector<Splat>>> inputs;
  inputs.emplace_back("city", generateScene("city", 6000, 5).splats);
  const std::filesystem::path data = std::filesystem::path(POINTILLIST_TEST_DATA_DIR) / "data";
  if (std::filesystem::exists(data)) {
    ReadOptions read;
    read.meshSamplePoints = 6000;
    inputs.emplace_back("bunny", readPointCloud(data / "meshes" / "bunny00.off", read).splats);
  }
  for (auto& [name, points] : inputs) {
    SCOPED_TRACE(name);
    // Radii as the preprocess would leave them: about the point spacing.
    for (Splat& s : points) s.radius = s.radius > 0.0f ? s.radius : 0.01f;
    InstancingOptions options;
    InstancingStats stats;
    const auto bytes = instanceCell(points, options, stats);
    ASSERT_FALSE(bytes.empty());
    std::vector<Splat> storage;
    const InstancedSectionView view = parse(bytes, storage);
    expectSameQuantizedSet(points, view, options);
    EXPECT_LE(stats.colorErrorMax, options.colorTolerance);
    const double halfDiagonal = std::sqrt(3.0) * 0.5 * double{view.header.step};
    EXPECT_LE(stats.positionErrorMax, halfDiagonal * 1.0001);
    EXPECT_LE(stats.sectionBytes, stats.plainBytes);
    // Pools formed: the figures above concern generated points, not a plain copy.
    EXPECT_GT(stats.covered, points.size() / 5);
    EXPECT_GE(view.pools.size(), 1u);
  }
}

TEST(Instancing, DamagedSectionsAreRefused) {
  std::vector<Splat> points;
  for (int x = 0; x < 6; ++x)
    for (int y = 0; y < 6; ++y) points.push_back(pointAt(float(x), float(y), 0.0f));
  InstancingOptions options;
  options.minCellPoints = 1;
  options.minPoolPoints = 1;
  InstancingStats stats;
  const auto good = instanceCell(points, options, stats);
  ASSERT_FALSE(good.empty());
  std::vector<Splat> storage;
  EXPECT_NO_THROW(parse(good, storage));

  auto damaged = good;
  damaged[0] = std::byte{0};
  EXPECT_THROW(parse(damaged, storage), InputError);

  // A tag bit beyond the pool's translations.
  damaged = good;
  const InstancedSectionView view = parse(good, storage);
  InstancedPool pool{};
  std::memcpy(&pool, good.data() + sizeof(InstancedHeader), sizeof(pool));
  ASSERT_LT(pool.translationCount, kPoolTranslations);
  InstancedVertex v{};
  std::memcpy(&v, good.data() + pool.vertexOffset, sizeof(v));
  tagSet(v, pool.translationCount);
  std::memcpy(damaged.data() + pool.vertexOffset, &v, sizeof(v));
  EXPECT_THROW(parse(damaged, storage), InputError);

  // A vertex moved off the grid.
  damaged = good;
  std::memcpy(&v, good.data() + pool.vertexOffset, sizeof(v));
  v.q[0] = static_cast<std::uint16_t>(1u << view.header.bits);
  std::memcpy(damaged.data() + pool.vertexOffset, &v, sizeof(v));
  EXPECT_THROW(parse(damaged, storage), InputError);

  // Truncated.
  damaged.assign(good.begin(), good.begin() + 32);
  EXPECT_THROW(parse(damaged, storage), InputError);
}

// --instanced: every packet carries its units' sections between the
// level-splats and the points; the dataset opens and validates, the cells
// still address the original points, the units partition the points and
// their sections tile the packet's section records, and each section decodes
// to its unit's points.
TEST(Instancing, DatasetCarriesSectionsBetweenLevelSplatsAndPoints) {
  PreprocessOptions options;
  options.instancing = InstancingOptions{};
  options.instancing->unitPoints = 512;
  InstancingStats stats;
  options.instancingStats = &stats;
  options.radiiInLeaves = true;
  const std::vector<Splat> input = generateScene("city", 30000, 9).splats;
  DatasetContent plain = buildDatasetContent(input, PreprocessOptions{});
  DatasetContent content = buildDatasetContent(input, options);
  ASSERT_GT(stats.cellsInstanced, 0u);
  ASSERT_FALSE(content.instancedRecords.empty());

  const auto dir = std::filesystem::temp_directory_path() /
                   ("pointillist-instanced-" + std::to_string(::getpid()));
  std::filesystem::remove_all(dir);
  writeDataset(dir, content);
  const Dataset ds = Dataset::open(dir, DatasetParts::All);
  const std::vector<std::byte> file = ds.readFile(kInstancedSectionsKey);
  std::filesystem::remove_all(dir);
  EXPECT_EQ(ds.manifest().instancedRecordCount, content.instancedRecords.size());
  const auto cells = ds.cells();
  ASSERT_EQ(file.size(), cells.size() * sizeof(InstancedCellSection));
  std::vector<InstancedCellSection> sections(cells.size());
  std::memcpy(sections.data(), file.data(), file.size());

  const auto table = ds.topLevelCells();
  std::uint64_t generated = 0, plainBefore = 0;
  for (std::uint32_t k = 0; k < table.size(); ++k) {
    const auto packet = ds.packet(k);
    const TopLevelCell& t = table[k];
    const OctreeCell& root = cells[t.cellIndex];
    EXPECT_EQ(root.pointsOffset, pointsStart(t));
    // The same points as the plain dataset's, at the shifted offset.
    const auto points = packet.subspan(root.pointsOffset, t.pointCount);
    ASSERT_EQ(std::memcmp(points.data(), plain.points.data() + plainBefore, points.size_bytes()),
              0);
    plainBefore += t.pointCount;
    // Units in depth-first order: sections back to back, points partitioned.
    std::uint64_t nextRecord = t.levelSplatCount, unitPoints = 0;
    for (const std::uint32_t unit : instancingUnits(cells, t.cellIndex, 512)) {
      const InstancedCellSection& section = sections[unit];
      ASSERT_GT(section.records, 0u) << "every unit has a section";
      EXPECT_EQ(section.offset, nextRecord);
      nextRecord += section.records;
      const OctreeCell& c = cells[unit];
      unitPoints += c.pointsCount;
      const auto view =
          parseInstancedSection(packet.subspan(section.offset, section.records), "test");
      EXPECT_EQ(view.header.generatedCount + view.remainder.size(), c.pointsCount);
      expectSameQuantizedSet(packet.subspan(c.pointsOffset, c.pointsCount), view,
                             *options.instancing);
      generated += view.header.generatedCount;
    }
    EXPECT_EQ(nextRecord, pointsStart(t));
    EXPECT_EQ(unitPoints, t.pointCount);
  }
  EXPECT_EQ(generated, stats.covered);
}

}  // namespace
}  // namespace pointillist::preprocess
