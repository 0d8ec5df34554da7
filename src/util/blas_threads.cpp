#include "rotation_averaging/util/blas_threads.h"

#include <dlfcn.h>

#include <cstdlib>
#include <mutex>

namespace rotation_averaging {

bool HoldOpenBlasToOneThread() {
  static std::once_flag once;
  static bool held = false;
  std::call_once(once, [] {
    const auto set = reinterpret_cast<void (*)(int)>(dlsym(RTLD_DEFAULT, "openblas_set_num_threads"));
    if (!set) return;
    held = true;
    if (std::getenv("OPENBLAS_NUM_THREADS") || std::getenv("GOTO_NUM_THREADS")) return;
    set(1);
  });
  return held;
}

}  // namespace rotation_averaging
