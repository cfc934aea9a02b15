#include "preprocess/translation_palette.hpp"

#include <fftw3.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <limits>
#include <map>
#include <mutex>
#include <string>

#include "common/errors.hpp"

namespace pointillist::preprocess {

namespace {

// ---- FFT plans and buffers ----------------------------------------------

// Padded lengths come from a short list (2^k, 3 * 2^k, 5 * 2^k): lengths FFTW
// transforms fast, and few shapes to plan in a run.
std::int32_t paddedLength(std::int32_t atLeast) {
  std::int32_t best = std::numeric_limits<std::int32_t>::max();
  for (const std::int32_t base : {8, 12, 20})
    for (std::int32_t length = base; length < best; length *= 2)
      if (length >= atLeast) {
        best = length;
        break;
      }
  return best;
}

struct FftPlan {
  fftwf_plan forward = nullptr;
  fftwf_plan backward = nullptr;
  bool measured = false;
};

struct FftBuffers {
  float* real = nullptr;
  fftwf_complex* spectrum = nullptr;
  std::size_t realCapacity = 0;
  std::size_t spectrumCapacity = 0;
  double seconds = 0.0;
  ~FftBuffers() {
    fftwf_free(real);
    fftwf_free(spectrum);
  }
  void reserve(std::size_t realCount, std::size_t spectrumCount) {
    if (realCount > realCapacity) {
      fftwf_free(real);
      real = fftwf_alloc_real(realCount);
      realCapacity = realCount;
    }
    if (spectrumCount > spectrumCapacity) {
      fftwf_free(spectrum);
      spectrum = fftwf_alloc_complex(spectrumCount);
      spectrumCapacity = spectrumCount;
    }
    if (real == nullptr || spectrum == nullptr) throw std::bad_alloc();
  }
};

thread_local FftBuffers tBuffers;

// FFTW's planner is not thread-safe; executing a plan on other arrays is.
std::mutex gPlanMutex;
std::map<std::array<std::int32_t, 3>, FftPlan> gPlans;
bool gWisdomLoaded = false;

std::filesystem::path wisdomPath() {
  const char* cache = std::getenv("XDG_CACHE_HOME");
  const char* home = std::getenv("HOME");
  std::filesystem::path base;
  if (cache != nullptr && *cache != '\0')
    base = cache;
  else if (home != nullptr && *home != '\0')
    base = std::filesystem::path(home) / ".cache";
  else
    return {};
  return base / "pointillist" / "fftw3f.wisdom";
}

// Plans are made once per shape and reused for every cell. A shape the saved
// wisdom knows gets its measured plan at once; a new one is estimated (no
// planning time in this run) and measured by saveFftWisdom for the next runs.
FftPlan planFor(const std::array<std::int32_t, 3>& n) {
  std::lock_guard lock(gPlanMutex);
  if (const auto it = gPlans.find(n); it != gPlans.end()) return it->second;
  if (!gWisdomLoaded) {
    gWisdomLoaded = true;
    if (const auto path = wisdomPath(); !path.empty() && std::filesystem::exists(path))
      fftwf_import_wisdom_from_filename(path.c_str());  // stale or foreign wisdom is ignored
  }
  FftBuffers& b = tBuffers;
  b.reserve(gridVolume(n), gridVolume({n[0], n[1], n[2] / 2 + 1}));
  FftPlan plan;
  const unsigned known = FFTW_MEASURE | FFTW_WISDOM_ONLY;
  plan.forward = fftwf_plan_dft_r2c_3d(n[0], n[1], n[2], b.real, b.spectrum, known);
  plan.backward = fftwf_plan_dft_c2r_3d(n[0], n[1], n[2], b.spectrum, b.real, known);
  plan.measured = plan.forward != nullptr && plan.backward != nullptr;
  if (!plan.measured) {
    if (plan.forward != nullptr) fftwf_destroy_plan(plan.forward);
    if (plan.backward != nullptr) fftwf_destroy_plan(plan.backward);
    plan.forward = fftwf_plan_dft_r2c_3d(n[0], n[1], n[2], b.real, b.spectrum, FFTW_ESTIMATE);
    plan.backward = fftwf_plan_dft_c2r_3d(n[0], n[1], n[2], b.spectrum, b.real, FFTW_ESTIMATE);
  }
  if (plan.forward == nullptr || plan.backward == nullptr)
    throw Error("internal error: FFTW could not plan a " + std::to_string(n[0]) + "x" +
                std::to_string(n[1]) + "x" + std::to_string(n[2]) + " transform");
  gPlans.emplace(n, plan);
  return plan;
}

bool better(const TranslationCount& a, const TranslationCount& b) {
  if (a.count != b.count) return a.count > b.count;
  return a.t < b.t;
}

}  // namespace

// ---- the palette ----------------------------------------------------------

std::vector<TranslationCount> translationPalette(std::span<const Voxel> occupied,
                                                 const std::array<std::int32_t, 3>& dims,
                                                 std::size_t limit, std::int32_t window) {
  if (occupied.size() < 2 || limit == 0) return {};
  const auto start = std::chrono::steady_clock::now();
  // Zero padding to 2N - 1 per axis: the circular correlation is then the
  // linear one, every translation in (-N, N) on its own frequency bin.
  // Translations within the window: padding each axis to N + w keeps every
  // lag up to w on its own bin (no wrap-around) at a fraction of 2N - 1.
  std::array<std::int32_t, 3> reach{};
  std::array<std::int32_t, 3> padded{};
  for (std::size_t a = 0; a < 3; ++a) {
    reach[a] = std::min(window, dims[a] - 1);
    padded[a] = paddedLength(dims[a] + reach[a]);
  }
  // Axes in descending padded length: permutations of one shape share a plan.
  std::array<std::size_t, 3> axis{0, 1, 2};
  std::stable_sort(axis.begin(), axis.end(),
                   [&](std::size_t a, std::size_t b) { return padded[a] > padded[b]; });
  const std::array<std::int32_t, 3> n{padded[axis[0]], padded[axis[1]], padded[axis[2]]};
  const std::array<std::int32_t, 3> lag{reach[axis[0]], reach[axis[1]], reach[axis[2]]};
  const FftPlan plan = planFor(n);
  const std::size_t realCount = gridVolume(n);
  const std::size_t spectrumCount = gridVolume({n[0], n[1], n[2] / 2 + 1});
  FftBuffers& b = tBuffers;
  b.reserve(realCount, spectrumCount);
  std::fill_n(b.real, realCount, 0.0f);
  for (const Voxel& v : occupied)
    b.real[gridIndex(n, v.q[axis[0]], v.q[axis[1]], v.q[axis[2]])] = 1.0f;
  fftwf_execute_dft_r2c(plan.forward, b.real, b.spectrum);
  // A(f) times its conjugate: the power spectrum, the transform of the autocorrelation.
  for (std::size_t i = 0; i < spectrumCount; ++i) {
    const float re = b.spectrum[i][0], im = b.spectrum[i][1];
    b.spectrum[i][0] = re * re + im * im;
    b.spectrum[i][1] = 0.0f;
  }
  fftwf_execute_dft_c2r(plan.backward, b.spectrum, b.real);

  const double scale = 1.0 / static_cast<double>(realCount);  // FFTW does not normalize
  auto translationOf = [&](std::int32_t i, std::size_t a) -> std::int32_t {
    if (i <= lag[a]) return i;
    if (i >= n[a] - lag[a]) return i - n[a];
    return std::numeric_limits<std::int32_t>::min();  // beyond any pair of voxels
  };
  // Worst on top: a heap ordered by `better`.
  std::vector<TranslationCount> heap;
  heap.reserve(limit + 1);
  for (std::int32_t x = 0; x < n[0]; ++x) {
    const std::int32_t tx = translationOf(x, 0);
    if (tx == std::numeric_limits<std::int32_t>::min()) continue;
    for (std::int32_t y = 0; y < n[1]; ++y) {
      const std::int32_t ty = translationOf(y, 1);
      if (ty == std::numeric_limits<std::int32_t>::min()) continue;
      const float* row = b.real + gridIndex(n, x, y, 0);
      for (std::int32_t z = 0; z < n[2]; ++z) {
        // Counts below 1.5 are never kept: skip the rounding for them.
        const double value = double{row[z]} * scale;
        if (value < 1.5) continue;
        const std::int32_t tz = translationOf(z, 2);
        if (tz == std::numeric_limits<std::int32_t>::min() || (tx == 0 && ty == 0 && tz == 0))
          continue;
        TranslationCount c{{}, static_cast<std::uint32_t>(std::llround(value))};
        c.t[axis[0]] = tx;
        c.t[axis[1]] = ty;
        c.t[axis[2]] = tz;
        if (heap.size() < limit) {
          heap.push_back(c);
          std::push_heap(heap.begin(), heap.end(), better);
        } else if (better(c, heap.front())) {
          std::pop_heap(heap.begin(), heap.end(), better);
          heap.back() = c;
          std::push_heap(heap.begin(), heap.end(), better);
        }
      }
    }
  }
  std::sort(heap.begin(), heap.end(), better);
  b.seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return heap;
}

std::vector<TranslationCount> bruteForceTranslationCounts(std::span<const Voxel> occupied) {
  std::map<std::array<std::int32_t, 3>, std::uint32_t> counts;
  for (const Voxel& a : occupied)
    for (const Voxel& b : occupied)
      if (a != b) ++counts[{b.q[0] - a.q[0], b.q[1] - a.q[1], b.q[2] - a.q[2]}];
  std::vector<TranslationCount> out;
  for (const auto& [t, c] : counts) out.push_back({t, c});
  return out;
}

double fftSecondsThisThread() {
  return tBuffers.seconds;
}

std::size_t fftPlansMade() {
  std::lock_guard lock(gPlanMutex);
  return gPlans.size();
}

std::size_t saveFftWisdom(double budgetSeconds) {
  std::lock_guard lock(gPlanMutex);
  const auto path = wisdomPath();
  if (path.empty()) return 0;
  const auto start = std::chrono::steady_clock::now();
  std::size_t measured = 0;
  std::vector<std::pair<std::size_t, std::array<std::int32_t, 3>>> pending;
  for (const auto& [n, plan] : gPlans)
    if (!plan.measured) pending.emplace_back(gridVolume(n), n);
  std::sort(pending.begin(), pending.end());  // small shapes first: most within the budget
  for (const auto& [size, n] : pending) {
    const double left =
        budgetSeconds -
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    if (left <= 0.0) break;
    float* real = fftwf_alloc_real(size);
    fftwf_complex* spectrum = fftwf_alloc_complex(gridVolume({n[0], n[1], n[2] / 2 + 1}));
    if (real == nullptr || spectrum == nullptr) {
      fftwf_free(real);
      fftwf_free(spectrum);
      break;
    }
    fftwf_set_timelimit(left / 2.0);
    const fftwf_plan forward =
        fftwf_plan_dft_r2c_3d(n[0], n[1], n[2], real, spectrum, FFTW_MEASURE);
    const fftwf_plan backward =
        fftwf_plan_dft_c2r_3d(n[0], n[1], n[2], spectrum, real, FFTW_MEASURE);
    if (forward != nullptr) fftwf_destroy_plan(forward);
    if (backward != nullptr) fftwf_destroy_plan(backward);
    fftwf_free(real);
    fftwf_free(spectrum);
    gPlans[n].measured = true;  // the wisdom knows it now; this run keeps its plan
    ++measured;
  }
  fftwf_set_timelimit(FFTW_NO_TIMELIMIT);
  if (measured == 0) return 0;
  std::error_code ec;
  std::filesystem::create_directories(path.parent_path(), ec);
  // Wisdom only saves planning time: a cache that cannot be written is no error.
  if (!ec) fftwf_export_wisdom_to_filename(path.c_str());
  return measured;
}
}  // namespace pointillist::preprocess
