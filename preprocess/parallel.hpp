#pragma once
// The preprocess's one way of spreading independent items over threads.
#include <algorithm>
#include <atomic>
#include <cstddef>
#include <thread>
#include <vector>

namespace pointillist::preprocess {

// Calls fn(i) for every i in [0, n) on `threads` threads (0: all cores),
// handing out chunks of `chunk` items so uneven items even out.
template <class Fn>
void parallelFor(std::size_t n, unsigned threads, Fn fn, std::size_t chunk = 64) {
  if (threads == 0) threads = std::max(1u, std::thread::hardware_concurrency());
  std::atomic<std::size_t> next{0};
  auto run = [&] {
    for (std::size_t b; (b = next.fetch_add(chunk)) < n;)
      for (std::size_t i = b; i < std::min(n, b + chunk); ++i) fn(i);
  };
  std::vector<std::thread> pool;
  for (unsigned t = 1; t < threads && static_cast<std::size_t>(t) * chunk < n; ++t)
    pool.emplace_back(run);
  run();
  for (auto& t : pool) t.join();
}

}  // namespace pointillist::preprocess
