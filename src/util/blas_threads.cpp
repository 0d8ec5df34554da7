#include "rotation_averaging/util/blas_threads.h"

#include <dlfcn.h>

#include <cstdlib>
#include <mutex>

namespace rotation_averaging {

void HoldOpenBlasToOneThread(bool stop_pool) {
  static std::once_flag once;
  std::call_once(once, [stop_pool] {
    if (std::getenv("OPENBLAS_NUM_THREADS") || std::getenv("GOTO_NUM_THREADS")) return;
    using SetThreads = void (*)(int);
    using Shutdown = int (*)();
    const auto set = reinterpret_cast<SetThreads>(dlsym(RTLD_DEFAULT, "openblas_set_num_threads"));
    if (!set) return;
    set(1);
    if (!stop_pool) return;
    if (const auto shutdown = reinterpret_cast<Shutdown>(dlsym(RTLD_DEFAULT, "blas_thread_shutdown_"))) shutdown();
    setenv("OPENBLAS_NUM_THREADS", "1", /*overwrite=*/0);
  });
}

}  // namespace rotation_averaging
