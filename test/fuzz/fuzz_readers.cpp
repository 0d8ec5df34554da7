// libFuzzer target for every file reader: the first byte picks the reader,
// the rest is the file's content. Built and run by scripts/fuzz.sh (clang,
// -fsanitize=fuzzer,address,undefined). A reader may refuse any input with an
// error; it must never crash, hang or touch memory it does not own.
#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <fstream>
#include <string>

#include "rotation_averaging/core/io/graph_io.h"
#include "rotation_averaging/core/io/orientation_io.h"

namespace ra = rotation_averaging;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size < 1) return 0;
  static const std::string dir = [] {
    char pattern[] = "/tmp/rotavg_fuzz_XXXXXX";
    return std::string(mkdtemp(pattern));
  }();
  const std::string path = dir + "/input";
  {
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    out.write(reinterpret_cast<const char*>(data + 1), static_cast<std::streamsize>(size - 1));
  }
  ra::ViewGraph graph;
  ra::NamedOrientations orientations;
  switch (data[0] % 9) {
    case 0: ra::ReadOneDsfm(path, "", &graph); break;
    case 1: ra::ReadG2o(path, &graph); break;
    case 2: ra::ReadToro(path, &graph); break;
    case 3: ra::ReadIRotAvg(path, &graph); break;
    case 4: ra::ReadRotavgGraph(path, &graph); break;
    case 5: ra::ReadOrientationsCsv(path, &orientations); break;
    case 6: ra::ReadColmapGroundTruth(path, &orientations); break;
    case 7: ra::ReadChainedGroundTruth(path, ra::GraphFormat::kG2o, &orientations); break;
    default: ra::ReadViewGraph(path, ra::GraphFormat::kAuto, &graph); break;
  }
  return 0;
}
