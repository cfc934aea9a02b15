// pointillist-bench-render: splats per second of each render path (mode x GL
// profile, or the CPU point kernel with N threads) at given frame sizes, for
// random and for clustered splats. One frame = clear + draw all splats from
// cached cells + the result readable; the median of --frames timed frames
// after one warm-up frame is reported. Not a test.
//
// --tiles CxR draws the frame as a job's render processes do: C x R tiles,
// each from its own cell of the splats whose footprint reaches it (binned
// before timing, as the traverse's walk gives each tile its cells), into a
// tile-sized buffer. Splats/s count each splat once, however many tiles draw
// it.
//
// Scenes (both fill the view of a cameraForBounds camera; radii give splats of
// about --pixels pixels across on screen):
//   random:    uniform in a box, stored in random order (no locality);
//   clustered: points on a wavy surface, stored in spatially coherent order
//              (like octree leaves), so consecutive splats land close by.
#include <CLI/CLI.hpp>

#include "common/tool_entry.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <exception>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "common/camera.hpp"
#include "common/errors.hpp"
#include "render/gl/offscreen_context.hpp"
#include "render/gl/tile_renderers.hpp"

namespace pointillist::render {
namespace {

struct Path {
  SplatMode mode;
  v1::Renderer renderer;
  GlProfile profile;
  unsigned threads;  // cpu renderer
  float pointSize;   // points: 0 = from radius
  std::string name;
};

std::vector<Splat> makeScene(bool clustered, std::size_t count, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  std::vector<Splat> splats(count);
  // Side of a grid with `count` cells: clustered points walk it row by row.
  const auto side = static_cast<std::size_t>(std::ceil(std::sqrt(static_cast<double>(count))));
  for (std::size_t i = 0; i < count; ++i) {
    Splat& s = splats[i];
    glm::vec3 p, n(0.0f, 0.0f, 1.0f);
    if (clustered) {
      // Boustrophedon walk over a grid: neighbours in memory are neighbours on screen.
      const std::size_t row = i / side, col = (row % 2 == 0) ? i % side : side - 1 - i % side;
      const float x = (static_cast<float>(col) + 0.5f) / static_cast<float>(side) * 2.0f - 1.0f;
      const float y = (static_cast<float>(row) + 0.5f) / static_cast<float>(side) * 2.0f - 1.0f;
      const float h = 0.15f * std::sin(4.0f * x) * std::cos(3.0f * y);
      p = {x + 0.2f * u(rng) / static_cast<float>(side), y, h};
      n = glm::normalize(glm::vec3(-0.6f * std::cos(4.0f * x) * std::cos(3.0f * y),
                                   0.45f * std::sin(4.0f * x) * std::sin(3.0f * y), 1.0f));
    } else {
      p = {u(rng), u(rng), 0.3f * u(rng)};
      n = glm::normalize(glm::vec3(u(rng), u(rng), u(rng)) + glm::vec3(0.0f, 0.0f, 1e-3f));
    }
    for (int k = 0; k < 3; ++k) {
      s.position[k] = p[k];
      s.normal[k] = n[k];
    }
    s.color[0] = static_cast<std::uint8_t>(rng());
    s.color[1] = static_cast<std::uint8_t>(rng());
    s.color[2] = static_cast<std::uint8_t>(rng());
    s.color[3] = 255;
  }
  return splats;
}

// Sets radii so splats are about `pixels` across at the scene centre's depth.
void setRadii(std::vector<Splat>& splats, const Camera& camera, float pixels) {
  const float depth = viewDepth(camera, cameraTarget(camera));
  const float radius = 0.5f * pixels / pixelsPerUnit(camera, depth);
  for (Splat& s : splats) s.radius = radius;
}

// The frame cut into columns x rows tiles (the display's even grid): each
// tile's rect, and the splats whose footprint (about `pixels` across, a pixel
// more for rounding) reaches it, in their order.
struct BinnedTiles {
  std::vector<TileRect> rects;
  std::vector<std::vector<Splat>> splats;
};

BinnedTiles binByTile(const std::vector<Splat>& splats, const Camera& camera, std::uint32_t columns,
                      std::uint32_t rows, float pixels) {
  const std::uint32_t width = camera.image_width(), height = camera.image_height();
  BinnedTiles out;
  std::vector<std::uint32_t> xs{0}, ys{0};
  for (std::uint32_t c = 1; c <= columns; ++c) xs.push_back(width * c / columns);
  for (std::uint32_t r = 1; r <= rows; ++r) ys.push_back(height * r / rows);
  for (std::uint32_t r = 0; r < rows; ++r) {
    for (std::uint32_t c = 0; c < columns; ++c) {
      TileRect rect;
      rect.set_x(xs[c]);
      rect.set_y(ys[r]);
      rect.set_width(xs[c + 1] - xs[c]);
      rect.set_height(ys[r + 1] - ys[r]);
      out.rects.push_back(rect);
    }
  }
  out.splats.resize(out.rects.size());
  const float reach = 0.5f * pixels + 1.0f;
  const auto column = [&](float x) {
    const float clamped = std::clamp(x, 0.0f, static_cast<float>(width) - 1.0f);
    return static_cast<std::uint32_t>(
        std::upper_bound(xs.begin(), xs.end(), static_cast<std::uint32_t>(clamped)) - xs.begin() -
        1);
  };
  const auto row = [&](float y) {
    const float clamped = std::clamp(y, 0.0f, static_cast<float>(height) - 1.0f);
    return static_cast<std::uint32_t>(
        std::upper_bound(ys.begin(), ys.end(), static_cast<std::uint32_t>(clamped)) - ys.begin() -
        1);
  };
  for (const Splat& s : splats) {
    const glm::vec4 w =
        projectToWindow(camera, glm::vec3(s.position[0], s.position[1], s.position[2]));
    if (w.w <= 0.0f || w.x + reach < 0.0f || w.y + reach < 0.0f ||
        w.x - reach >= static_cast<float>(width) || w.y - reach >= static_cast<float>(height)) {
      continue;
    }
    for (std::uint32_t r = row(w.y - reach); r <= row(w.y + reach); ++r) {
      for (std::uint32_t c = column(w.x - reach); c <= column(w.x + reach); ++c) {
        out.splats[r * columns + c].push_back(s);
      }
    }
  }
  return out;
}

// Process CPU time (all llvmpipe threads): less sensitive than wall time to
// other load on a shared machine.
double cpuSeconds() {
  timespec t{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return static_cast<double>(t.tv_sec) + static_cast<double>(t.tv_nsec) * 1e-9;
}

std::vector<std::string> split(const std::string& text, char sep) {
  std::vector<std::string> parts;
  std::stringstream stream(text);
  for (std::string part; std::getline(stream, part, sep);) {
    if (!part.empty()) parts.push_back(part);
  }
  return parts;
}

Path parsePath(const std::string& name) {
  // <mode>[-const1]/<profile | cpu[-THREADS]>, e.g. points/compat,
  // points-const1/core, splats/compat, points/cpu, points-const1/cpu-2
  const auto slash = name.find('/');
  if (slash == std::string::npos) throw UsageError("path '" + name + "': want mode/profile");
  std::string mode = name.substr(0, slash);
  float pointSize = 0.0f;
  if (mode == "points-const1") {
    mode = "points";
    pointSize = 1.0f;
  }
  const std::string drawer = name.substr(slash + 1);
  if (drawer.rfind("cpu", 0) == 0) {
    unsigned threads = 1;
    if (drawer.size() > 4 && drawer[3] == '-')
      threads = static_cast<unsigned>(std::stoul(drawer.substr(4)));
    return {
        parseSplatMode(mode), v1::RENDERER_CPU, GlProfile::Compatibility, threads, pointSize, name};
  }
  return {parseSplatMode(mode), v1::RENDERER_GL, parseProfile(drawer), 1, pointSize, name};
}

int run(int argc, char** argv) {
  CLI::App app{"Pointillist render benchmark: splats/second per render path"};
  std::size_t count = 2'000'000;
  int frames = 3;
  float pixels = 1.5f;
  std::string sizes = "1280x720,1920x1080";
  std::string paths =
      "points/cpu,points-const1/cpu,points/cpu-2,points/compat,points-const1/compat,points/core,"
      "splats/compat,splats/core,blended/compat";
  std::string scenes = "random,clustered";
  std::string tiles = "1x1,8x4";
  app.add_option("-n,--count", count, "splats per frame");
  app.add_option("--frames", frames, "timed frames per case (median reported)")
      ->check(CLI::Range(1, 100));
  app.add_option("--pixels", pixels, "splat diameter on screen in pixels (sets radii)");
  app.add_option("--sizes", sizes, "frame sizes, comma-separated WxH");
  app.add_option("--paths", paths,
                 "mode/drawer list: {points, points-const1, splats, blended}/{compat, core} for "
                 "OSMesa, {points, points-const1}/cpu[-THREADS] for the CPU point kernel");
  app.add_option("--scenes", scenes, "random,clustered");
  app.add_option("--tiles", tiles,
                 "tile grids CxR, comma-separated: 1x1 draws the whole frame at once, 8x4 as "
                 "32 tiles of their own splats (the job's render processes)")
      ->capture_default_str();
  app.name("pointillist-bench-render");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  }
  const char* threads = std::getenv("LP_NUM_THREADS");
  std::printf("# %zu splats per frame, ~%.1f px across, median of %d frames; LP_NUM_THREADS=%s\n",
              count, static_cast<double>(pixels), frames,
              threads != nullptr ? threads : "(default: all cores)");
  std::printf("%-20s %-10s %-10s %-6s %10s %12s %14s\n", "path", "size", "scene", "tiles",
              "ms/frame", "Msplats/s", "Msplats/cpu-s");
  std::vector<std::pair<std::uint32_t, std::uint32_t>> grids;
  for (const std::string& grid : split(tiles, ',')) {
    std::uint32_t c = 0, r = 0;
    if (std::sscanf(grid.c_str(), "%ux%u", &c, &r) != 2 || c == 0 || r == 0) {
      throw UsageError("bad tile grid " + grid + " (want CxR, e.g. 8x4)");
    }
    grids.emplace_back(c, r);
  }

  for (const std::string& pathName : split(paths, ',')) {
    const Path path = parsePath(pathName);
    const auto drawer = makeTileRenderer(path.renderer, path.profile, path.threads);
    TileRenderer& renderer = *drawer;
    for (const std::string& sceneName : split(scenes, ',')) {
      if (sceneName != "random" && sceneName != "clustered") {
        throw UsageError("unknown scene " + sceneName);
      }
      std::vector<Splat> splats = makeScene(sceneName == "clustered", count, 7);
      for (const std::string& size : split(sizes, ',')) {
        std::uint32_t w = 0, h = 0;
        if (std::sscanf(size.c_str(), "%ux%u", &w, &h) != 2) throw UsageError("bad size " + size);
        const Camera camera =
            cameraForBounds({-1, -1, -0.3f}, {1, 1, 0.3f}, w, h, 90.0f, 90.0f, 0.75f, 45.0f);
        setRadii(splats, camera, pixels);
        RenderSettings settings;
        settings.mode = path.mode;
        settings.pointSize = path.pointSize;
        // The whole frame once, to check each grid's tiles against.
        const DrawRange whole{0, 0, static_cast<std::uint32_t>(splats.size())};
        renderer.uploadCell(0, splats);
        renderer.render(camera, fullFrameRect(camera), {&whole, 1}, settings);
        const std::vector<std::uint8_t> wholeFrame(renderer.pixels().begin(),
                                                   renderer.pixels().end());
        renderer.releaseCell(0);
        for (const auto& [columns, rows] : grids) {
          BinnedTiles binned;
          if (columns * rows == 1) {
            binned.rects = {fullFrameRect(camera)};
            binned.splats = {splats};
          } else {
            binned = binByTile(splats, camera, columns, rows, pixels);
          }
          std::vector<DrawRange> ranges(binned.rects.size());
          for (std::uint32_t t = 0; t < binned.rects.size(); ++t) {
            renderer.uploadCell(t, binned.splats[t]);
            ranges[t] = {t, 0, static_cast<std::uint32_t>(binned.splats[t].size())};
          }
          const auto frame = [&] {
            double seconds = 0.0;
            for (std::size_t t = 0; t < ranges.size(); ++t) {
              seconds +=
                  renderer.render(camera, binned.rects[t], {&ranges[t], 1}, settings).seconds;
            }
            return seconds;
          };
          // Warm-up (and JIT); each tile must equal its rect of the whole frame.
          for (std::size_t t = 0; t < ranges.size(); ++t) {
            const TileRect& rect = binned.rects[t];
            renderer.render(camera, rect, {&ranges[t], 1}, settings);
            const auto tile = renderer.pixels();
            for (std::uint32_t y = 0; y < rect.height(); ++y) {
              const std::size_t row = 4 * rect.width();
              const auto from =
                  wholeFrame.begin() + static_cast<std::ptrdiff_t>(
                                           4 * ((rect.y() + y) * camera.image_width() + rect.x()));
              if (!std::equal(tile.begin() + static_cast<std::ptrdiff_t>(y * row),
                              tile.begin() + static_cast<std::ptrdiff_t>((y + 1) * row), from)) {
                throw Error(path.name + " " + size + " " + sceneName + ": tile " +
                            std::to_string(t) + " of " + std::to_string(columns) + "x" +
                            std::to_string(rows) + " differs from the whole frame at its row " +
                            std::to_string(y));
              }
            }
          }
          std::vector<double> times, cpu;
          for (int f = 0; f < frames; ++f) {
            const double c0 = cpuSeconds();
            times.push_back(frame());
            cpu.push_back(cpuSeconds() - c0);
          }
          for (std::uint32_t t = 0; t < ranges.size(); ++t) renderer.releaseCell(t);
          std::sort(times.begin(), times.end());
          std::sort(cpu.begin(), cpu.end());
          const double median = times[times.size() / 2], medianCpu = cpu[cpu.size() / 2];
          const std::string grid = std::to_string(columns) + "x" + std::to_string(rows);
          std::printf("%-20s %-10s %-10s %-6s %10.1f %12.2f %14.2f\n", path.name.c_str(),
                      size.c_str(), sceneName.c_str(), grid.c_str(), median * 1e3,
                      static_cast<double>(count) / median * 1e-6,
                      static_cast<double>(count) / medianCpu * 1e-6);
          std::fflush(stdout);
        }
      }
    }
  }
  return 0;
}

}  // namespace
}  // namespace pointillist::render

int main(int argc, char** argv) {
  return pointillist::runToolMain("pointillist-bench-render",
                                  [&] { return pointillist::render::run(argc, argv); });
}
