// pointillist-reference: single-process renderer, no MPI. Renders a dataset
// (every top-level cell's original points) or a built-in scene to a PNG, as
// one full frame or as tiles blitted together (--tiles), and can check that
// both agree (--compare). It is the ground truth the distributed frames are
// compared with.
#include <CLI/CLI.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <exception>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include "common/camera.hpp"
#include "common/dataset.hpp"
#include "common/errors.hpp"
#include "common/image.hpp"
#include "render/offscreen_context.hpp"
#include "render/splat_renderer.hpp"

namespace pointillist::render {
namespace {

struct Scene {
  std::vector<std::vector<Splat>> ownedCells;  // built-in scene
  std::optional<Dataset> dataset;
  glm::vec3 boundsMin{0.0f}, boundsMax{0.0f};
};

std::uint8_t toByte(float v) {
  return static_cast<std::uint8_t>(std::lround(std::clamp(v, 0.0f, 1.0f) * 255.0f));
}

// A sphere on a wavy ground plane with normals, colours and radii from the
// point spacing; split into 8 cells so cell ranges are exercised.
Scene builtinScene(std::size_t count, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  Scene scene;
  scene.ownedCells.resize(8);
  const std::size_t sphereCount = count / 3, groundCount = count - sphereCount;
  const float pi = 3.14159265f;
  // Radius ~1.5x the mean spacing: random sampling leaves gaps wider than the mean.
  const float sphereRadius =
      1.5f * std::sqrt(4.0f * pi * 0.8f * 0.8f / static_cast<float>(sphereCount));
  const float groundRadius = 1.5f * std::sqrt(16.0f / static_cast<float>(groundCount));
  for (std::size_t i = 0; i < count; ++i) {
    Splat s{};
    glm::vec3 p, n, c;
    float r;
    if (i < sphereCount) {
      const float z = 2.0f * u(rng) - 1.0f, phi = 2.0f * pi * u(rng);
      const float rho = std::sqrt(std::max(0.0f, 1.0f - z * z));
      n = {rho * std::cos(phi), rho * std::sin(phi), z};
      p = 0.8f * n + glm::vec3(0.0f, 0.0f, 0.9f);
      c = {0.9f, 0.5f + 0.4f * z, 0.2f};
      r = sphereRadius;
    } else {
      const float x = 4.0f * u(rng) - 2.0f, y = 4.0f * u(rng) - 2.0f;
      const float h = 0.05f * std::sin(3.0f * x) * std::cos(2.0f * y);
      p = {x, y, h};
      n = glm::normalize(glm::vec3(-0.15f * std::cos(3.0f * x) * std::cos(2.0f * y),
                                   0.1f * std::sin(3.0f * x) * std::sin(2.0f * y), 1.0f));
      const bool check =
          (static_cast<int>(std::floor(x * 2.0f)) + static_cast<int>(std::floor(y * 2.0f))) % 2 ==
          0;
      c = check ? glm::vec3(0.3f, 0.6f, 0.3f) : glm::vec3(0.8f, 0.8f, 0.7f);
      r = groundRadius;
    }
    for (int k = 0; k < 3; ++k) {
      s.position[k] = p[k];
      s.normal[k] = n[k];
    }
    s.radius = r;
    s.color[0] = toByte(c.r);
    s.color[1] = toByte(c.g);
    s.color[2] = toByte(c.b);
    s.color[3] = 255;
    const std::size_t cell =
        (p.x >= 0.0f ? 1u : 0u) + (p.y >= 0.0f ? 2u : 0u) + (p.z >= 0.5f ? 4u : 0u);
    scene.ownedCells[cell].push_back(s);
  }
  scene.boundsMin = {-2.0f, -2.0f, -0.1f};
  scene.boundsMax = {2.0f, 2.0f, 1.7f};
  return scene;
}

int run(int argc, char** argv) {
  CLI::App app{"Pointillist reference renderer: one process, no MPI, OSMesa"};
  std::string datasetDir, out = "reference.png", modeName = "points", profileName = "compat";
  std::string tiles, upName = "z";
  std::size_t generate = 0;
  std::uint32_t width = 1280, height = 720, seed = 1;
  float azimuth = 30.0f, elevation = 20.0f, distance = 1.0f, fov = 45.0f;
  RenderSettings settings;
  bool compare = false;
  app.add_option("--dataset", datasetDir, "dataset directory written by pointillist-preprocess");
  app.add_option("--generate", generate, "render a built-in scene of this many splats instead");
  app.add_option("--seed", seed, "seed of the built-in scene");
  app.add_option("-o,--out", out, "output PNG");
  app.add_option("--width", width, "image width")->check(CLI::Range(1u, 16384u));
  app.add_option("--height", height, "image height")->check(CLI::Range(1u, 16384u));
  app.add_option("--mode", modeName, "points, splats or blended");
  app.add_option("--profile", profileName, "GL profile: compat (fast points) or core");
  app.add_option("--azimuth", azimuth, "camera azimuth in degrees");
  app.add_option("--elevation", elevation, "camera elevation in degrees");
  app.add_option("--distance", distance, "distance factor (1 fits the bounds, < 1 zooms in)");
  app.add_option("--fov", fov, "vertical field of view in degrees");
  app.add_option("--up", upName, "up axis: z or y");
  app.add_option("--point-size", settings.pointSize,
                 "points: constant size in pixels (0: from radius)");
  app.add_option("--size-scale", settings.sizeScale, "multiplies splat radii");
  app.add_option("--tiles", tiles, "render as CxR tiles and blit them together, e.g. 4x3");
  app.add_flag("--compare", compare, "with --tiles: also render the full frame and compare");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  }
  if (datasetDir.empty() == (generate == 0)) {
    throw UsageError("give exactly one of --dataset DIR or --generate N");
  }
  if (upName != "z" && upName != "y") throw UsageError("--up must be z or y");
  settings.mode = parseSplatMode(modeName);
  settings.clearColor = {0.08f, 0.08f, 0.1f, 1.0f};
  std::uint32_t columns = 1, rows = 1;
  if (!tiles.empty() && std::sscanf(tiles.c_str(), "%ux%u", &columns, &rows) != 2) {
    throw UsageError("--tiles must look like 4x3");
  }
  if (columns == 0 || rows == 0 || columns > width || rows > height) {
    throw UsageError("--tiles: bad tile grid " + tiles);
  }

  Scene scene;
  if (!datasetDir.empty()) {
    scene.dataset = Dataset::open(datasetDir, DatasetParts::Points);
    const DatasetManifest& m = scene.dataset->manifest();
    scene.boundsMin = {m.boundsMin[0], m.boundsMin[1], m.boundsMin[2]};
    scene.boundsMax = {m.boundsMax[0], m.boundsMax[1], m.boundsMax[2]};
  } else {
    scene = builtinScene(generate, seed);
  }

  OffscreenContext context(1, 1, parseProfile(profileName));
  SplatRenderer renderer(context);
  std::vector<DrawRange> ranges;
  if (scene.dataset) {
    // Like a render process: one cached cell per top-level cell; drawn are the
    // original points (the finest level), not the level-splats.
    const auto table = scene.dataset->topLevelCells();
    for (std::uint32_t k = 0; k < table.size(); ++k) {
      renderer.uploadCell(k, scene.dataset->packet(k));
      ranges.push_back({k, 0, table[k].pointCount});
    }
  } else {
    for (std::uint32_t k = 0; k < scene.ownedCells.size(); ++k) {
      renderer.uploadCell(k, scene.ownedCells[k]);
      ranges.push_back({k, 0, static_cast<std::uint32_t>(scene.ownedCells[k].size())});
    }
  }

  const glm::vec3 up = upName == "y" ? glm::vec3(0, 1, 0) : glm::vec3(0, 0, 1);
  const Camera camera = cameraForBounds(scene.boundsMin, scene.boundsMax, width, height, azimuth,
                                        elevation, distance, fov, up);
  std::fprintf(stderr, "%s, %s; %zu cells, %llu bytes uploaded\n", context.versionString().c_str(),
               context.rendererString().c_str(), renderer.cellCount(),
               static_cast<unsigned long long>(renderer.uploadedBytes()));

  Image frame(width, height);
  RenderStats total;
  for (std::uint32_t i = 0; i < columns; ++i) {
    for (std::uint32_t j = 0; j < rows; ++j) {
      const std::uint32_t x0 = width * i / columns, x1 = width * (i + 1) / columns;
      const std::uint32_t y0 = height * j / rows, y1 = height * (j + 1) / rows;
      const TileRect rect = makeTileRect(x0, y0, x1 - x0, y1 - y0);
      const RenderStats stats = renderer.render(camera, rect, ranges, settings);
      total.splats += stats.splats;
      total.seconds += stats.seconds;
      blit(context.pixels(), rect.width(), rect.height(), frame, x0, y0);
    }
  }
  std::printf(
      "rendered %llu splats in %ux%u tile(s) of a %ux%u frame (%s, %s): %.1f ms, %.2f M splats/s\n",
      static_cast<unsigned long long>(total.splats), columns, rows, width, height,
      splatModeName(settings.mode), profileName.c_str(), total.seconds * 1e3,
      static_cast<double>(total.splats) / total.seconds * 1e-6);
  writePng(frame, out);
  std::printf("wrote %s\n", out.c_str());

  if (compare && columns * rows > 1) {
    renderer.render(camera, fullFrameRect(camera), ranges, settings);
    const ImageDiff diff = compareImages(context.image(), frame);
    std::printf("tiled vs full frame: %llu differing pixels, max channel difference %d\n",
                static_cast<unsigned long long>(diff.differingPixels), diff.maxChannelDifference);
    if (diff.differingPixels != 0) return 1;
  }
  return 0;
}

}  // namespace
}  // namespace pointillist::render

int main(int argc, char** argv) {
  try {
    return pointillist::render::run(argc, argv);
  } catch (const pointillist::Error& e) {
    std::fprintf(stderr, "pointillist-reference: %s: %s\n", e.kind(), e.what());
    return 2;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "pointillist-reference: %s\n", e.what());
    return 2;
  }
}
