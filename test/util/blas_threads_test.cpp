#include "rotation_averaging/util/blas_threads.h"

#include <dlfcn.h>
#include <gtest/gtest.h>

#include <cstdlib>

namespace rotation_averaging {
namespace {

// This test links nothing that brings OpenBLAS: the process loads it here, as
// Ceres or OpenCV bring it to the programs, and it must then run every call
// on one thread. Without OpenBLAS on the machine the call finds nothing.
TEST(BlasThreads, OpenBlasIsHeldToOneThread) {
  void* blas = dlopen("libopenblas.so.0", RTLD_NOW | RTLD_GLOBAL);
  if (!blas) GTEST_SKIP() << "no libopenblas.so.0: " << dlerror();
  const auto get = reinterpret_cast<int (*)()>(dlsym(blas, "openblas_get_num_threads"));
  ASSERT_NE(get, nullptr);
  // A thread count the user set is left alone.
  const int before = get();
  setenv("OPENBLAS_NUM_THREADS", "2", 1);
  EXPECT_FALSE(HoldOpenBlasToOneThreadIn(blas));
  EXPECT_EQ(get(), before);
  unsetenv("OPENBLAS_NUM_THREADS");
  unsetenv("GOTO_NUM_THREADS");
  EXPECT_TRUE(HoldOpenBlasToOneThread());
  EXPECT_EQ(get(), 1);
  EXPECT_TRUE(HoldOpenBlasToOneThread());  // once per process; still held
  EXPECT_EQ(get(), 1);
}

}  // namespace
}  // namespace rotation_averaging
