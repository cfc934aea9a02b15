#pragma once
// A few threads kept for short bursts of independent work (the display's
// compressed tile images of one receive batch): starting threads for each
// burst would cost more than some bursts take. Idle workers block on a
// condition variable, so a pool on a shared core costs nothing between bursts.
#include <condition_variable>
#include <cstddef>
#include <functional>
#include <mutex>
#include <thread>
#include <vector>

namespace pointillist {

class TaskPool {
 public:
  // `threads` in all, the caller of run() included (at least 1: no workers).
  explicit TaskPool(unsigned threads);
  ~TaskPool();
  TaskPool(const TaskPool&) = delete;
  TaskPool& operator=(const TaskPool&) = delete;

  unsigned threads() const { return static_cast<unsigned>(workers_.size()) + 1; }

  // Calls task(i) for every i in [0, n) on the workers and this thread, and
  // returns when all are done. A task must not throw (catch inside it). Not
  // reentrant: one run at a time.
  void run(std::size_t n, const std::function<void(std::size_t)>& task);

 private:
  void work();
  void drain();

  std::mutex mutex_;
  std::condition_variable wake_, done_;
  const std::function<void(std::size_t)>* task_ = nullptr;  // under mutex_
  std::size_t count_ = 0, next_ = 0, finished_ = 0;         // under mutex_
  std::size_t generation_ = 0;                              // under mutex_
  bool stop_ = false;                                       // under mutex_
  std::vector<std::thread> workers_;
};

}  // namespace pointillist
