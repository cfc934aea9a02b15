// pointillist-statistical-table: seed 004's Table 1 measured on llvmpipe with
// the statistical program -- the fewest samples whose points
// (kStatisticalPointPixels = 2 pixels wide) cover every pixel centre inside
// the screen ellipse of a node's gamma ellipsoid with semi-axes (a, b) pixels,
// a >= b in 1..--size (render/gl/statistical_coverage.hpp). For each (a, b):
//   quasi   the Sobol sequence (the renderer's buffer): the worst over the
//           sub-pixel offsets kCoverageOffsets of the ellipse's centre;
//   pseudo  std::mt19937_64 samples with --seeds seeds: per seed the worst
//           over the offsets, then the mean over seeds ("mean") and the value
//           that covers for 95 % of the seeds ("p95", the ceil(0.95 k)-th
//           smallest).
// Prints the markdown table and the C++ initializer of
// common/statistical_point_table.cpp: the quasi column made monotone in both
// semi-axes (each entry the largest measured at or below it). With --speed N
// it also times frames of N random nodes (generated points per second).
// Not a test.
#include <CLI/CLI.hpp>

#include "common/tool_entry.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>
#include <string>
#include <vector>

#include "common/camera.hpp"
#include "common/statistical_point_table.hpp"
#include "common/statistical_samples.hpp"
#include "render/gl/offscreen_context.hpp"
#include "render/gl/splat_renderer.hpp"
#include "render/gl/statistical_coverage.hpp"

namespace pointillist::render {
namespace {

std::uint32_t worstOverOffsets(EllipseCoverage& coverage, float a, float b, std::uint32_t limit) {
  std::uint32_t worst = 0;
  for (const auto& offset : kCoverageOffsets) {
    worst = std::max(worst, coverage.fewest(a, b, offset[0], offset[1], limit));
  }
  return worst;
}

// A random orthonormal frame (columns of a QR of a Gaussian matrix, roughly).

void timeFrames(SplatRenderer& renderer, std::uint32_t nodes, std::uint32_t width,
                std::uint32_t height, float sigmaPixels) {
  const Camera camera =
      makeCamera({0, 0, 5}, {0, 0, 0}, {0, 1, 0}, 45.0f, 1.0f, 10.0f, width, height);
  const float unit = 1.0f / pixelsPerUnit(camera, 5.0f);
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f), u01(0.0f, 1.0f);
  std::vector<StatisticalNode> list(nodes);
  for (StatisticalNode& node : list) {
    node.mean[0] = 1.8f * u(rng);
    node.mean[1] = 1.0f * u(rng);
    node.mean[2] = u(rng);
    randomFrame(rng, node.axes);
    randomFrame(rng, node.normalFrame);
    randomFrame(rng, node.colorAxes);
    const float s = sigmaPixels * unit * (0.5f + u01(rng));
    node.sigma[0] = s;
    node.sigma[1] = s * (0.3f + 0.7f * u01(rng));
    node.sigma[2] = 0.1f * node.sigma[1];
    node.sigmaNormal[0] = 0.3f * u01(rng);
    node.sigmaNormal[1] = 0.5f * node.sigmaNormal[0];
    for (int i = 0; i < 3; ++i) {
      node.color[i] = 255.0f * u01(rng);
      node.sigmaColor[i] = 10.0f * u01(rng);
    }
  }
  RenderSettings settings;
  settings.mode = SplatMode::Statistical;
  renderer.renderNodes(camera, fullFrameRect(camera), list, settings);  // warm-up
  std::vector<double> seconds;
  RenderStats stats;
  for (int f = 0; f < 5; ++f) {
    stats = renderer.renderNodes(camera, fullFrameRect(camera), list, settings);
    seconds.push_back(stats.seconds);
  }
  std::sort(seconds.begin(), seconds.end());
  const double median = seconds[seconds.size() / 2];
  std::printf(
      "\n# speed: %u nodes (sigma ~%.1f px), %ux%u: %llu points in %u draws, %.2f ms/frame, "
      "%.2f M points/s\n",
      nodes, static_cast<double>(sigmaPixels), width, height,
      static_cast<unsigned long long>(stats.splats), stats.drawCalls, median * 1e3,
      static_cast<double>(stats.splats) / median * 1e-6);
}

int run(int argc, char** argv) {
  CLI::App app{"Seed 004 Table 1 on llvmpipe: samples that cover a node's screen ellipse"};
  std::uint32_t size = kStatisticalTableSize;
  std::uint32_t seeds = 20;
  std::uint32_t limit = kStatisticalMaxSamples;
  std::uint32_t speedNodes = 0;
  float speedSigma = 1.0f;
  app.add_option("--size", size, "largest semi-axis in pixels")->check(CLI::Range(1, 64));
  app.add_option("--seeds", seeds, "pseudo-random seeds (0: no pseudo column)");
  app.add_option("--limit", limit, "most samples tried")->check(CLI::Range(1u, 1u << 20));
  app.add_option("--speed", speedNodes, "also time frames of this many random nodes");
  app.add_option("--speed-sigma", speedSigma, "their sigma_1 in pixels (about)");
  app.name("pointillist-statistical-table");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  }

  OffscreenContext context(1, 1, GlProfile::Compatibility);
  SplatRenderer renderer(context);
  std::printf("# %s; points %.0f px wide, gamma %.1f\n", renderer.describe().c_str(),
              static_cast<double>(kStatisticalPointPixels), static_cast<double>(kStatisticalGamma));
  if (speedNodes > 0) {
    timeFrames(renderer, speedNodes, 1280, 720, speedSigma);
    return 0;
  }
  EllipseCoverage coverage(renderer, size);

  struct Row {
    std::uint32_t a, b, pixels, quasi, pseudoP95;
    double pseudoMean;
  };
  std::vector<Row> rows;
  const std::vector<GaussianSample> sobol = gaussianSamples(limit);
  for (std::uint32_t a = 1; a <= size; ++a) {
    for (std::uint32_t b = 1; b <= a; ++b) {
      const auto fa = static_cast<float>(a), fb = static_cast<float>(b);
      Row row{a, b, coverage.insidePixels(fa, fb, 0.0f, 0.0f), 0, 0, 0.0};
      renderer.setStatisticalSamples(sobol);
      row.quasi = worstOverOffsets(coverage, fa, fb, limit);
      std::vector<std::uint32_t> pseudo;
      for (std::uint32_t seed = 1; seed <= seeds; ++seed) {
        renderer.setStatisticalSamples(gaussianSamples(limit, SampleSequence::Pseudo, seed));
        pseudo.push_back(worstOverOffsets(coverage, fa, fb, limit));
      }
      if (!pseudo.empty()) {
        std::sort(pseudo.begin(), pseudo.end());
        double sum = 0.0;
        for (std::uint32_t n : pseudo) sum += n;
        row.pseudoMean = sum / static_cast<double>(pseudo.size());
        const auto rank =
            static_cast<std::size_t>(std::ceil(0.95 * static_cast<double>(pseudo.size())));
        row.pseudoP95 = pseudo[std::max<std::size_t>(rank, 1) - 1];
      }
      rows.push_back(row);
      std::fprintf(stderr, "a %u b %u: quasi %u pseudo %.1f\n", a, b, row.quasi, row.pseudoMean);
    }
  }

  std::printf("\n| a | b | pixels | # pseudo (mean of %u) | # pseudo (95 %%) | # quasi |\n", seeds);
  std::printf("|---|---|---|---|---|---|\n");
  for (const Row& row : rows) {
    std::printf("| %u | %u | %u | %.1f | %u | %u |\n", row.a, row.b, row.pixels, row.pseudoMean,
                row.pseudoP95, row.quasi);
  }
  std::printf("\n(values above %u: not covered within --limit)\n", limit);

  // Monotone in both semi-axes; entries with b > a repeat [a][a].
  std::vector<std::vector<std::uint32_t>> table(size, std::vector<std::uint32_t>(size, 0));
  for (const Row& row : rows) table[row.a - 1][row.b - 1] = row.quasi;
  for (std::uint32_t a = 0; a < size; ++a) {
    for (std::uint32_t b = 0; b <= a; ++b) {
      if (a > 0 && b <= a - 1) table[a][b] = std::max(table[a][b], table[a - 1][b]);
      if (b > 0) table[a][b] = std::max(table[a][b], table[a][b - 1]);
    }
    for (std::uint32_t b = a + 1; b < size; ++b) table[a][b] = table[a][a];
  }
  std::printf("\n// kStatisticalQuasiTable (kStatisticalTableSize = %u)\n", size);
  for (std::uint32_t a = 0; a < size; ++a) {
    std::printf("        {");
    for (std::uint32_t b = 0; b < size; ++b) std::printf(b == 0 ? "%u" : ", %u", table[a][b]);
    std::printf("},\n");
  }
  return 0;
}

}  // namespace
}  // namespace pointillist::render

int main(int argc, char** argv) {
  return pointillist::runToolMain("pointillist-statistical-table",
                                  [&] { return pointillist::render::run(argc, argv); });
}
