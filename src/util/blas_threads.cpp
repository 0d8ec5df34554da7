#include "rotation_averaging/util/blas_threads.h"

#include <dlfcn.h>

#include <cstdlib>
#include <mutex>

namespace rotation_averaging {

bool HoldOpenBlasToOneThreadIn(void* library) {
  if (std::getenv("OPENBLAS_NUM_THREADS") || std::getenv("GOTO_NUM_THREADS")) return false;
  const auto set = reinterpret_cast<void (*)(int)>(dlsym(library, "openblas_set_num_threads"));
  if (!set) return false;
  set(1);
  return true;
}

bool HoldOpenBlasToOneThread() {
  static std::once_flag once;
  static bool held = false;
  std::call_once(once, [] { held = HoldOpenBlasToOneThreadIn(RTLD_DEFAULT); });
  return held;
}

}  // namespace rotation_averaging
