#include "common/task_pool.hpp"

#include <atomic>
#include <chrono>
#include <mutex>
#include <set>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

namespace pointillist {
namespace {

TEST(TaskPool, EveryTaskRunsOnceEveryRunAndOnSeveralThreads) {
  TaskPool pool(4);
  EXPECT_EQ(pool.threads(), 4u);
  std::mutex mutex;
  std::set<std::thread::id> threads;
  for (int round = 0; round < 200; ++round) {
    const std::size_t n = 1 + static_cast<std::size_t>(round % 37);
    std::vector<std::atomic<int>> runs(n);
    pool.run(n, [&](std::size_t i) {
      runs[i].fetch_add(1);
      if (n > 30) {
        // Long enough that the workers take some.
        std::this_thread::sleep_for(std::chrono::microseconds(200));
        const std::lock_guard lock(mutex);
        threads.insert(std::this_thread::get_id());
      }
    });
    for (std::size_t i = 0; i < n; ++i) ASSERT_EQ(runs[i].load(), 1) << round << " " << i;
  }
  EXPECT_GT(threads.size(), 1u) << "the workers took part";
  pool.run(0, [](std::size_t) { FAIL() << "no task in an empty run"; });
}

TEST(TaskPool, OneThreadRunsOnTheCaller) {
  TaskPool pool(1);
  EXPECT_EQ(pool.threads(), 1u);
  const auto caller = std::this_thread::get_id();
  int sum = 0;
  pool.run(10, [&](std::size_t i) {
    EXPECT_EQ(std::this_thread::get_id(), caller);
    sum += static_cast<int>(i);
  });
  EXPECT_EQ(sum, 45);
}

}  // namespace
}  // namespace pointillist
