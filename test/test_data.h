// Where the tests find the real third-party data: $ROTAVG_DATA_DIR, else the
// ../shared/data folder beside the repository (compiled in). Tests that need
// it skip with a message when it is absent.
#ifndef ROTATION_AVERAGING_TEST_TEST_DATA_H_
#define ROTATION_AVERAGING_TEST_TEST_DATA_H_

#include <cstdlib>
#include <string>

namespace rotation_averaging {

inline std::string SharedDataPath(const std::string& relative) {
  const char* env = std::getenv("ROTAVG_DATA_DIR");
  return std::string(env ? env : ROTAVG_DATA_DIR) + "/" + relative;
}

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_TEST_TEST_DATA_H_
