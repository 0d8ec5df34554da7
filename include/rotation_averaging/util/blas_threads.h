// OpenBLAS held to one thread. Debian's BLAS is OpenBLAS's pthread build,
// which splits each call over a pool of worker threads, one per core, that
// it starts when it loads. The package's work is many small dense products
// (CHOLMOD's supernodes under Ceres' bundle adjustment and the averaging's
// factorisations, OpenCV's LAPACK), threaded already where it pays (the
// front end's pool): split further, the workers mostly wait, and a waiting
// worker spins on sched_yield, a core each, for a while before it sleeps,
// taking the CPU the rest of a robot's stack needs. And a product split over
// another number of threads differs in its last bits: the results would
// depend on the machine's core count. Measured on the replay of the demo bag
// (results/refinement.md, "OpenBLAS").
#ifndef ROTATION_AVERAGING_UTIL_BLAS_THREADS_H_
#define ROTATION_AVERAGING_UTIL_BLAS_THREADS_H_

namespace rotation_averaging {

// OpenBLAS, looked up in `library` (a dlopen handle, searched with its
// dependencies; RTLD_DEFAULT: the process's global scope), runs every later
// call on the calling thread, unless the user set a thread count
// (OPENBLAS_NUM_THREADS or GOTO_NUM_THREADS). True if it was found and is
// held now; false without OpenBLAS there, or with the user's count left alone.
bool HoldOpenBlasToOneThreadIn(void* library);
// The same in the process's global scope, once per process (the first
// call's answer).
bool HoldOpenBlasToOneThread();

// OpenBLAS's cblas_sgemm, when the process has OpenBLAS (the package's setup
// installs it as the system BLAS): C = A B^T for row-major float matrices,
// A m x k, B n x k, C m x n (leading dimensions k, k and n). Its kernels
// are chosen for the CPU it runs on (AVX-512 or AVX2 where there is one),
// where Eigen's are the ones this package was compiled for (SSE2 on
// x86-64). OpenBLAS is held to one thread first, so a product is computed
// the same way whatever calls it. Null without OpenBLAS: the caller keeps
// its own product. Looked up once per process.
using FloatProductByTransposed = void (*)(int m, int n, int k, const float* a, const float* b, float* c);
FloatProductByTransposed OpenBlasFloatProductByTransposed();

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_UTIL_BLAS_THREADS_H_
