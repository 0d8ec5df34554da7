#include "rotation_averaging/util/blas_threads.h"

#include <dlfcn.h>
#include <gtest/gtest.h>

#include <cstdlib>
#include <random>
#include <vector>

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

// The product the descriptor matching takes from OpenBLAS: C = A B^T,
// row-major, against the sum written out (float sums of 128 terms: a relative
// 1e-5 apart at most).
TEST(BlasThreads, OpenBlasFloatProductByTransposedIsTheProduct) {
  void* blas = dlopen("libopenblas.so.0", RTLD_NOW | RTLD_GLOBAL);
  if (!blas) GTEST_SKIP() << "no libopenblas.so.0: " << dlerror();
  const FloatProductByTransposed product = OpenBlasFloatProductByTransposed();
  ASSERT_NE(product, nullptr);
  EXPECT_EQ(product, OpenBlasFloatProductByTransposed());
  const int m = 37, n = 53, k = 128;
  std::mt19937 random(7);
  std::uniform_real_distribution<float> value(0.0f, 255.0f);
  std::vector<float> a(m * k), b(n * k), c(m * n, -1.0f);
  for (float& x : a) x = value(random);
  for (float& x : b) x = value(random);
  product(m, n, k, a.data(), b.data(), c.data());
  for (int i = 0; i < m; ++i) {
    for (int j = 0; j < n; ++j) {
      double sum = 0.0;
      for (int d = 0; d < k; ++d) sum += static_cast<double>(a[i * k + d]) * b[j * k + d];
      ASSERT_NEAR(c[i * n + j], sum, 1e-5 * sum) << i << ", " << j;
    }
  }
  // Looked up, OpenBLAS runs on the calling thread (unless the user said
  // otherwise), so a product is the same whatever thread count runs them.
  const auto get = reinterpret_cast<int (*)()>(dlsym(blas, "openblas_get_num_threads"));
  ASSERT_NE(get, nullptr);
  if (!std::getenv("OPENBLAS_NUM_THREADS") && !std::getenv("GOTO_NUM_THREADS")) EXPECT_EQ(get(), 1);
}

}  // namespace
}  // namespace rotation_averaging
