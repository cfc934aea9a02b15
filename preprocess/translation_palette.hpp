#pragma once
// Seed 000 §5: transformation palettes. The most common translations between
// the occupied voxels of a grid are the peaks of the occupancy's
// autocorrelation, computed with FFTW as the power spectrum transformed back.
#include <array>
#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

#include "common/instanced_section.hpp"

namespace pointillist::preprocess {

// Row-major voxel grids: x slowest, z fastest.
inline std::size_t gridVolume(const std::array<std::int32_t, 3>& d) {
  return static_cast<std::size_t>(std::int64_t{d[0]} * d[1] * d[2]);
}
inline std::size_t gridIndex(const std::array<std::int32_t, 3>& d, std::int32_t x, std::int32_t y,
                             std::int32_t z) {
  return static_cast<std::size_t>((std::int64_t{x} * d[1] + y) * d[2] + z);
}

struct TranslationCount {
  std::array<std::int32_t, 3> t{};
  std::uint32_t count = 0;  // ordered pairs of occupied voxels it maps
  bool operator==(const TranslationCount&) const = default;
};

// The `limit` most common non-null translations among distinct occupied
// voxels inside `dims`, no component beyond +-window, counted by FFT
// autocorrelation; only counts of at least 2; by count descending, then t
// ascending. Thread-safe.
std::vector<TranslationCount> translationPalette(std::span<const Voxel> occupied,
                                                 const std::array<std::int32_t, 3>& dims,
                                                 std::size_t limit, std::int32_t window = 32);
// Every non-null translation's count by comparing all pairs, sorted by t (tests).
std::vector<TranslationCount> bruteForceTranslationCounts(std::span<const Voxel> occupied);

// Wall time spent in FFTs by this thread, and FFT shapes planned (statistics).
double fftSecondsThisThread();
std::size_t fftPlansMade();
// FFTW wisdom lives in $XDG_CACHE_HOME/pointillist (or ~/.cache/pointillist).
// A shape it knows is planned measured; a new one is estimated at once, and
// this measures the new shapes within the budget and saves the wisdom for the
// next runs. Returns the shapes measured.
std::size_t saveFftWisdom(double budgetSeconds = 2.0);

}  // namespace pointillist::preprocess
