#include "rotation_averaging/util/stream_gaps.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdint>
#include <string>
#include <vector>

namespace rotation_averaging {
namespace {

constexpr std::int64_t kPeriodNs = 50'000'000;  // 20 Hz

// A 20 Hz stream whose stamps jitter by up to 4 ms, without the frames in `lost`.
void Feed(StreamGaps* gaps, const std::string& camera, int frames, const std::vector<int>& lost) {
  for (int i = 0; i < frames; ++i) {
    if (std::find(lost.begin(), lost.end(), i) != lost.end()) continue;
    gaps->Observe(camera, 1'000'000'000'000 + i * kPeriodNs + ((i * 7919) % 9 - 4) * 1'000'000);
  }
}

TEST(StreamGaps, ASteadyStreamWithJitterMissesNothing) {
  StreamGaps gaps;
  Feed(&gaps, "cam0", 200, {});
  EXPECT_EQ(gaps.Missing(), 0u);
  EXPECT_NEAR(gaps.PeriodS("cam0"), 0.05, 0.005);
}

TEST(StreamGaps, LostFramesAreCountedPerCamera) {
  StreamGaps gaps;
  // One frame lost at 40, three in a row at 100-102, one at 150.
  Feed(&gaps, "cam0", 200, {40, 100, 101, 102, 150});
  Feed(&gaps, "cam1", 200, {60});
  EXPECT_EQ(gaps.Missing("cam0"), 5u);
  EXPECT_EQ(gaps.Missing("cam1"), 1u);
  EXPECT_EQ(gaps.Missing(), 6u);
  EXPECT_EQ(gaps.Missing("cam2"), 0u);
}

TEST(StreamGaps, NothingIsCountedBeforeThePeriodIsKnown) {
  StreamGaps gaps;
  // The third frame is lost before eight gaps have been seen.
  Feed(&gaps, "cam0", 40, {2});
  EXPECT_EQ(gaps.Missing(), 0u);
}

TEST(StreamGaps, StampsThatDoNotAdvanceAreIgnored) {
  StreamGaps gaps;
  Feed(&gaps, "cam0", 20, {});
  EXPECT_EQ(gaps.Observe("cam0", 1'000'000'000'000), 0u);  // back in time
  EXPECT_EQ(gaps.Observe("cam0", 1'000'000'000'000 + 19 * kPeriodNs + 10 * kPeriodNs), 9u);
  EXPECT_EQ(gaps.Missing(), 9u);
}

TEST(StreamGaps, APauseIsNotLostFrames) {
  StreamGaps gaps;
  Feed(&gaps, "cam0", 20, {});
  const std::int64_t last = 1'000'000'000'000 + 19 * kPeriodNs;
  EXPECT_EQ(gaps.Observe("cam0", last + 3'000'000'000), 0u);  // 3 s later
  EXPECT_EQ(gaps.Observe("cam0", last + 3'000'000'000 + 3 * kPeriodNs), 2u);  // the period is still known
}

TEST(StreamGaps, ResetForgetsTheStreamsButKeepsTheCount) {
  StreamGaps gaps;
  Feed(&gaps, "cam0", 50, {30});
  ASSERT_EQ(gaps.Missing(), 1u);
  gaps.Reset();
  EXPECT_EQ(gaps.PeriodS("cam0"), 0.0);
  // A stream that resumes minutes later is not counted as lost frames.
  EXPECT_EQ(gaps.Observe("cam0", 2'000'000'000'000), 0u);
  EXPECT_EQ(gaps.Missing(), 1u);
}

}  // namespace
}  // namespace rotation_averaging
