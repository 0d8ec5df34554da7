// libFuzzer target for every file reader: the first byte picks the reader,
// the rest is the file's content. The keyframe database's checksum and size
// are set to match the mutated contents before it is read (and its
// vocabulary fingerprint is taken as the reader's), so that the fuzzer
// reaches the parsing behind them. Built and run by scripts/fuzz.sh (clang,
// -fsanitize=fuzzer,address,undefined). A reader may refuse any input with an
// error; it must never crash, hang or touch memory it does not own.
#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <fstream>
#include <map>
#include <string>

#define XXH_INLINE_ALL
#include <xxhash.h>

#include <cstring>
#include <vector>

#include "rotation_averaging/core/io/graph_io.h"
#include "rotation_averaging/core/io/orientation_io.h"
#include "rotation_averaging/core/controllers/rig_model.h"
#include "rotation_averaging/frontend/controllers/keyframe_refiner.h"
#include "rotation_averaging/frontend/io/keyframe_database.h"

namespace ra = rotation_averaging;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size < 1) return 0;
  static const std::string dir = [] {
    char pattern[] = "/tmp/rotavg_fuzz_XXXXXX";
    return std::string(mkdtemp(pattern));
  }();
  const std::string path = dir + "/input";
  const int reader = data[0] % 12;
  std::vector<char> content(data + 1, data + size);
  std::uint64_t fingerprint = 0;
  constexpr std::size_t kHeader = 44;  // magic 16, version 4, fingerprint 8, size 8, checksum 8
  if (reader == 10 && content.size() >= kHeader) {
    std::memcpy(&fingerprint, &content[20], 8);
    const std::uint64_t payload = content.size() - kHeader;
    const std::uint64_t sum = XXH3_64bits(content.data() + kHeader, payload);
    std::memcpy(&content[28], &payload, 8);
    std::memcpy(&content[36], &sum, 8);
  }
  {
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    out.write(content.data(), static_cast<std::streamsize>(content.size()));
  }
  ra::ViewGraph graph;
  ra::NamedOrientations orientations;
  std::map<ra::ViewId, Eigen::Matrix3d> saved_orientations;
  std::string error;
  switch (reader) {
    case 0: ra::ReadOneDsfm(path, "", &graph); break;
    case 1: ra::ReadG2o(path, &graph); break;
    case 2: ra::ReadToro(path, &graph); break;
    case 3: ra::ReadIRotAvg(path, &graph); break;
    case 4: ra::ReadRotavgGraph(path, &graph, &saved_orientations); break;
    case 5: ra::ReadOrientationsCsv(path, &orientations); break;
    case 6: ra::ReadColmapGroundTruth(path, &orientations); break;
    case 7: ra::ReadChainedGroundTruth(path, ra::GraphFormat::kG2o, &orientations); break;
    case 9: {
      ra::RigModel rig(ra::RigModelOptions{});
      rig.Load(path, &error);
      break;
    }
    case 10: {
      ra::KeyframeDatabase database;
      ra::ReadKeyframeDatabase(path, fingerprint, &database, &error);
      break;
    }
    case 11: {
      std::map<ra::KeyframeKey, Eigen::Matrix3d> corrections;
      ra::KeyframeRefiner::ReadCorrections(path, &corrections, &error);
      break;
    }
    default: ra::ReadViewGraph(path, ra::GraphFormat::kAuto, &graph); break;
  }
  return 0;
}
