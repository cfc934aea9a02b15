#include "common/task_pool.hpp"

namespace pointillist {

TaskPool::TaskPool(unsigned threads) {
  for (unsigned t = 1; t < threads; ++t) workers_.emplace_back([this] { work(); });
}

TaskPool::~TaskPool() {
  {
    const std::lock_guard lock(mutex_);
    stop_ = true;
  }
  wake_.notify_all();
  for (auto& worker : workers_) worker.join();
}

// Takes tasks of the current run until none is left; called with no lock held.
void TaskPool::drain() {
  std::unique_lock lock(mutex_);
  while (task_ != nullptr && next_ < count_) {
    const std::size_t i = next_++;
    const auto* task = task_;
    lock.unlock();
    (*task)(i);
    lock.lock();
    if (++finished_ == count_) done_.notify_all();
  }
}

void TaskPool::work() {
  std::size_t seen = 0;
  while (true) {
    {
      std::unique_lock lock(mutex_);
      wake_.wait(lock, [&] { return stop_ || generation_ != seen; });
      if (stop_) return;
      seen = generation_;
    }
    drain();
  }
}

void TaskPool::run(std::size_t n, const std::function<void(std::size_t)>& task) {
  if (n == 0) return;
  {
    const std::lock_guard lock(mutex_);
    task_ = &task;
    count_ = n;
    next_ = 0;
    finished_ = 0;
    ++generation_;
  }
  if (n > 1) wake_.notify_all();
  drain();
  std::unique_lock lock(mutex_);
  done_.wait(lock, [&] { return finished_ == count_; });
  task_ = nullptr;
}

}  // namespace pointillist
