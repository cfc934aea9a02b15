// The SIMD point kernel against its scalar reference, bit for bit, on every
// Highway target this CPU runs: jobs compare tiles drawn by one process with a
// full frame drawn by another, so any difference would show as wrong pixels.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <new>
#include <random>
#include <set>
#include <string>
#include <vector>

#include <glm/glm.hpp>

#include "render/raster/cpu_point_renderer.hpp"
#include "render_test_util.hpp"

namespace pointillist::render {
namespace {

using testing::makeSplat;

constexpr std::uint32_t kWidth = 320, kHeight = 200;

// Oblique, so that no matrix entry is 0 or 1 and every product rounds.
Camera kernelCamera() {
  return makeCamera({1.3f, 2.1f, 4.6f}, {0.1f, -0.2f, 0.3f}, {0.1f, 1.0f, 0.05f}, 40.0f, 1.0f,
                    10.0f, kWidth, kHeight);
}

// Points anywhere around the view (behind the eye, before the near and beyond
// the far plane, outside the frame), points on the near and far planes and on
// pixel boundaries, with and without normals, 1 to 10 px wide and beyond.
std::vector<Splat> edgeScene(std::size_t count, std::uint32_t seed) {
  const Camera camera = kernelCamera();
  const glm::mat4 inverse = glm::inverse(viewProjectionMatrix(camera));
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f), r01(0.0f, 1.0f);
  std::uniform_int_distribution<int> kind(0, 9), pixel(-20, 340);
  std::vector<Splat> splats;
  splats.reserve(count);
  for (std::size_t i = 0; i < count; ++i) {
    glm::vec3 p;
    switch (kind(rng)) {
      case 0: {  // on the near or far plane (up to rounding)
        const glm::vec4 h = inverse * glm::vec4(u(rng), u(rng), i % 2 == 0 ? -1.0f : 1.0f, 1.0f);
        p = glm::vec3(h) / h.w;
        break;
      }
      case 1: {  // on a pixel edge or centre in window coordinates
        const float wx = static_cast<float>(pixel(rng)) + 0.5f * static_cast<float>(i % 2);
        const float wy = static_cast<float>(pixel(rng)) + 0.5f * static_cast<float>(i % 3 == 0);
        const glm::vec4 h = inverse * glm::vec4(wx / kWidth * 2.0f - 1.0f,
                                                wy / kHeight * 2.0f - 1.0f, u(rng), 1.0f);
        p = glm::vec3(h) / h.w;
        break;
      }
      case 2:  // anywhere, also behind the eye (z > 5)
        p = {8.0f * u(rng), 8.0f * u(rng), 8.0f * u(rng)};
        break;
      default:
        p = {2.0f * u(rng), 2.0f * u(rng), 3.0f * u(rng)};
    }
    glm::vec3 n(0.0f);
    switch (i % 4) {
      case 0:
        n = glm::normalize(glm::vec3(u(rng), u(rng), u(rng)) + glm::vec3(1e-3f));
        break;
      case 1:
        n = glm::vec3(u(rng), u(rng), u(rng)) * 0.8f;  // not unit; some below 0.5
        break;
      default:
        break;  // no normal
    }
    // Diameters of 1 to ~10 px at the middle of the view; some far larger.
    float radius = (0.003f + 0.03f * r01(rng) * r01(rng)) * (i % 97 == 0 ? 30.0f : 1.0f);
    if (i % 101 == 0) radius = -radius;
    if (i % 103 == 0) radius = 0.0f;
    splats.push_back(makeSplat(p.x, p.y, p.z, radius, static_cast<std::uint8_t>(rng()),
                               static_cast<std::uint8_t>(rng()), static_cast<std::uint8_t>(rng()),
                               n.x, n.y, n.z));
    splats.back().color[3] = static_cast<std::uint8_t>(rng());
  }
  return splats;
}

std::vector<RenderSettings> settingsVariants() {
  std::vector<RenderSettings> variants;
  for (const bool lighting : {true, false}) {
    for (const float pointSize : {0.0f, 1.0f, 2.0f, 3.4f}) {
      RenderSettings s;
      s.lighting = lighting;
      s.pointSize = pointSize;
      variants.push_back(s);
    }
  }
  RenderSettings small;
  small.maxPointSize = 5.0f;
  small.ambient = 0.0f;
  small.sizeScale = 1.7f;
  variants.push_back(small);
  return variants;
}

// Runs `check` once per Highway target the kernel can use here, with the
// kernel forced to it.
template <class Check>
void forEachTarget(Check check) {
  const std::vector<std::int64_t> targets = pointKernelTargets();
  ASSERT_FALSE(targets.empty());
  std::set<std::string> names;
  for (const std::int64_t target : targets) {
    forcePointKernelTarget(target);
    const std::string name = pointKernelTargetName();
    names.insert(name);
    SCOPED_TRACE(name);
    check();
  }
  forcePointKernelTarget(0);
  EXPECT_EQ(names.size(), targets.size()) << "forcing a target did not change the kernel";
}

TileRect randomTile(std::mt19937& rng) {
  std::uniform_int_distribution<std::uint32_t> x(0, kWidth - 1), y(0, kHeight - 1);
  const std::uint32_t x0 = x(rng), y0 = y(rng);
  std::uniform_int_distribution<std::uint32_t> w(1, kWidth - x0), h(1, kHeight - y0);
  return makeTileRect(x0, y0, w(rng), h(rng));
}

void expectSameFootprints(const PointRaster& raster, std::span<const Splat> splats,
                          const PointCell& cell, std::size_t from, std::size_t to) {
  const std::vector<PointFootprint> simd = pointFootprints(raster, cell, from, to);
  ASSERT_EQ(simd.size(), to - from);
  std::size_t differ = 0, drawn = 0;
  for (std::size_t i = from; i < to; ++i) {
    const PointFootprint expected = pointFootprintScalar(raster, splats[i]);
    drawn += expected.x1 > expected.x0 ? 1u : 0u;
    if (simd[i - from] == expected) continue;
    if (++differ <= 5) {
      const PointFootprint& got = simd[i - from];
      ADD_FAILURE() << "splat " << i << ": expected [" << expected.x0 << "," << expected.x1 << ")x["
                    << expected.y0 << "," << expected.y1 << ") " << std::hex << expected.word
                    << std::dec << ", got [" << got.x0 << "," << got.x1 << ")x[" << got.y0 << ","
                    << got.y1 << ") " << std::hex << got.word;
    }
  }
  EXPECT_EQ(differ, 0u);
  if (to - from > 1000 && raster.tileWidth == static_cast<std::int32_t>(kWidth)) {
    EXPECT_GT(drawn, (to - from) / 10);  // the scene is not all culled
  }
}

TEST(CpuPointKernel, EverySplatGetsTheReferenceWordAndPixels) {
  const std::vector<Splat> splats = edgeScene(120000, 17);
  const PointCell cell = makePointCell(splats);
  const Camera camera = kernelCamera();
  std::mt19937 rng(5);
  forEachTarget([&] {
    for (const RenderSettings& settings : settingsVariants()) {
      expectSameFootprints(pointRaster(camera, fullFrameRect(camera), settings), splats, cell, 0,
                           splats.size());
      const TileRect tile = randomTile(rng);
      expectSameFootprints(pointRaster(camera, tile, settings), splats, cell, 3, splats.size() - 5);
    }
  });
}

std::vector<std::uint64_t> drawScalar(const PointRaster& raster, std::span<const Splat> splats) {
  std::vector<std::uint64_t> buffer(
      static_cast<std::size_t>(raster.tileWidth) * static_cast<std::size_t>(raster.tileHeight),
      kEmptyPixel);
  rasterizePointsScalar(raster, splats, buffer.data());
  return buffer;
}

std::vector<std::uint64_t> drawSimd(const PointRaster& raster, const PointCell& cell,
                                    std::size_t from, std::size_t to) {
  std::vector<std::uint64_t> buffer(
      static_cast<std::size_t>(raster.tileWidth) * static_cast<std::size_t>(raster.tileHeight),
      kEmptyPixel);
  rasterizePoints(raster, cell, from, to, buffer.data());
  return buffer;
}

// Odd counts and offsets put splats in every lane and in partial vectors.
TEST(CpuPointKernel, OddCountsAndOffsetsDrawAsTheReference) {
  const std::vector<Splat> splats = edgeScene(3000, 23);
  const PointCell cell = makePointCell(splats);
  const Camera camera = kernelCamera();
  const std::size_t counts[] = {1, 2, 3, 7, 8, 9, 15, 16, 17, 31, 33, 63, 65, 255, 257, 1001};
  const std::size_t offsets[] = {0, 1, 5, 15, 16, 17, 1000};
  forEachTarget([&] {
    for (const RenderSettings& settings : {settingsVariants()[0], settingsVariants()[4]}) {
      const PointRaster raster = pointRaster(camera, fullFrameRect(camera), settings);
      for (const std::size_t count : counts) {
        for (const std::size_t offset : offsets) {
          const std::span<const Splat> part(splats.data() + offset, count);
          EXPECT_TRUE(drawSimd(raster, cell, offset, offset + count) == drawScalar(raster, part))
              << count << " splats from " << offset;
          expectSameFootprints(raster, splats, cell, offset, offset + count);
        }
      }
    }
  });
}

TEST(CpuPointKernel, SubTilesDrawAsTheReference) {
  const std::vector<Splat> splats = edgeScene(100000, 29);
  const PointCell cell = makePointCell(splats);
  const Camera camera = kernelCamera();
  std::mt19937 rng(31);
  forEachTarget([&] {
    for (const RenderSettings& settings : settingsVariants()) {
      for (int i = 0; i < 4; ++i) {
        const TileRect tile = randomTile(rng);
        const PointRaster raster = pointRaster(camera, tile, settings);
        EXPECT_TRUE(drawSimd(raster, cell, 0, splats.size()) == drawScalar(raster, splats))
            << "tile " << tile.x() << "," << tile.y() << " " << tile.width() << "x"
            << tile.height();
      }
    }
  });
}

// Many short ranges of several cells in one pass draw what the scalar
// reference draws for the same splats: batches run across ranges, empty ranges
// and ranges of one splat included.
TEST(CpuPointKernel, ManyShortRangesInOnePassDrawAsTheReference) {
  const std::vector<Splat> splats = edgeScene(40000, 41);
  std::vector<PointCell> cells;
  for (std::size_t begin = 0; begin < splats.size(); begin += 10000) {
    cells.push_back(makePointCell({splats.data() + begin, 10000}));
  }
  std::mt19937 rng(43);
  std::vector<PointRange> ranges;
  std::vector<Splat> drawn;
  for (int k = 0; k < 600; ++k) {
    const std::size_t which = rng() % cells.size();
    const std::size_t from = rng() % 9990;
    const std::size_t count = k % 7 == 0 ? 0 : 1 + rng() % (k % 3 == 0 ? 9 : 70);
    const std::size_t to = std::min<std::size_t>(from + count, 10000);
    ranges.push_back({&cells[which], from, to});
    drawn.insert(drawn.end(), splats.begin() + static_cast<std::ptrdiff_t>(which * 10000 + from),
                 splats.begin() + static_cast<std::ptrdiff_t>(which * 10000 + to));
  }
  const Camera camera = kernelCamera();
  forEachTarget([&] {
    for (const RenderSettings& settings : {settingsVariants()[0], settingsVariants()[4]}) {
      const PointRaster raster = pointRaster(camera, fullFrameRect(camera), settings);
      std::vector<std::uint64_t> buffer(
          static_cast<std::size_t>(raster.tileWidth) * static_cast<std::size_t>(raster.tileHeight),
          kEmptyPixel);
      rasterizePointRanges(raster, ranges, buffer.data());
      const auto expected = drawScalar(raster, drawn);
      EXPECT_TRUE(buffer == expected);
      EXPECT_GT(std::count_if(buffer.begin(), buffer.end(),
                              [](std::uint64_t word) { return word != kEmptyPixel; }),
                1000);
    }
  });
}

// A cell grown part by part (as layered packets arrive) holds what one upload
// of the same splats holds, padding zeros included, and draws the same.
TEST(CpuPointKernel, ACellGrownInPartsEqualsOneUpload) {
  const std::vector<Splat> splats = edgeScene(5000, 47);
  const PointCell whole = makePointCell(splats);
  PointCell grown;
  std::size_t at = 0;
  for (const std::size_t part : std::initializer_list<std::size_t>{1, 15, 16, 17, 200, 751, 4000}) {
    appendToPointCell(grown, {splats.data() + at, part});
    at += part;
  }
  ASSERT_EQ(at, splats.size());
  ASSERT_EQ(grown.count, whole.count);
  EXPECT_EQ(grown.hasNormals, whole.hasNormals);
  const std::size_t padded =
      (whole.count + PointCell::kPad - 1) / PointCell::kPad * PointCell::kPad;
  for (std::size_t i = 0; i < padded; ++i) {
    ASSERT_EQ(*grown.x(i), *whole.x(i)) << i;
    ASSERT_EQ(*grown.z(i), *whole.z(i)) << i;
    ASSERT_EQ(*grown.radius(i), *whole.radius(i)) << i;
    ASSERT_EQ(*grown.nz(i), *whole.nz(i)) << i;
    ASSERT_EQ(*grown.color(i), *whole.color(i)) << i;
  }
  EXPECT_EQ(*whole.x(padded - 1) == 0.0f, whole.count < padded);
  const Camera camera = kernelCamera();
  const PointRaster raster = pointRaster(camera, fullFrameRect(camera), settingsVariants()[0]);
  EXPECT_TRUE(drawSimd(raster, grown, 0, grown.count) == drawScalar(raster, splats));
}

// A cell written in ranges out of order, with holes between them (a render
// holds the ranges its tiles draw), draws each range as one upload of the
// whole packet does.
TEST(CpuPointKernel, ACellWrittenInRangesDrawsTheRangesAsTheWholePacket) {
  const std::vector<Splat> splats = edgeScene(5000, 61);
  const PointCell whole = makePointCell(splats);
  const std::span<const Splat> all(splats);
  PointCell ranged;
  // The far ranges first, made room for once; then nearer ones, one that
  // overlaps data held (the same splats), and one that starts mid-group.
  writeToPointCell(ranged, 4000, all.subspan(4000, 1000), 5000);
  writeToPointCell(ranged, 1000, all.subspan(1000, 500));
  writeToPointCell(ranged, 1400, all.subspan(1400, 300));
  writeToPointCell(ranged, 7, all.subspan(7, 9));
  EXPECT_EQ(ranged.count, splats.size());
  const Camera camera = kernelCamera();
  const std::pair<std::size_t, std::size_t> held[] = {{7, 16}, {1000, 1700}, {4000, 5000}};
  for (const RenderSettings& settings : settingsVariants()) {
    const PointRaster raster = pointRaster(camera, fullFrameRect(camera), settings);
    for (const auto& [from, to] : held) {
      EXPECT_TRUE(drawSimd(raster, ranged, from, to) == drawSimd(raster, whole, from, to))
          << from << "-" << to;
    }
  }
  // A hole reads as zeros, never as another cell's data.
  EXPECT_EQ(*ranged.x(2000), 0.0f);
  EXPECT_EQ(*ranged.radius(3), 0.0f);
}

// Vectors of values that start on a cache line, as a laid-out block does.
template <class T>
struct CacheLineAllocator {
  using value_type = T;
  CacheLineAllocator() = default;
  template <class U>
  explicit CacheLineAllocator(const CacheLineAllocator<U>&) {}
  T* allocate(std::size_t n) {
    return static_cast<T*>(
        ::operator new (n * sizeof(T), std::align_val_t{PointGroups::kAlignment}));
  }
  void deallocate(T* p, std::size_t) {
    ::operator delete (p, std::align_val_t{PointGroups::kAlignment});
  }
  bool operator==(const CacheLineAllocator&) const = default;
};
using AlignedFloats = CacheLineAllocator<float>;

// A cell drawn in place from a block laid out elsewhere (a data-send's shared
// memory, common/point_groups.hpp) draws as its own copy; appending to it
// copies what it holds first, and the block is left as it was.
TEST(CpuPointKernel, ACellDrawnInPlaceEqualsItsOwnCopy) {
  const std::vector<Splat> splats = edgeScene(3001, 53);
  std::vector<float, AlignedFloats> block(PointGroups::blockBytes(splats.size()) / 4, 0.0f);
  const bool normals = writePointGroups(splats, 0, block.data());
  const std::vector<float, AlignedFloats> before = block;
  const PointCell whole = makePointCell(splats);
  EXPECT_EQ(normals, whole.hasNormals);
  // Bit for bit (the scene holds NaNs).
  const std::size_t bytes = block.size() * sizeof(float);
  EXPECT_EQ(std::memcmp(block.data(), whole.values(), bytes), 0);

  const std::size_t held = 1000;  // a prefix, as a render holds one
  const PointCell view = PointCell::view(block.data(), held, normals);
  EXPECT_TRUE(view.isView());
  const PointCell copy = makePointCell({splats.data(), held});
  const Camera camera = kernelCamera();
  for (const RenderSettings& settings : settingsVariants()) {
    const PointRaster raster = pointRaster(camera, fullFrameRect(camera), settings);
    EXPECT_TRUE(drawSimd(raster, view, 0, held) == drawSimd(raster, copy, 0, held));
    EXPECT_TRUE(drawSimd(raster, view, 17, 901) == drawScalar(raster, {splats.data() + 17, 884}));
  }

  PointCell grown = PointCell::view(block.data(), held, normals);
  appendToPointCell(grown, {splats.data() + held, splats.size() - held});
  EXPECT_FALSE(grown.isView());
  ASSERT_EQ(grown.count, splats.size());
  EXPECT_EQ(std::memcmp(grown.values(), whole.values(), bytes), 0);
  EXPECT_EQ(std::memcmp(block.data(), before.data(), bytes), 0);

  // Through the renderer: a view, then a longer view of the same block.
  CpuPointRenderer renderer;
  ASSERT_TRUE(renderer.viewCell(7, block.data(), held, normals));
  ASSERT_TRUE(renderer.viewCell(7, block.data(), splats.size(), normals));
  CpuPointRenderer uploaded;
  uploaded.uploadCell(7, splats);
  const DrawRange all{7, 0, static_cast<std::uint32_t>(splats.size())};
  renderer.render(camera, fullFrameRect(camera), {&all, 1}, settingsVariants()[0]);
  uploaded.render(camera, fullFrameRect(camera), {&all, 1}, settingsVariants()[0]);
  EXPECT_TRUE(std::ranges::equal(renderer.pixels(), uploaded.pixels()));
}

// One pixel per point everywhere: the batched 1x1 path.
TEST(CpuPointKernel, ConstantOnePixelDrawsAsTheReference) {
  const std::vector<Splat> splats = edgeScene(50001, 37);
  const PointCell cell = makePointCell(splats);
  const Camera camera = kernelCamera();
  RenderSettings settings;
  settings.pointSize = 1.0f;
  forEachTarget([&] {
    const PointRaster raster = pointRaster(camera, fullFrameRect(camera), settings);
    EXPECT_TRUE(drawSimd(raster, cell, 0, splats.size()) == drawScalar(raster, splats));
  });
}

TEST(CpuPointKernel, DescribeNamesTheTarget) {
  const CpuPointRenderer renderer;
  // Built by appending: GCC 12 at -O3 warns falsely (-Wrestrict) on
  // "literal" + std::string there.
  std::string target = "(";
  target += pointKernelTargetName();
  target += ")";
  EXPECT_NE(renderer.describe().find(target), std::string::npos) << renderer.describe();
}

}  // namespace
}  // namespace pointillist::render
