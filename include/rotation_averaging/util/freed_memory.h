// The C library's allocator told to keep freed memory for reuse. By default
// glibc serves every block above a threshold that starts at 128 KiB with a
// fresh mapping, and gives freed memory at the top of a heap back to the
// system beyond twice that threshold. The image path allocates and frees
// large buffers every image: the Lucas-Kanade pyramids of each image (a few
// MiB), and per keyframe SIFT's scale space of the doubled image (about
// 70 MiB). Each came back as new pages, and every page's first touch is a
// page fault: half a million of them on a 30 s two-camera stream, where
// threads fault at once, and nearly half of SIFT's time (docs/decisions.md,
// "Freed memory kept for reuse").
#ifndef ROTATION_AVERAGING_UTIL_FREED_MEMORY_H_
#define ROTATION_AVERAGING_UTIL_FREED_MEMORY_H_

#include <cstddef>

namespace rotation_averaging {

// Blocks up to kHeapBlockLimit come from the heaps (larger ones are still
// mapped on their own), and up to kKeptFreeMemory of freed memory at the top
// of a heap stays with the process. For the programs' main(): the setting
// is the process's. Leaves a setting the user made (GLIBC_TUNABLES with a
// glibc.malloc tunable, or a MALLOC_*_ variable) alone. True if it set
// them; false with the user's settings, or without glibc.
constexpr std::size_t kHeapBlockLimit = std::size_t{32} << 20;   // glibc's largest
constexpr std::size_t kKeptFreeMemory = std::size_t{256} << 20;  // several keyframes' SIFT
bool KeepFreedMemoryForReuse();
// The user set the allocator: GLIBC_TUNABLES holds a glibc.malloc tunable,
// or a MALLOC_*_ variable that sets a threshold, the top pad or the count
// of mappings is set.
bool AllocatorSetByTheUser();

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_UTIL_FREED_MEMORY_H_
