// pointillist-bench-walk: the data-traverse walk (traverseTile) alone, on one
// core, over a dataset's camera path: milliseconds a frame for the whole frame
// and for the frame cut into a grid of tiles, with the cells visited and the
// ranges and splats found. Not a test: the reference prints its walk too, but
// beside drawing that shares the caches and the cores, so figures there swing
// with the machine; here each pass over the path is repeated and the fastest
// is kept. With --working-set it also prints what one render process holding
// every tile would be sent: the first frame and each later one, as the ranges
// the tiles need and as prefixes through them (the floor of a job's bytes).
#include <CLI/CLI.hpp>

#include "common/tool_entry.hpp"

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "common/camera.hpp"
#include "common/cell_ranges.hpp"
#include "common/dataset.hpp"
#include "common/errors.hpp"
#include "common/view_options.hpp"
#include "traverse/core/culling_table.hpp"
#include "traverse/core/octree_traversal.hpp"
#include "traverse/core/packet_planner.hpp"

namespace pointillist::traverse {
namespace {

struct PassFigures {
  double seconds = 0.0;
  std::uint64_t visited = 0;
  std::uint64_t ranges = 0;
  std::uint64_t splats = 0;
  std::uint64_t culledFrustum = 0;
  std::uint64_t culledBackface = 0;
};

// One pass over every camera, each frame walked as columns x rows tiles.
PassFigures walkPath(const CullingTable& table, const std::vector<Camera>& cameras,
                     std::uint32_t columns, std::uint32_t rows, const TraversalSettings& settings) {
  PassFigures pass;
  for (const Camera& camera : cameras) {
    const std::uint32_t width = camera.image_width();
    const std::uint32_t height = camera.image_height();
    for (std::uint32_t column = 0; column < columns; ++column) {
      for (std::uint32_t row = 0; row < rows; ++row) {
        const std::uint32_t x = width * column / columns;
        const std::uint32_t y = height * row / rows;
        const TileRect rect =
            makeTileRect(x, y, width * (column + 1) / columns - x, height * (row + 1) / rows - y);
        const auto start = std::chrono::steady_clock::now();
        const TraversalResult result = traverseTile(table, camera, rect, settings);
        pass.seconds +=
            std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
        pass.visited += result.cellsVisited;
        pass.ranges += result.ranges.size();
        pass.splats += result.splats;
        pass.culledFrustum += result.cellsCulledFrustum;
        pass.culledBackface += result.cellsCulledBackface;
      }
    }
  }
  return pass;
}

// Bytes a render process holding everything its earlier frames drew is sent
// for the first frame and, on average, for each later one: as ranges of
// packets (what the job sends) and as prefixes through them.
struct WorkingSet {
  double needRanges = 0.0;  // a frame, over its tiles
  double cellNeeds = 0.0;   // the cells they lie in (a prefix each)
  double firstRangeMiB = 0.0, steadyRangeMiB = 0.0;
  double firstPrefixMiB = 0.0, steadyPrefixMiB = 0.0;
};

WorkingSet workingSet(const CullingTable& table, const PacketLayers& layers,
                      const std::vector<Camera>& cameras, std::uint32_t columns, std::uint32_t rows,
                      const TraversalSettings& settings, std::uint32_t gapSplats) {
  std::map<std::uint32_t, SpanSet> ranges;
  std::map<std::uint32_t, std::uint32_t> prefixes;
  WorkingSet set;
  constexpr double kMiB = 1048576.0;
  for (std::size_t frame = 0; frame < cameras.size(); ++frame) {
    const Camera& camera = cameras[frame];
    std::uint64_t rangeSplats = 0, prefixSplats = 0;
    for (std::uint32_t column = 0; column < columns; ++column) {
      for (std::uint32_t row = 0; row < rows; ++row) {
        const std::uint32_t x = camera.image_width() * column / columns;
        const std::uint32_t y = camera.image_height() * row / rows;
        const TileRect rect = makeTileRect(x, y, camera.image_width() * (column + 1) / columns - x,
                                           camera.image_height() * (row + 1) / rows - y);
        const TraversalResult result = traverseTile(table, camera, rect, settings);
        const TileWalk walk = walkOf(result);
        const auto needs =
            needRanges(walk, 0, walk.needs.size(), 0, walk.ranges.size(), layers, gapSplats);
        set.needRanges += static_cast<double>(needs.size()) / static_cast<double>(cameras.size());
        for (const CellRange& need : needs) {
          rangeSplats += ranges[need.cell].add(need.first, static_cast<std::uint32_t>(need.end()));
        }
        set.cellNeeds +=
            static_cast<double>(result.needs.size()) / static_cast<double>(cameras.size());
        for (const CellPrefix& need : result.needs) {
          std::uint32_t& held = prefixes[need.cell];
          if (need.splats > held) prefixSplats += need.splats - std::exchange(held, need.splats);
        }
      }
    }
    const double rangeMiB = static_cast<double>(rangeSplats * sizeof(Splat)) / kMiB;
    const double prefixMiB = static_cast<double>(prefixSplats * sizeof(Splat)) / kMiB;
    if (frame == 0) {
      set.firstRangeMiB = rangeMiB;
      set.firstPrefixMiB = prefixMiB;
    } else {
      const auto later = static_cast<double>(cameras.size() - 1);
      set.steadyRangeMiB += rangeMiB / later;
      set.steadyPrefixMiB += prefixMiB / later;
    }
  }
  return set;
}

std::pair<std::uint32_t, std::uint32_t> parseGrid(const std::string& text) {
  const auto x = text.find('x');
  try {
    if (x != std::string::npos) {
      const unsigned long columns = std::stoul(text.substr(0, x));
      const unsigned long rows = std::stoul(text.substr(x + 1));
      if (columns >= 1 && rows >= 1 && columns <= 256 && rows <= 256)
        return {static_cast<std::uint32_t>(columns), static_cast<std::uint32_t>(rows)};
    }
  } catch (const std::exception&) {
  }
  throw UsageError("--tiles '" + text + "' is not COLUMNSxROWS with each from 1 to 256");
}

int run(int argc, char** argv) {
  CLI::App app{"Pointillist walk benchmark: the traverse's octree walk alone, on one core"};
  std::string datasetPath;
  ViewOptions view;
  std::vector<std::string> grids{"1x1", "4x2"};
  unsigned repeat = 5;
  bool noScreenBoxes = false;
  bool printWorkingSet = false;
  std::uint32_t gapSplats = kNeedGapSplatsCopied;
  app.add_option("--dataset", datasetPath, "Dataset directory")->required();
  addViewOptions(app, view);
  app.add_option("--tiles", grids, "Tile grids to walk each frame as, COLUMNSxROWS (repeatable)");
  app.add_option("--repeat", repeat, "Passes over the path per grid; the fastest is reported")
      ->check(CLI::Range(1, 1000));
  app.add_flag("--no-screen-boxes", noScreenBoxes,
               "Walk without projecting the drawn cells' bounds (the traverse projects them for "
               "each packet's screen box)");
  app.add_flag("--working-set", printWorkingSet,
               "Also print the MiB one render process holding every tile would be sent for the "
               "first frame and each later one, as ranges and as prefixes, per grid");
  app.add_option("--need-gap", gapSplats,
                 "With --working-set: drawn ranges this many splats apart or less are needed as "
                 "one (a job's: " +
                     std::to_string(kNeedGapSplatsCopied) + " over links, " +
                     std::to_string(kNeedGapSplatsInPlace) + " read in place)")
      ->capture_default_str();
  app.name("pointillist-bench-walk");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& error) {
    return app.exit(error);
  }

  std::vector<std::pair<std::uint32_t, std::uint32_t>> tileGrids;
  for (const std::string& grid : grids) tileGrids.push_back(parseGrid(grid));
  const Dataset dataset = Dataset::open(datasetPath, DatasetParts::Cells);
  const std::vector<Camera> cameras = viewCameras(view, datasetBounds(dataset.manifest()));
  if (cameras.empty()) throw UsageError("the camera path has no frames");
  for (std::size_t g = 0; g < grids.size(); ++g) {
    if (tileGrids[g].first > cameras[0].image_width() ||
        tileGrids[g].second > cameras[0].image_height())
      throw UsageError("--tiles '" + grids[g] + "' has more tiles across than the " + view.size +
                       " frame has pixels");
  }
  TraversalSettings settings = traversalSettings(view);
  settings.screenBoxes = !noScreenBoxes;  // as the traverse walks
  const v1::RenderMode mode = parseRenderMode(view.mode);
  if (mode == v1::RENDER_MODE_STATISTICAL)
    throw UsageError(
        "--mode statistical has no octree walk (its cut is timed by "
        "pointillist-reference --mode statistical)");
  if (mode == v1::RENDER_MODE_INSTANCED) settings.instanced = InstancedCells::load(dataset);
  const CullingTable table(dataset.cells(), settings.sizeScale);
  std::printf("walk: %s, %zu frames of %s, %zu cells, best of %u passes\n", datasetPath.c_str(),
              cameras.size(), view.size.c_str(), dataset.cells().size(), repeat);
  std::printf("%-7s %10s %12s %12s %10s %12s %10s %10s\n", "tiles", "ms/frame", "ns/visit",
              "visited", "ranges", "splats", "culled fr", "culled bf");
  const auto frames = static_cast<double>(cameras.size());
  for (std::size_t g = 0; g < grids.size(); ++g) {
    const auto [columns, rows] = tileGrids[g];
    const std::string& grid = grids[g];
    PassFigures best;
    for (unsigned pass = 0; pass < repeat; ++pass) {
      const PassFigures figures = walkPath(table, cameras, columns, rows, settings);
      if (pass == 0 || figures.seconds < best.seconds) best = figures;
    }
    const double visited = static_cast<double>(best.visited) / frames;
    std::printf(
        "%-7s %10.3f %12.1f %12.0f %10.0f %12.0f %10.0f %10.0f\n", grid.c_str(),
        best.seconds / frames * 1e3, visited > 0.0 ? best.seconds / frames / visited * 1e9 : 0.0,
        visited, static_cast<double>(best.ranges) / frames,
        static_cast<double>(best.splats) / frames, static_cast<double>(best.culledFrustum) / frames,
        static_cast<double>(best.culledBackface) / frames);
  }
  if (printWorkingSet) {
    const PacketLayers layers(dataset.cells(), dataset.topLevelCells());
    std::printf("\none render process holding every tile, MiB sent (later: mean a frame):\n");
    std::printf("%-7s %10s %14s %14s %10s %10s %14s %14s %10s\n", "tiles", "ranges", "ranges first",
                "ranges later", "share", "prefixes", "prefix first", "prefix later", "share");
    for (std::size_t g = 0; g < grids.size(); ++g) {
      const auto [columns, rows] = tileGrids[g];
      const WorkingSet set = workingSet(table, layers, cameras, columns, rows, settings, gapSplats);
      const auto share = [](double later, double first) {
        return first > 0.0 ? 100.0 * later / first : 0.0;
      };
      std::printf("%-7s %10.0f %14.2f %14.3f %9.2f%% %10.0f %14.2f %14.3f %9.2f%%\n",
                  grids[g].c_str(), set.needRanges, set.firstRangeMiB, set.steadyRangeMiB,
                  share(set.steadyRangeMiB, set.firstRangeMiB), set.cellNeeds, set.firstPrefixMiB,
                  set.steadyPrefixMiB, share(set.steadyPrefixMiB, set.firstPrefixMiB));
    }
  }
  return 0;
}

}  // namespace
}  // namespace pointillist::traverse

int main(int argc, char** argv) {
  return pointillist::runToolMain("pointillist-bench-walk",
                                  [&] { return pointillist::traverse::run(argc, argv); });
}
