#include "simulator/calibration.hpp"

#include <algorithm>
#include <array>
#include <cmath>
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

// Least squares of seconds on the columns in `use` (0: a constant, 1: pixels,
// 2: splats) by the normal equations, columns scaled to their mean first so
// the system stays well conditioned. nullopt when it is singular.
std::optional<std::array<double, 3>> leastSquares(std::span<const PacketSample> samples,
                                                  const std::array<bool, 3>& use) {
  const auto column = [](const PacketSample& s, std::size_t c) {
    return c == 0 ? 1.0 : c == 1 ? s.pixels : s.splats;
  };
  std::array<std::size_t, 3> cols{};
  std::size_t n = 0;
  for (std::size_t c = 0; c < 3; ++c)
    if (use[c]) cols[n++] = c;
  std::array<double, 3> scale{1.0, 1.0, 1.0};
  for (std::size_t i = 0; i < n; ++i) {
    double sum = 0.0;
    for (const PacketSample& s : samples) sum += std::abs(column(s, cols[i]));
    scale[i] = sum > 0.0 ? sum / static_cast<double>(samples.size()) : 1.0;
  }
  std::array<std::array<double, 4>, 3> m{};
  for (const PacketSample& s : samples) {
    std::array<double, 3> x{};
    for (std::size_t i = 0; i < n; ++i) x[i] = column(s, cols[i]) / scale[i];
    for (std::size_t i = 0; i < n; ++i) {
      for (std::size_t j = 0; j < n; ++j) m[i][j] += x[i] * x[j];
      m[i][3] += x[i] * s.seconds;
    }
  }
  for (std::size_t c = 0; c < n; ++c) {  // Gauss-Jordan with partial pivoting
    std::size_t pivot = c;
    for (std::size_t r = c + 1; r < n; ++r)
      if (std::abs(m[r][c]) > std::abs(m[pivot][c])) pivot = r;
    if (!(std::abs(m[pivot][c]) > 1e-12 * static_cast<double>(samples.size()))) return std::nullopt;
    std::swap(m[c], m[pivot]);
    for (std::size_t r = 0; r < n; ++r) {
      if (r == c) continue;
      const double f = m[r][c] / m[c][c];
      for (std::size_t k = c; k < 4; ++k) m[r][k] -= f * m[c][k];
    }
  }
  std::array<double, 3> out{};
  for (std::size_t i = 0; i < n; ++i) out[cols[i]] = m[i][3] / m[i][i] / scale[i];
  return out;
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

// The packets a run's render processes drew (tiles.csv; none without one).
// Tiles answered without a render (empty) have no render time.
std::vector<PacketSample> readPackets(const fs::path& dir) {
  std::vector<PacketSample> samples;
  if (!fs::exists(dir / "tiles.csv")) return samples;
  const CsvFile tiles(dir / "tiles.csv");
  for (std::size_t i = 0; i < tiles.rows(); ++i) {
    PacketSample s;
    s.seconds = tiles.number(i, "render_seconds");
    s.splats = tiles.number(i, "splats");
    s.pixels = tiles.number(i, "pixels");
    if (s.seconds > 0.0) samples.push_back(s);
  }
  return samples;
}

}  // namespace

PacketTimeFit fitPacketTimes(std::span<const PacketSample> samples) {
  double meanSeconds = 0.0;
  bool anySplats = false;
  for (const PacketSample& s : samples) {
    meanSeconds += s.seconds;
    anySplats = anySplats || s.splats > 0.0;
  }
  if (!anySplats) throw InputError("no packet drew a splat, so T_s cannot be fitted");
  meanSeconds /= static_cast<double>(samples.size());
  double total = 0.0;
  for (const PacketSample& s : samples)
    total += (s.seconds - meanSeconds) * (s.seconds - meanSeconds);
  // Every model with T_s; of those whose coefficients are all >= 0, the
  // one that leaves the least squared error.
  std::optional<PacketTimeFit> best;
  double bestError = 0.0;
  for (const std::array<bool, 3> use :
       {std::array<bool, 3>{true, true, true}, std::array<bool, 3>{true, false, true},
        std::array<bool, 3>{false, true, true}, std::array<bool, 3>{false, false, true}}) {
    const auto c = leastSquares(samples, use);
    if (!c || (*c)[0] < 0.0 || (*c)[1] < 0.0 || !((*c)[2] > 0.0)) continue;
    double error = 0.0;
    for (const PacketSample& s : samples) {
      const double e = s.seconds - ((*c)[0] + (*c)[1] * s.pixels + (*c)[2] * s.splats);
      error += e * e;
    }
    if (best && error >= bestError) continue;
    best = PacketTimeFit{(*c)[0], (*c)[1], (*c)[2], samples.size(),
                         total > 0.0 ? 1.0 - error / total : 1.0};
    bestError = error;
  }
  if (!best)
    throw InputError("the packets' times do not grow with their splats: T_s cannot be fitted");
  return *best;
}

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
  std::vector<PacketSample> packets;
  for (const fs::path& dir : runDirs) {
    calibration.runs.push_back(readRun(dir));
    splats += calibration.runs.back().splats;
    busy += calibration.runs.back().busySeconds;
    tiles += calibration.runs.back().tiles;
    const auto drawn = readPackets(dir);
    packets.insert(packets.end(), drawn.begin(), drawn.end());
  }
  if (splats == 0 || !(busy > 0.0)) {
    throw InputError(directory.string() + ": the runs drew no splats, so T_s cannot be measured");
  }
  if (!packets.empty()) {
    try {
      calibration.fit = fitPacketTimes(packets);
    } catch (const InputError& e) {
      throw InputError(directory.string() + ": tiles.csv: " + e.what());
    }
    calibration.secondsPerSplat = calibration.fit->secondsPerSplat;
    return calibration;
  }
  // The per-packet overhead is modelled apart; take it out, but never more
  // than half of the busy time (the overhead is itself a guess).
  const double drawing =
      std::max(busy - static_cast<double>(tiles) * packetOverheadSeconds, 0.5 * busy);
  calibration.secondsPerSplat = drawing / static_cast<double>(splats);
  return calibration;
}

}  // namespace pointillist::simulator
