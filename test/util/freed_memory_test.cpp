#include "rotation_averaging/util/freed_memory.h"

#include <gtest/gtest.h>
#include <malloc.h>

#include <cstdlib>
#include <cstring>

namespace rotation_averaging {
namespace {

bool Sanitized() {
#if defined(__SANITIZE_ADDRESS__)
  return true;
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
  return true;
#else
  return false;
#endif
#else
  return false;
#endif
}

// A block of the size of SIFT's scale-space layers on a large image comes
// from the heap and, freed, stays with the process for the next image. By
// glibc's default it is mapped on its own (it starts at a 128 KiB
// threshold) and unmapped when freed: its pages faulted in again next time.
TEST(FreedMemory, AFreedLargeBlockStaysWithTheProcess) {
  if (Sanitized()) GTEST_SKIP() << "a sanitizer's allocator replaces glibc's";
  if (AllocatorSetByTheUser()) {
    EXPECT_FALSE(KeepFreedMemoryForReuse());  // the user's settings are left alone
    GTEST_SKIP() << "the allocator's settings are the user's here";
  }
  ASSERT_TRUE(KeepFreedMemoryForReuse());
  const std::size_t size = std::size_t{24} << 20;
  const struct mallinfo2 before = mallinfo2();
  char* block = static_cast<char*>(std::malloc(size));
  ASSERT_NE(block, nullptr);
  std::memset(block, 1, size);
  const struct mallinfo2 held = mallinfo2();
  EXPECT_EQ(held.hblkhd, before.hblkhd) << "the block was mapped on its own";
  std::free(block);
  const struct mallinfo2 after = mallinfo2();
  EXPECT_GE(after.fordblks, before.fordblks + size) << "the freed block went back to the system";
}

// A MALLOC_*_ variable the user set is the user's setting: it is left alone.
TEST(FreedMemory, AUsersAllocatorVariableIsLeftAlone) {
  if (AllocatorSetByTheUser()) GTEST_SKIP() << "the allocator's settings are the user's here";
  setenv("MALLOC_TOP_PAD_", "0", 1);
  EXPECT_TRUE(AllocatorSetByTheUser());
  EXPECT_FALSE(KeepFreedMemoryForReuse());
  unsetenv("MALLOC_TOP_PAD_");
  EXPECT_FALSE(AllocatorSetByTheUser());
}

}  // namespace
}  // namespace rotation_averaging
