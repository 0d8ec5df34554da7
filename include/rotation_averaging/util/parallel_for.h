// Runs independent tasks on a few threads. Each task writes only its own
// slot of the caller's output and the caller combines the slots in task
// order, so results do not depend on the number of threads or on which
// thread ran what.
#ifndef ROTATION_AVERAGING_UTIL_PARALLEL_FOR_H_
#define ROTATION_AVERAGING_UTIL_PARALLEL_FOR_H_

#include <algorithm>
#include <atomic>
#include <exception>
#include <mutex>
#include <thread>
#include <vector>

namespace rotation_averaging {

// The number of threads `requested` means: itself if positive, else the
// machine's cores (at least 1).
inline int ResolveThreadCount(int requested) {
  if (requested > 0) return requested;
  return std::max(1, static_cast<int>(std::thread::hardware_concurrency()));
}

// Calls task(i) for i in [0, count) on up to num_threads threads (the caller
// is one of them). Tasks are handed out one at a time, so long and short ones
// balance. The first exception a task throws is rethrown here once all
// threads have stopped.
template <typename Task>
void ParallelFor(int count, int num_threads, const Task& task) {
  const int threads = std::min(std::max(1, num_threads), count);
  if (threads <= 1) {
    for (int i = 0; i < count; ++i) task(i);
    return;
  }
  std::atomic<int> next{0};
  std::exception_ptr failure;
  std::mutex failure_mutex;
  auto work = [&]() {
    for (int i = next++; i < count; i = next++) {
      try {
        task(i);
      } catch (...) {
        std::lock_guard<std::mutex> lock(failure_mutex);
        if (!failure) failure = std::current_exception();
      }
    }
  };
  std::vector<std::thread> pool;
  pool.reserve(threads - 1);
  for (int t = 1; t < threads; ++t) pool.emplace_back(work);
  work();
  for (std::thread& t : pool) t.join();
  if (failure) std::rethrow_exception(failure);
}

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_UTIL_PARALLEL_FOR_H_
