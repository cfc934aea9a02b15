// pointillist-statistical-quality: seed 004's rate-distortion curve of a
// dataset built with --statistical (preprocess/statistical_quality.hpp),
// beside the paper's figure for Lucy (2.52 bits per point at 71 dB).
#include <CLI/CLI.hpp>
#include <cstdio>
#include <exception>
#include <fstream>
#include <mutex>
#include <sstream>
#include <string>
#include <vector>

#include "common/dataset.hpp"
#include "common/errors.hpp"
#include "common/tool_entry.hpp"
#include "preprocess/parallel.hpp"
#include "preprocess/statistical_quality.hpp"

namespace pp = pointillist::preprocess;
using pointillist::InputError;

namespace {

constexpr const char* kTool = "pointillist-statistical-quality";

// The hierarchy options the dataset was built with (manifest extras).
pp::StatisticalOptions buildOptions(const pointillist::DatasetManifest& m, const std::string& dir) {
  pp::StatisticalOptions o;
  const auto get = [&](const char* key) {
    const auto found = m.extra.find(key);
    if (found == m.extra.end())
      throw InputError(dir + "/manifest.txt: no " + key + " (built by an older preprocess?)");
    return found->second;
  };
  o.leafPoints = static_cast<std::uint32_t>(std::stoul(get("statistical_leaf_points")));
  o.minSigmaShare = std::stod(get("statistical_min_sigma_share"));
  o.balanceShare = std::stod(get("statistical_balance_share"));
  std::istringstream eta(get("statistical_eta"));
  eta >> o.eta0 >> o.eta1;
  o.threads = 1;
  return o;
}

int run(const std::string& dir, std::uint64_t maxGenerated, const std::string& csv,
        unsigned threads) {
  const auto dataset = pointillist::Dataset::open(dir, pointillist::DatasetParts::All);
  if (!dataset.hasStatistical())
    throw pointillist::UsageError(dir +
                                  " has no statistical hierarchy; build it with "
                                  "pointillist-preprocess --statistical");
  const pp::StatisticalOptions options = buildOptions(dataset.manifest(), dir);
  const pointillist::ClassTables classes = dataset.readStatisticalClasses();
  const auto table = dataset.topLevelCells();
  std::vector<pointillist::Splat> all;
  all.reserve(dataset.manifest().pointCount);
  std::vector<pp::PcaTree> trees(table.size());
  std::vector<std::vector<pointillist::StatisticalNode>> decoded(table.size());
  std::vector<std::size_t> firstPoint(table.size());
  for (std::uint32_t t = 0; t < table.size(); ++t) {
    const auto packet = dataset.packet(t).subspan(pointillist::pointsStart(table[t]));
    firstPoint[t] = all.size();
    all.insert(all.end(), packet.begin(), packet.end());
  }
  // The hierarchies again, one cell per thread as the preprocess built them.
  std::mutex mutex;
  std::exception_ptr error;
  pp::parallelFor(
      table.size(), threads,
      [&](std::size_t t) {
        try {
          const auto cell = static_cast<std::uint32_t>(t);
          trees[t] = pp::buildPcaTree(
              dataset.packet(cell).subspan(pointillist::pointsStart(table[t])), options);
          auto view = pointillist::decodeStatisticalPacket(
              dataset.packet(dataset.statisticalPacketId(cell)), classes,
              dir + ": top-level cell " + std::to_string(t));
          if (view.nodes.size() != trees[t].nodes.size())
            throw InputError(dir + ": top-level cell " + std::to_string(t) + ": the packet holds " +
                             std::to_string(view.nodes.size()) + " nodes, the rebuilt hierarchy " +
                             std::to_string(trees[t].nodes.size()) + " (other build options?)");
          decoded[t] = std::move(view.nodes);
        } catch (...) {
          std::lock_guard lock(mutex);
          if (!error) error = std::current_exception();
        }
      },
      1);
  if (error) std::rethrow_exception(error);
  std::vector<pp::CellHierarchy> cells(table.size());
  for (std::uint32_t t = 0; t < table.size(); ++t)
    cells[t] = {
        std::span<const pointillist::Splat>(all).subspan(firstPoint[t], table[t].pointCount),
        &trees[t], decoded[t]};
  const auto curve = pp::rateDistortion(all, cells, maxGenerated, threads);
  std::printf("%s: %s, %zu points, %zu top-level cells, leaves of < %u points\n", kTool,
              dir.c_str(), all.size(), table.size(), options.leafPoints);
  std::printf(
      "| depth | cut nodes | nodes to depth | bits/point (position+normal) | bits/point "
      "(18-byte nodes) | generated | Hausdorff PSNR dB | unquantized PSNR dB |\n");
  std::printf("|---|---|---|---|---|---|---|---|\n");
  for (const auto& p : curve)
    std::printf("| %u | %llu | %llu | %.3f | %.3f | %llu | %.2f | %.2f |\n", p.depth,
                static_cast<unsigned long long>(p.cutNodes),
                static_cast<unsigned long long>(p.prefixNodes), p.bitsPerPoint, p.bitsWithColor,
                static_cast<unsigned long long>(p.generated), p.psnr, p.psnrUnquantized);
  std::printf(
      "seed 004, Lucy (14 M points): 2.52 bits per point for position and normal at "
      "about 71 dB\n");
  if (!csv.empty()) {
    std::ofstream out(csv);
    if (!out) throw InputError(csv + ": cannot write");
    out << "depth,cut_nodes,prefix_nodes,bits_per_point,bits_with_color,generated,psnr,"
           "psnr_unquantized\n";
    for (const auto& p : curve)
      out << p.depth << ',' << p.cutNodes << ',' << p.prefixNodes << ',' << p.bitsPerPoint << ','
          << p.bitsWithColor << ',' << p.generated << ',' << p.psnr << ',' << p.psnrUnquantized
          << '\n';
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "Rate-distortion curve of a dataset's statistical hierarchies (seed 004 §10.1): "
      "bits per point against Hausdorff PSNR, cut by cut"};
  std::string dir, csv;
  std::uint64_t maxGenerated = 2'000'000;
  unsigned threads = 0;
  app.add_option("dataset", dir,
                 "Dataset directory built with pointillist-preprocess --statistical")
      ->required();
  app.add_option("--max-generated", maxGenerated,
                 "Generated points measured per depth at most (every k-th node beyond)")
      ->capture_default_str();
  app.add_option("--csv", csv, "Also write the curve as CSV");
  app.add_option("--threads", threads, "Worker threads (0: all cores)");
  CLI11_PARSE(app, argc, argv);
  return pointillist::runToolMain(kTool, [&] { return run(dir, maxGenerated, csv, threads); });
}
