// Where the tests find the real third-party data: $ROTAVG_DATA_DIR, else the
// ../shared/data folder beside the repository (compiled in). A test that needs
// it starts with ROTAVG_REQUIRE_SHARED_DATA(path): where the data is absent it
// skips with a message, unless ROTAVG_REQUIRE_DATA=1 (scripts/test.sh sets it
// under CI, which always has the data), where it fails. These tests carry the
// ctest label `data` (ctest -LE data runs the others).
#ifndef ROTATION_AVERAGING_TEST_COMMON_TEST_DATA_H_
#define ROTATION_AVERAGING_TEST_COMMON_TEST_DATA_H_

#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <string>

namespace rotation_averaging {

inline std::string SharedDataPath(const std::string& relative) {
  const char* env = std::getenv("ROTAVG_DATA_DIR");
  return std::string(env ? env : ROTAVG_DATA_DIR) + "/" + relative;
}

inline bool SharedDataRequired() {
  const char* env = std::getenv("ROTAVG_REQUIRE_DATA");
  return env != nullptr && std::strcmp(env, "1") == 0;
}

}  // namespace rotation_averaging

#define ROTAVG_REQUIRE_SHARED_DATA(path)                                                               \
  if (!std::filesystem::exists(path)) {                                                               \
    if (::rotation_averaging::SharedDataRequired()) {                                                 \
      FAIL() << "shared data absent: " << (path) << " (ROTAVG_REQUIRE_DATA=1; set ROTAVG_DATA_DIR)"; \
    }                                                                                                 \
    GTEST_SKIP() << "shared data absent: " << (path) << " (set ROTAVG_DATA_DIR)";                     \
  }

#endif  // ROTATION_AVERAGING_TEST_COMMON_TEST_DATA_H_
