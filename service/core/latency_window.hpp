#pragma once
// The last N latencies of one kind, for the median and 95th percentile the
// statistics request reports (a window, so a long run stays bounded).
#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <vector>

namespace pointillist::service {

struct LatencyFigures {
  std::uint64_t count = 0;  // all ever added
  double median = 0.0;
  double p95 = 0.0;
  double max = 0.0;  // over the window
};

class LatencyWindow {
 public:
  explicit LatencyWindow(std::size_t capacity = 4096) : capacity_(capacity) {}

  void add(double value) {
    if (samples_.size() < capacity_) {
      samples_.push_back(value);
    } else {
      samples_[static_cast<std::size_t>(count_ % capacity_)] = value;
    }
    ++count_;
  }

  // Nearest-rank percentiles over the window.
  LatencyFigures figures() const {
    LatencyFigures out;
    out.count = count_;
    if (samples_.empty()) return out;
    std::vector<double> sorted = samples_;
    std::sort(sorted.begin(), sorted.end());
    const auto rank = [&](double share) {
      const auto index =
          static_cast<std::size_t>(share * static_cast<double>(sorted.size()) + 0.999999);
      return sorted[std::clamp<std::size_t>(index, 1, sorted.size()) - 1];
    };
    out.median = rank(0.5);
    out.p95 = rank(0.95);
    out.max = sorted.back();
    return out;
  }

 private:
  std::size_t capacity_;
  std::uint64_t count_ = 0;
  std::vector<double> samples_;
};

}  // namespace pointillist::service
