#pragma once
// The preprocess's one way of spreading independent items over threads.
#include <algorithm>
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <exception>
#include <thread>
#include <vector>

#include <sys/mman.h>

namespace pointillist::preprocess {

// Calls fn(i) for every i in [0, n) on `threads` threads (0: all cores),
// handing out chunks of `chunk` items so uneven items even out. Where fn
// throws, no further chunk is handed out and the first exception is
// rethrown here once every thread is joined (thrown on a thread of its own,
// it ended the process; on this one, it left the others unjoined, which did
// too).
template <class Fn>
void parallelFor(std::size_t n, unsigned threads, Fn fn, std::size_t chunk = 64) {
  if (threads == 0) threads = std::max(1u, std::thread::hardware_concurrency());
  std::atomic<std::size_t> next{0};
  std::atomic<bool> failed{false};
  std::exception_ptr error;  // the first one, set once `failed` is won
  auto run = [&] {
    try {
      for (std::size_t b; (b = next.fetch_add(chunk)) < n;)
        for (std::size_t i = b; i < std::min(n, b + chunk); ++i) fn(i);
    } catch (...) {
      if (!failed.exchange(true)) error = std::current_exception();
      next.store(n);
    }
  };
  std::vector<std::thread> pool;
  for (unsigned t = 1; t < threads && static_cast<std::size_t>(t) * chunk < n; ++t)
    pool.emplace_back(run);
  run();
  for (auto& t : pool) t.join();
  if (error) std::rethrow_exception(error);
}

// Copies n trivially copyable values on `threads` threads (0: all cores).
template <class T>
void parallelCopy(const T* from, std::size_t n, T* to, unsigned threads) {
  constexpr std::size_t kChunk = std::size_t{1} << 16;
  parallelFor((n + kChunk - 1) / kChunk, threads,
              [&](std::size_t chunk) {
                const std::size_t first = chunk * kChunk;
                std::memcpy(to + first, from + first, std::min(kChunk, n - first) * sizeof(T));
              },
              1);
}

// Maps fresh memory's pages in ahead of a serial writer, on `threads` threads
// (0: all cores), one madvise call per 16 MiB: a page fault taken one by one costs
// microseconds on a virtual machine (0.2 s for 320 MB here), and a serial
// copy into a fresh vector took them all on one core. Only a hint: the
// pages are zero either way, and a kernel without MADV_POPULATE_WRITE (before
// Linux 5.14) leaves them to fault as before.
inline void populatePages(void* data, std::size_t bytes, unsigned threads) {
#ifdef MADV_POPULATE_WRITE
  constexpr std::size_t kPage = 4096;
  constexpr std::size_t kChunk = std::size_t{16} << 20;
  const auto first = (reinterpret_cast<std::uintptr_t>(data) + kPage - 1) / kPage * kPage;
  const auto last = (reinterpret_cast<std::uintptr_t>(data) + bytes) / kPage * kPage;
  if (last <= first) return;
  parallelFor((last - first + kChunk - 1) / kChunk, threads,
              [&](std::size_t c) {
                const std::uintptr_t begin = first + c * kChunk;
                // NOLINTNEXTLINE(performance-no-int-to-ptr): an address range for the kernel
                ::madvise(reinterpret_cast<void*>(begin),
                          std::min<std::uintptr_t>(kChunk, last - begin), MADV_POPULATE_WRITE);
              },
              1);
#else
  (void)data;
  (void)bytes;
  (void)threads;
#endif
}

// Resizes `values` to n, the new elements' pages mapped on `threads` threads
// first: a resize or a scattered fill of fresh memory would take every page
// fault one by one (on one core for the resize).
template <class Vector>
void resizePopulated(Vector& values, std::size_t n, unsigned threads) {
  if (n > values.size()) {
    values.reserve(n);
    populatePages(values.data() + values.size(),
                  (n - values.size()) * sizeof(typename Vector::value_type), threads);
  }
  values.resize(n);
}

// std::sort on `threads` threads (0: all cores): pieces sorted apart, then
// merged pairwise. The order is the one std::sort gives wherever `less` is a
// strict total order (no two items equal).
template <class Iterator, class Less>
void parallelSort(Iterator first, Iterator last, unsigned threads, Less less) {
  if (threads == 0) threads = std::max(1u, std::thread::hardware_concurrency());
  const auto n = static_cast<std::size_t>(last - first);
  if (threads < 2 || n < (std::size_t{1} << 16)) {
    std::sort(first, last, less);
    return;
  }
  const std::size_t pieces = threads;
  std::vector<Iterator> bound(pieces + 1);
  for (std::size_t p = 0; p <= pieces; ++p)
    bound[p] = first + static_cast<std::ptrdiff_t>(n * p / pieces);
  parallelFor(
      pieces, threads, [&](std::size_t p) { std::sort(bound[p], bound[p + 1], less); }, 1);
  for (std::size_t width = 1; width < pieces; width *= 2) {
    parallelFor((pieces + 2 * width - 1) / (2 * width), threads,
                [&](std::size_t pair) {
                  const std::size_t left = pair * 2 * width;
                  const std::size_t middle = std::min(pieces, left + width);
                  const std::size_t right = std::min(pieces, left + 2 * width);
                  if (middle < right)
                    std::inplace_merge(bound[left], bound[middle], bound[right], less);
                },
                1);
  }
}

}  // namespace pointillist::preprocess
