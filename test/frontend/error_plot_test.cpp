#include "rotation_averaging/frontend/eval/error_plot.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdlib>
#include <string>
#include <vector>

#include <opencv2/imgcodecs.hpp>

namespace rotation_averaging {
namespace {

TEST(ErrorPlot, WritesAPngAndRefusesEmptyInput) {
  const std::string path = "/tmp/rotavg_error_plot_test.png";
  std::string error;
  EXPECT_FALSE(WriteErrorPlot(path, "empty", {}, &error));
  EXPECT_FALSE(error.empty());
  ErrorSeries s{"cam", {0.0, 1.0, 2.0, 3.0}, {0.1, 0.5, 0.2, 40.0}};
  ASSERT_TRUE(WriteErrorPlot(path, "four keyframes", {s}, &error)) << error;
  const cv::Mat png = cv::imread(path);
  EXPECT_GT(png.cols, 1000);
  EXPECT_GT(png.rows, 400);
  EXPECT_FALSE(WriteErrorPlot("/nonexistent_dir/x.png", "t", {s}, &error));
}

TEST(ErrorPlot, CdfPlotCountsMissingViewsAsFailures) {
  const std::string path = "/tmp/rotavg_cdf_plot_test.png";
  std::string error;
  EXPECT_FALSE(WriteCdfPlot(path, "empty", {}, 0, 0.0, &error));
  EXPECT_FALSE(error.empty());
  // Two methods over 10 views: one estimates all of them within 1 deg, the
  // other only 5 (the rest missing). At x = 1 deg the first curve reaches
  // the top of the panel and the second stops at half height.
  CdfSeries all{"all", {0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 0.95}};
  CdfSeries half{"half", {0.1, 0.2, 0.3, 0.4, 0.5}};
  ASSERT_TRUE(WriteCdfPlot(path, "two methods", {all, half}, 10, 1.0, &error)) << error;
  const cv::Mat png = cv::imread(path);
  ASSERT_FALSE(png.empty());
  EXPECT_GT(png.cols, 500);
  // Coloured (non-grey) pixels on the right edge of the panel: at the top for
  // the first series, at half height for the second.
  auto coloured_rows = [&](int x) {
    std::vector<int> rows;
    for (int y = 0; y < png.rows; ++y) {
      const cv::Vec3b p = png.at<cv::Vec3b>(y, x);
      if (std::max({p[0], p[1], p[2]}) - std::min({p[0], p[1], p[2]}) > 60) rows.push_back(y);
    }
    return rows;
  };
  const std::vector<int> rows = coloured_rows(70 + 560 - 3);  // kMarginLeft + kPanelWidth, just inside
  ASSERT_GE(rows.size(), 2u);
  const int top = 50 + 30, bottom = 50 + 30 + 400;
  EXPECT_NEAR(rows.front(), top, 4);
  bool half_height = false;
  for (int y : rows) half_height = half_height || std::abs(y - (top + bottom) / 2) <= 4;
  EXPECT_TRUE(half_height);
  // Errors beyond the x range do not draw a rise at the right edge: with the
  // range cut at 0.45 deg, both curves end at 40% (4 of 10 views) there.
  ASSERT_TRUE(WriteCdfPlot(path, "cut", {all, half}, 10, 0.45, &error)) << error;
  const cv::Mat cut = cv::imread(path);
  int highest = bottom;
  for (int y = 0; y < cut.rows; ++y) {
    const cv::Vec3b p = cut.at<cv::Vec3b>(y, 70 + 560 - 3);
    if (std::max({p[0], p[1], p[2]}) - std::min({p[0], p[1], p[2]}) > 60) highest = std::min(highest, y);
  }
  EXPECT_NEAR(highest, bottom - 0.4 * 400, 4);
}

}  // namespace
}  // namespace rotation_averaging
