// Internal to the package: may change between versions.
// OpenBLAS, when it is the BLAS this process loaded, held to one thread.
//
// CHOLMOD's supernodal factorisation calls BLAS for its dense supernode
// updates. The pthread build of OpenBLAS (see CMakeLists.txt) runs those on a
// pool of worker threads that it starts when it loads; on the factors of
// pose graphs the threads cost more than they bring (median of 7 solves on a
// 2-core machine: sphere2500 0.24 s with its default threads against 0.054 s
// with one, cubicle 0.67 vs 0.24 s), and the solver is single-threaded by
// design. Looked up at run time: other BLAS have no such calls.
#ifndef ROTATION_AVERAGING_UTIL_BLAS_THREADS_H_
#define ROTATION_AVERAGING_UTIL_BLAS_THREADS_H_

namespace rotation_averaging {

// Holds OpenBLAS to one thread, once per process: the first call that finds
// OpenBLAS decides, later ones do nothing. A thread count the user set
// (OPENBLAS_NUM_THREADS, GOTO_NUM_THREADS) is kept. OpenBLAS is looked up in
// `library` (a dlopen handle: that library and its dependencies) or, when
// null, in the process's global scope. With `stop_pool` the workers OpenBLAS
// started when it loaded are shut down as well (idle workers spin on
// sched_yield for a while before they sleep, a core each). Stopping the pool
// is only safe while no other thread can be calling BLAS: right after
// OpenBLAS was loaded by the caller, or first thing in main.
void HoldOpenBlasToOneThread(bool stop_pool = false, void* library = nullptr);

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_UTIL_BLAS_THREADS_H_
