#include "simulator/calibration.hpp"

#include <algorithm>
#include <fstream>
#include <map>
#include <sstream>

#include "common/errors.hpp"

namespace pointillist::simulator {
namespace {

namespace fs = std::filesystem;

std::vector<std::string> splitCsvLine(const std::string& line) {
  std::vector<std::string> fields;
  std::string field;
  std::istringstream in(line);
  while (std::getline(in, field, ',')) fields.push_back(field);
  if (!line.empty() && line.back() == ',') fields.emplace_back();
  return fields;
}

// A CSV file with a header line, read as columns by name.
class CsvFile {
 public:
  explicit CsvFile(const fs::path& file) : file_(file) {
    std::ifstream in(file);
    if (!in) throw InputError(file.string() + ": cannot read");
    std::string line;
    if (!std::getline(in, line)) throw InputError(file.string() + ": empty, no header line");
    const auto names = splitCsvLine(line);
    for (std::size_t i = 0; i < names.size(); ++i) columns_[names[i]] = i;
    while (std::getline(in, line)) {
      if (!line.empty()) rows_.push_back(splitCsvLine(line));
    }
  }

  std::size_t rows() const { return rows_.size(); }

  double number(std::size_t row, const std::string& column) const {
    const auto found = columns_.find(column);
    if (found == columns_.end()) {
      throw InputError(file_.string() + ": no column '" + column + "'");
    }
    const auto& fields = rows_.at(row);
    if (found->second >= fields.size() || fields[found->second].empty()) return 0.0;
    try {
      return std::stod(fields[found->second]);
    } catch (const std::exception&) {
      throw InputError(file_.string() + ": line " + std::to_string(row + 2) + ", column '" +
                       column + "': '" + fields[found->second] + "' is not a number");
    }
  }

 private:
  fs::path file_;
  std::map<std::string, std::size_t> columns_;
  std::vector<std::vector<std::string>> rows_;
};

std::string layoutOf(const fs::path& statsJson) {
  std::ifstream in(statsJson);
  std::string line;
  const std::string key = "\"layout\": \"";
  while (std::getline(in, line)) {
    const auto at = line.find(key);
    if (at == std::string::npos) continue;
    const auto start = at + key.size();
    return line.substr(start, line.find('"', start) - start);
  }
  return {};
}

MeasuredRun readRun(const fs::path& dir) {
  MeasuredRun run;
  run.name = dir.filename().string();
  const CsvFile perRender(dir / "per_frame_render.csv");
  for (std::size_t i = 0; i < perRender.rows(); ++i) {
    run.splats += static_cast<std::uint64_t>(perRender.number(i, "splats"));
    run.busySeconds += perRender.number(i, "busy_seconds");
  }
  if (fs::exists(dir / "frames.csv")) {
    const CsvFile frames(dir / "frames.csv");
    for (std::size_t i = 0; i < frames.rows(); ++i) {
      run.tiles += static_cast<std::uint64_t>(frames.number(i, "tiles"));
    }
  }
  if (fs::exists(dir / "figures.csv")) {
    const CsvFile figures(dir / "figures.csv");
    if (figures.rows() > 0) {
      run.framesPerSecondSteady = figures.number(0, "frames_per_second_steady");
      run.imbalanceBusy = figures.number(0, "imbalance_busy");
    }
  }
  if (fs::exists(dir / "stats.json")) run.layout = layoutOf(dir / "stats.json");
  return run;
}

}  // namespace

Calibration calibrateFromRuns(const fs::path& directory, double packetOverheadSeconds) {
  if (!fs::is_directory(directory)) {
    throw InputError(directory.string() +
                     ": not a directory (give a run directory of "
                     "deploy/bench-loadbalance.sh)");
  }
  std::vector<fs::path> runDirs;
  if (fs::exists(directory / "per_frame_render.csv")) {
    runDirs.push_back(directory);
  } else {
    for (const auto& entry : fs::directory_iterator(directory)) {
      if (entry.is_directory() && fs::exists(entry.path() / "per_frame_render.csv")) {
        runDirs.push_back(entry.path());
      }
    }
    std::sort(runDirs.begin(), runDirs.end());
  }
  if (runDirs.empty()) {
    throw InputError(directory.string() +
                     ": no per_frame_render.csv here or in a subdirectory (is it a "
                     "deploy/bench-loadbalance.sh output directory?)");
  }
  Calibration calibration;
  std::uint64_t splats = 0, tiles = 0;
  double busy = 0.0;
  for (const fs::path& dir : runDirs) {
    calibration.runs.push_back(readRun(dir));
    splats += calibration.runs.back().splats;
    busy += calibration.runs.back().busySeconds;
    tiles += calibration.runs.back().tiles;
  }
  if (splats == 0 || !(busy > 0.0)) {
    throw InputError(directory.string() + ": the runs drew no splats, so T_s cannot be measured");
  }
  // The per-packet overhead is modelled apart; take it out, but never more
  // than half of the busy time (the overhead is itself a guess).
  const double drawing =
      std::max(busy - static_cast<double>(tiles) * packetOverheadSeconds, 0.5 * busy);
  calibration.secondsPerSplat = drawing / static_cast<double>(splats);
  return calibration;
}

}  // namespace pointillist::simulator
