#pragma once
// How render processes turn noisy timings into the T_s and T_n they report
// (seed 003 §4.3), in the RenderCore that the runtime and the simulator share.
#include <algorithm>
#include <cstddef>
#include <deque>
#include <vector>

namespace pointillist {

// T_s: a moving average; contention slows drawing for real, so it counts.
inline double movingAverage(double average, double sample) {
  return average <= 0.0 ? sample : average + 0.2 * (sample - average);
}

// The last `capacity` samples of a noisy measurement. T_n is their lower
// quartile: a transfer is only ever slowed by the receiver being descheduled
// or asleep between polls, never sped up.
class RecentSamples {
 public:
  explicit RecentSamples(std::size_t capacity) : capacity_(capacity) {}
  void add(double sample) {
    if (samples_.size() == capacity_) samples_.pop_front();
    samples_.push_back(sample);
  }
  double lowerQuartile() const {
    if (samples_.empty()) return 0.0;
    std::vector<double> sorted(samples_.begin(), samples_.end());
    const auto quartile = static_cast<std::ptrdiff_t>(sorted.size() / 4);
    std::nth_element(sorted.begin(), sorted.begin() + quartile, sorted.end());
    return sorted[static_cast<std::size_t>(quartile)];
  }

 private:
  std::size_t capacity_;
  std::deque<double> samples_;
};

}  // namespace pointillist
