#include "rotation_averaging/util/blas_threads.h"

#include <dlfcn.h>

#include <cstdlib>
#include <mutex>

namespace rotation_averaging {

void HoldOpenBlasToOneThread(bool stop_pool, void* library) {
  static std::mutex mutex;
  static bool held = false;
  std::lock_guard<std::mutex> lock(mutex);
  if (held) return;
  if (std::getenv("OPENBLAS_NUM_THREADS") || std::getenv("GOTO_NUM_THREADS")) {
    held = true;
    return;
  }
  void* scope = library ? library : RTLD_DEFAULT;
  using SetThreads = void (*)(int);
  using Shutdown = int (*)();
  const auto set = reinterpret_cast<SetThreads>(dlsym(scope, "openblas_set_num_threads"));
  if (!set) return;  // OpenBLAS not loaded (yet): a later call decides
  held = true;
  set(1);
  if (!stop_pool) return;
  if (const auto shutdown = reinterpret_cast<Shutdown>(dlsym(scope, "blas_thread_shutdown_"))) shutdown();
}

}  // namespace rotation_averaging
