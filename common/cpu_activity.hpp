#pragma once
// Where a process's CPU time goes: thread CPU time summed per named activity
// (receiving, handling each message kind, drawing, polling), so a benchmark
// can show the overhead of distribution and drive it down.
#include <map>
#include <string>

namespace pointillist {

// CPU time of the calling thread, in seconds.
double threadCpuSeconds();

class CpuActivities {
 public:
  void add(const std::string& activity, double seconds) { totals_[activity] += seconds; }
  const std::map<std::string, double>& totals() const { return totals_; }

  // Charges the calling thread's CPU time from construction (or the last
  // switchTo) to the activity named then.
  class Meter {
   public:
    Meter(CpuActivities& activities, std::string activity)
        : activities_(activities), activity_(std::move(activity)), start_(threadCpuSeconds()) {}
    ~Meter() { stop(); }
    Meter(const Meter&) = delete;
    Meter& operator=(const Meter&) = delete;
    void switchTo(std::string activity) {
      stop();
      activity_ = std::move(activity);
    }
    // Charges the span running now to another activity (once it turns out
    // what it was, e.g. a receive that found nothing was polling).
    void relabel(std::string activity) { activity_ = std::move(activity); }

   private:
    void stop() {
      const double now = threadCpuSeconds();
      activities_.add(activity_, now - start_);
      start_ = now;
    }
    CpuActivities& activities_;
    std::string activity_;
    double start_;
  };

 private:
  std::map<std::string, double> totals_;
};

}  // namespace pointillist
