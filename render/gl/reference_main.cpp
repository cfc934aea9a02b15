// pointillist-reference: renders the frames of a run in one process, with the
// same camera path, traversal (level of detail, culling) and shaders as the
// distributed job. It is the oracle the job's composed frames are checked
// against (--compare), and the single-process speed baseline.
#include <CLI/CLI.hpp>

#include "common/tool_entry.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <thread>

#include "common/errors.hpp"
#include "common/image.hpp"
#include "common/run_settings.hpp"
#include "common/view_options.hpp"
#include "render/gl/reference_renderer.hpp"

namespace pointillist::render {
namespace {

struct ReferenceOptions {
  std::string datasetPath;
  ViewOptions view;
  std::string outDir;
  std::string compareDir;
  std::uint64_t maxDifferingPixels = 0;
  // A compared frame must show something: two blank images would match.
  double minLitFraction = 0.0;
  std::uint64_t minSplats = 0;
  std::string profile = "compat";
  unsigned threads = std::max(1u, std::thread::hardware_concurrency());
  bool quality = false;
};

// Share of pixels that are not the background colour.
double litFraction(const Image& image) {
  const Rgba8 background{0, 0, 0, 255};
  std::uint64_t lit = 0;
  for (std::uint32_t y = 0; y < image.height(); ++y) {
    for (std::uint32_t x = 0; x < image.width(); ++x) {
      const Rgba8 pixel = image.at(x, y);
      lit += pixel[0] != background[0] || pixel[1] != background[1] || pixel[2] != background[2];
    }
  }
  const double pixels = static_cast<double>(image.width()) * image.height();
  return pixels > 0.0 ? static_cast<double>(lit) / pixels : 0.0;
}

int run(int argc, char** argv) {
  CLI::App app{"Pointillist reference renderer: whole frames in one process, no MPI"};
  ReferenceOptions options;
  app.add_option("--dataset", options.datasetPath, "Dataset directory")->required();
  addViewOptions(app, options.view);
  app.add_option("--out", options.outDir, "Directory for PNG frames");
  app.add_option("--compare", options.compareDir,
                 "Directory of frames (frame_NNNNN.png) to compare with the reference");
  app.add_option("--max-differing-pixels", options.maxDifferingPixels,
                 "Pixels a compared frame may differ in");
  app.add_option("--min-lit-fraction", options.minLitFraction,
                 "With --compare: every frame (ours and theirs) must have at least this share "
                 "of pixels off the background");
  app.add_option("--min-splats", options.minSplats,
                 "With --compare: every frame must draw at least this many splats");
  app.add_option("--gl-profile", options.profile, "OSMesa context profile: compat or core");
  app.add_option("--threads", options.threads,
                 "Threads drawing each frame with the cpu renderer (default: the cores)")
      ->check(CLI::Range(1, 256));
  app.add_flag("--quality", options.quality,
               "Also draw each frame at full detail (every point, no level-splats) and print "
               "the PSNR and the share of identical covered pixels against it");
  app.name("pointillist-reference");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& error) {
    return app.exit(error);
  }

  const Dataset dataset = Dataset::open(options.datasetPath, DatasetParts::All);
  const auto cameras = viewCameras(options.view, datasetBounds(dataset.manifest()));
  traverse::TraversalSettings traversal = traverse::traversalSettings(options.view);
  if (parseRenderMode(options.view.mode) == v1::RENDER_MODE_INSTANCED)
    traversal.instanced = traverse::InstancedCells::load(dataset);
  if (parseRenderMode(options.view.mode) == v1::RENDER_MODE_STATISTICAL)
    traversal.statistical =
        std::make_shared<traverse::StatisticalCutMemo>(StatisticalTrees::load(dataset));
  RenderSettings settings;
  settings.mode = splatModeFromProto(parseRenderMode(options.view.mode));
  settings.lighting = !options.view.unlit;
  checkViewEdl(options.view);
  settings.edl = {options.view.edl, options.view.edlStrength, options.view.edlRadius};
  const v1::Renderer kind =
      resolveRenderer(parseRenderer(options.view.renderer), parseRenderMode(options.view.mode));
  if (!options.outDir.empty()) std::filesystem::create_directories(options.outDir);

  ReferenceRenderer renderer(dataset, kind, parseProfile(options.profile), options.threads);
  std::printf("reference: drawing with %s\n", renderer.renderer().describe().c_str());
  traverse::TraversalSettings fullDetail = traversal;
  fullDetail.lodPixels = 0.0f;  // level-splats never project to 0 px: always the leaves' points
  double psnrSum = 0.0;
  std::uint64_t covered = 0, identical = 0;
  std::size_t identicalFrames = 0;
  double renderSeconds = 0.0;
  double traverseSeconds = 0.0;
  std::uint64_t splats = 0;
  int mismatches = 0;
  for (std::size_t index = 0; index < cameras.size(); ++index) {
    ReferenceFrame frame = renderer.render(cameras[index], traversal, settings);
    renderSeconds += frame.renderSeconds;
    traverseSeconds += frame.traverseSeconds;
    splats += frame.splats;
    char name[64];
    std::snprintf(name, sizeof name, "frame_%05zu.png", index);
    if (!options.outDir.empty()) {
      writePng(frame.image, std::filesystem::path(options.outDir) / name, true);
    }
    std::printf("reference frame %4zu: %6.2f M splats, traverse %6.1f ms, render %7.1f ms", index,
                static_cast<double>(frame.splats) / 1e6, frame.traverseSeconds * 1e3,
                frame.renderSeconds * 1e3);
    if (options.quality) {
      const ReferenceFrame truth = renderer.render(cameras[index], fullDetail, settings);
      const ImageQuality quality = measureQuality(frame.image, truth.image);
      if (std::isinf(quality.psnr)) {
        ++identicalFrames;
      } else {
        psnrSum += quality.psnr;
      }
      covered += quality.covered;
      identical += quality.identical;
      std::printf(
          ", full detail %.2f M splats: PSNR %.1f dB, %.1f%% of %.2f M covered pixels "
          "identical",
          static_cast<double>(truth.splats) / 1e6, quality.psnr, quality.identicalShare() * 100.0,
          static_cast<double>(quality.covered) / 1e6);
    }
    if (!options.compareDir.empty()) {
      const Image other = readPng(std::filesystem::path(options.compareDir) / name);
      // The job writes RGB PNGs; compare what both files hold.
      const Image expected = decodePng(encodePng(frame.image, true));
      const ImageDiff diff = compareImages(expected, other);
      std::printf(", %llu pixels differ (max channel difference %d)",
                  static_cast<unsigned long long>(diff.differingPixels), diff.maxChannelDifference);
      if (diff.differingPixels > options.maxDifferingPixels) {
        ++mismatches;
        std::printf(" MISMATCH, first at (%u, %u)", diff.firstX, diff.firstY);
      }
      const double lit = std::min(litFraction(expected), litFraction(other));
      std::printf(", %.1f%% lit", lit * 100.0);
      if (lit < options.minLitFraction || frame.splats < options.minSplats) {
        ++mismatches;
        std::printf(" TOO EMPTY (need %.1f%% lit and %llu splats)", options.minLitFraction * 100.0,
                    static_cast<unsigned long long>(options.minSplats));
      }
    }
    std::printf("\n");
  }
  const double seconds = renderSeconds + traverseSeconds;
  std::printf(
      "reference: %zu frames, %.2f frames/s, %.2f M splats/s rendering (%.2f M splats per frame)\n",
      cameras.size(), seconds > 0.0 ? static_cast<double>(cameras.size()) / seconds : 0.0,
      renderSeconds > 0.0 ? static_cast<double>(splats) / 1e6 / renderSeconds : 0.0,
      cameras.empty() ? 0.0
                      : static_cast<double>(splats) / 1e6 / static_cast<double>(cameras.size()));
  if (options.quality && !cameras.empty()) {
    // Mean PSNR over the frames that differ at all; identical ones are counted apart.
    const std::size_t differing = cameras.size() - identicalFrames;
    std::printf(
        "quality: mean PSNR %.1f dB over %zu frame(s) differing from full detail (%zu "
        "identical), %.2f%% of covered pixels identical\n",
        differing > 0 ? psnrSum / static_cast<double>(differing) : 0.0, differing, identicalFrames,
        covered > 0 ? 100.0 * static_cast<double>(identical) / static_cast<double>(covered)
                    : 100.0);
  }
  if (mismatches > 0) {
    std::fprintf(stderr,
                 "pointillist-reference: %d frame(s) differ from %s by more than %llu pixels or "
                 "show too little\n",
                 mismatches, options.compareDir.c_str(),
                 static_cast<unsigned long long>(options.maxDifferingPixels));
    return 1;
  }
  if (!options.compareDir.empty())
    std::printf("reference: every frame matches %s\n", options.compareDir.c_str());
  return 0;
}

}  // namespace
}  // namespace pointillist::render

int main(int argc, char** argv) {
  return pointillist::runToolMain("pointillist-reference",
                                  [&] { return pointillist::render::run(argc, argv); });
}
