#include "rotation_averaging/util/freed_memory.h"

#include <cstdlib>
#include <cstring>
#include <initializer_list>

#if defined(__GLIBC__)
#include <malloc.h>
#endif

namespace rotation_averaging {

bool AllocatorSetByTheUser() {
  const char* tunables = std::getenv("GLIBC_TUNABLES");
  if (tunables && std::strstr(tunables, "glibc.malloc.")) return true;
  for (const char* name : {"MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "MALLOC_TOP_PAD_", "MALLOC_MMAP_MAX_"}) {
    if (std::getenv(name)) return true;
  }
  return false;
}

bool KeepFreedMemoryForReuse() {
#if defined(__GLIBC__)
  if (AllocatorSetByTheUser()) return false;
  // Setting either ends glibc's own adjustment of both, so both are set.
  return mallopt(M_MMAP_THRESHOLD, static_cast<int>(kHeapBlockLimit)) == 1 &&
         mallopt(M_TRIM_THRESHOLD, static_cast<int>(kKeptFreeMemory)) == 1;
#else
  return false;
#endif
}

}  // namespace rotation_averaging
