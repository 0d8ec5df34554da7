#include "rotation_averaging/util/time_distribution.h"

#include <gtest/gtest.h>

namespace rotation_averaging {
namespace {

TEST(TimeDistribution, EmptyHasNoQuantilesAndSaysSo) {
  const TimeDistribution t;
  EXPECT_EQ(t.Count(), 0u);
  EXPECT_EQ(t.Median(), 0.0);
  EXPECT_EQ(t.P95(), 0.0);
  EXPECT_EQ(t.DescribeMs(), "none");
}

TEST(TimeDistribution, QuantilesAreNearestRankOverTheTimes) {
  TimeDistribution t;
  // 1..100 ms in a shuffled order: the median is 50 ms and the 95th
  // percentile 95 ms by nearest rank, whatever the order of arrival.
  for (int k = 0; k < 100; ++k) t.Add(1e-3 * (1 + (k * 37) % 100));
  EXPECT_EQ(t.Count(), 100u);
  EXPECT_NEAR(t.Total(), 1e-3 * 5050, 1e-12);
  EXPECT_DOUBLE_EQ(t.Median(), 0.050);
  EXPECT_DOUBLE_EQ(t.P95(), 0.095);
  EXPECT_DOUBLE_EQ(t.Quantile(0.0), 0.001);
  EXPECT_DOUBLE_EQ(t.Quantile(1.0), 0.100);
  EXPECT_EQ(t.DescribeMs(), "median 50.00 ms, p95 95.00 ms (of 100)");
}

TEST(TimeDistribution, AFewSlowTimesShowInThe95thPercentileNotTheMedian) {
  TimeDistribution t;
  // Six slow times in a hundred, the first ones: above the 94th percentile.
  for (int k = 0; k < 100; ++k) t.Add(k < 6 ? 0.200 : 0.002);
  EXPECT_DOUBLE_EQ(t.Median(), 0.002);
  EXPECT_DOUBLE_EQ(t.P95(), 0.200);
  EXPECT_DOUBLE_EQ(t.Quantile(0.94), 0.002);
}

TEST(TimeDistribution, TheWindowKeepsTheMostRecentTimesAndCountsAll) {
  TimeDistribution t(4);
  for (double s : {9.0, 9.0, 9.0, 9.0, 1.0, 2.0, 3.0, 4.0}) t.Add(s);
  EXPECT_EQ(t.Count(), 8u);
  EXPECT_EQ(t.Held(), 4u);
  EXPECT_DOUBLE_EQ(t.Total(), 46.0);
  EXPECT_DOUBLE_EQ(t.Last(), 4.0);
  EXPECT_DOUBLE_EQ(t.Median(), 2.0);  // of 1, 2, 3, 4: the old 9s are gone
  EXPECT_DOUBLE_EQ(t.Quantile(1.0), 4.0);
}

}  // namespace
}  // namespace rotation_averaging
