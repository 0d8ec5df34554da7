#include "core/util/backends.h"

#include <dlfcn.h>

#include <atomic>
#include <iostream>
#include <mutex>
#include <string>

#include "rotation_averaging/util/blas_threads.h"

namespace rotation_averaging {
namespace {

constexpr char kLibraryName[] = "librotation_averaging_backends.so";
constexpr char kEntryPoint[] = "rotation_averaging_backends";

std::atomic<const Backends*> loaded{nullptr};

// CHOLMOD's supernodal factorisation calls BLAS for its dense supernode
// updates. The pthread build of OpenBLAS (see CMakeLists.txt) runs those on a
// pool of worker threads that it starts when it loads; on the factors of
// pose graphs the threads cost more than they bring (the real pose graphs
// solved several times faster with one thread), and the solver is
// single-threaded by design. So OpenBLAS, looked up in `library` and its
// dependencies (other BLAS have no such calls), is held to one thread
// (util/blas_threads.h). With `stop_pool` the workers it started are shut
// down as well (idle workers spin on sched_yield for a while before they
// sleep, a core each): only safe while no other thread can be calling BLAS.
void HoldBackendsBlasToOneThread(void* library, bool stop_pool) {
  if (!HoldOpenBlasToOneThreadIn(library) || !stop_pool) return;
  if (const auto shutdown = reinterpret_cast<int (*)()>(dlsym(library, "blas_thread_shutdown_"))) shutdown();
}

// The directory of the library this function is in (the core), with a
// trailing slash; empty if the dynamic linker cannot say.
std::string CoreLibraryDirectory() {
  Dl_info info;
  if (dladdr(reinterpret_cast<void*>(&LoadBackends), &info) == 0 || info.dli_fname == nullptr) return "";
  const std::string path = info.dli_fname;
  const std::size_t slash = path.rfind('/');
  return slash == std::string::npos ? "" : path.substr(0, slash + 1);
}

const Backends* Load() {
  // Whether OpenBLAS is in the process already (OpenCV's LAPACK brings it to
  // the node): if it is, other threads may be calling it.
  void* blas = dlopen("libopenblas.so.0", RTLD_LAZY | RTLD_NOLOAD);
  const bool blas_was_loaded = blas != nullptr;
  if (blas) dlclose(blas);

  std::string errors;
  void* handle = nullptr;
  const std::string directory = CoreLibraryDirectory();
  if (!directory.empty()) {
    handle = dlopen((directory + kLibraryName).c_str(), RTLD_NOW | RTLD_LOCAL);
    if (!handle) errors = dlerror();
  }
  if (!handle) {
    handle = dlopen(kLibraryName, RTLD_NOW | RTLD_LOCAL);
    if (!handle) errors += std::string(errors.empty() ? "" : "; ") + dlerror();
  }
  if (!handle) {
    std::cerr << "rotation_averaging: cannot load " << kLibraryName << " (" << errors
              << "): solving without CHOLMOD's supernodal factor and without the Ceres solver" << std::endl;
    return nullptr;
  }
  using EntryPoint = const Backends* (*)();
  const auto entry = reinterpret_cast<EntryPoint>(dlsym(handle, kEntryPoint));
  if (!entry) {
    std::cerr << "rotation_averaging: " << kLibraryName << " has no " << kEntryPoint
              << ": solving without its back ends" << std::endl;
    return nullptr;
  }
  // If OpenBLAS came in with the library just now, no other thread can be
  // using its pool yet: stopping the pool is safe.
  HoldBackendsBlasToOneThread(handle, /*stop_pool=*/!blas_was_loaded);
  return entry();
}

}  // namespace

const Backends* LoadBackends() {
  static std::once_flag once;
  std::call_once(once, [] { loaded.store(Load()); });
  return loaded.load();
}

bool BackendsLoaded() { return loaded.load() != nullptr; }

}  // namespace rotation_averaging
