// A render process that switches renderer for a served frame's mode hands its
// cells over with forEachCell: what comes out must be what went in, and a
// renderer fed that way must draw what one fed directly draws.
#include <gtest/gtest.h>

#include <cstring>
#include <map>
#include <vector>

#include "render/gl/tile_renderers.hpp"
#include "render_test_util.hpp"

namespace pointillist::render {
namespace {

using testing::mixedScene;

std::map<std::uint32_t, std::vector<Splat>> cellsOf(const TileRenderer& renderer) {
  std::map<std::uint32_t, std::vector<Splat>> cells;
  renderer.forEachCell([&](std::uint32_t id, std::span<const Splat> splats) {
    EXPECT_FALSE(cells.contains(id)) << "cell " << id << " visited twice";
    cells[id].assign(splats.begin(), splats.end());
  });
  return cells;
}

bool sameBytes(std::span<const Splat> a, std::span<const Splat> b) {
  return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size_bytes()) == 0;
}

class RendererHandover : public ::testing::TestWithParam<v1::Renderer> {};

TEST_P(RendererHandover, ForEachCellGivesBackEveryCellAsUploaded) {
  auto renderer = makeTileRenderer(GetParam(), GlProfile::Compatibility);
  const auto first = mixedScene(500, 1);
  const auto more = mixedScene(123, 2);
  const auto other = mixedScene(77, 3);
  const auto dropped = mixedScene(10, 4);
  renderer->uploadCell(3, first);
  // More of cell 3 arrived: the range after what it holds.
  renderer->writeToCell(3, static_cast<std::uint32_t>(first.size()), more,
                        first.size() + more.size());
  renderer->writeToCell(7, 0, other, other.size());  // an unknown id starts a cell
  renderer->uploadCell(9, dropped);
  renderer->releaseCell(9);
  renderer->releaseCell(42);  // unknown: nothing happens

  const auto cells = cellsOf(*renderer);
  ASSERT_EQ(cells.size(), 2u);
  std::vector<Splat> three = first;
  three.insert(three.end(), more.begin(), more.end());
  EXPECT_TRUE(sameBytes(cells.at(3), three));
  EXPECT_TRUE(sameBytes(cells.at(7), other));
}

TEST_P(RendererHandover, ARendererFedByAnotherDrawsAsOneFedDirectly) {
  const v1::Renderer from = GetParam();
  const v1::Renderer to = from == v1::RENDERER_CPU ? v1::RENDERER_GL : v1::RENDERER_CPU;
  const auto scene = mixedScene(4000, 5);
  const std::span<const Splat> all(scene);
  auto source = makeTileRenderer(from, GlProfile::Compatibility);
  source->uploadCell(0, all.first(1500));
  source->writeToCell(0, 1500, all.subspan(1500, 1000), 2500);
  source->uploadCell(1, all.subspan(2500));

  auto handedOver = makeTileRenderer(to, GlProfile::Compatibility);
  source->forEachCell(
      [&](std::uint32_t id, std::span<const Splat> splats) { handedOver->uploadCell(id, splats); });
  auto direct = makeTileRenderer(to, GlProfile::Compatibility);
  direct->uploadCell(0, all.first(2500));
  direct->uploadCell(1, all.subspan(2500));

  const Camera camera = makeCamera({0, 0, 4}, {0, 0, 0}, {0, 1, 0}, 45.0f, 0.5f, 10.0f, 200, 150);
  const std::vector<DrawRange> ranges{{0, 100, 2300}, {1, 0, 1500}};
  RenderSettings settings;  // points: the mode both renderers draw
  const RenderStats a = handedOver->render(camera, fullFrameRect(camera), ranges, settings);
  const std::vector<std::uint8_t> handedPixels(handedOver->pixels().begin(),
                                               handedOver->pixels().end());
  const RenderStats b = direct->render(camera, fullFrameRect(camera), ranges, settings);
  EXPECT_EQ(a.splats, b.splats);
  ASSERT_EQ(handedPixels.size(), direct->pixels().size());
  EXPECT_TRUE(std::equal(handedPixels.begin(), handedPixels.end(), direct->pixels().begin()));
  std::size_t lit = 0;
  for (std::size_t i = 0; i < handedPixels.size(); i += 4) {
    lit += handedPixels[i] != 0 || handedPixels[i + 1] != 0 || handedPixels[i + 2] != 0;
  }
  EXPECT_GT(lit, 1000u) << "the scene must show";
}

INSTANTIATE_TEST_SUITE_P(Kinds, RendererHandover,
                         ::testing::Values(v1::RENDERER_CPU, v1::RENDERER_GL),
                         [](const auto& param) {
                           return std::string(param.param == v1::RENDERER_CPU ? "Cpu" : "Gl");
                         });

}  // namespace
}  // namespace pointillist::render
