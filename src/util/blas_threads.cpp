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

namespace {

// CBLAS's enumerations, fixed by its standard.
constexpr int kCblasRowMajor = 101, kCblasNoTrans = 111, kCblasTrans = 112;
using CblasSgemm = void (*)(int, int, int, int, int, int, float, const float*, int, const float*, int, float, float*,
                            int);
CblasSgemm openblas_sgemm = nullptr;

void ProductByTransposed(int m, int n, int k, const float* a, const float* b, float* c) {
  openblas_sgemm(kCblasRowMajor, kCblasNoTrans, kCblasTrans, m, n, k, 1.0f, a, k, b, k, 0.0f, c, n);
}

}  // namespace

FloatProductByTransposed OpenBlasFloatProductByTransposed() {
  static std::once_flag once;
  std::call_once(once, [] {
    // cblas_sgemm from the library that holds openblas_set_num_threads: in
    // the global scope BLAS symbols may be another BLAS's (sgemm_ is
    // ATLAS's, which Ceres' and faiss' link lines bring; cblas_sgemm is
    // whichever BLAS libblas.so.3 is).
    void* set = dlsym(RTLD_DEFAULT, "openblas_set_num_threads");
    Dl_info info;
    if (!set || !dladdr(set, &info) || !info.dli_fname) return;
    void* library = dlopen(info.dli_fname, RTLD_LAZY | RTLD_NOLOAD);
    if (!library) return;
    openblas_sgemm = reinterpret_cast<CblasSgemm>(dlsym(library, "cblas_sgemm"));
    HoldOpenBlasToOneThread();
  });
  return openblas_sgemm ? &ProductByTransposed : nullptr;
}

}  // namespace rotation_averaging
