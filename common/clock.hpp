#pragma once
// Time as the roles' cores see it: they never read a clock, they are told
// `now`. The MPI roles pass steady_clock::now(); the simulator passes
// simulated seconds as time points after the clock's epoch.
#include <chrono>

namespace pointillist {

using Clock = std::chrono::steady_clock;
using TimePoint = Clock::time_point;

inline double secondsBetween(TimePoint from, TimePoint to) {
  return std::chrono::duration<double>(to - from).count();
}

inline double millisecondsBetween(TimePoint from, TimePoint to) {
  return std::chrono::duration<double, std::milli>(to - from).count();
}

inline TimePoint timeAfterEpoch(double seconds) {
  return TimePoint{} +
         std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(seconds));
}

inline double secondsSinceEpoch(TimePoint time) {
  return std::chrono::duration<double>(time.time_since_epoch()).count();
}

inline Clock::duration durationOf(double seconds) {
  return std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(seconds));
}

}  // namespace pointillist
