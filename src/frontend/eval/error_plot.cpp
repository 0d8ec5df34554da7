#include "rotation_averaging/frontend/eval/error_plot.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

namespace rotation_averaging {
namespace {

constexpr int kPanelWidth = 560, kPanelHeight = 400, kMarginLeft = 70, kMarginBottom = 50, kMarginTop = 50;

// A round axis maximum (1, 2 or 5 times a power of ten) at or above `value`.
double NiceCeiling(double value) {
  if (!(value > 0.0)) return 1.0;
  const double p = std::pow(10.0, std::floor(std::log10(value)));
  for (double m : {1.0, 1.2, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0}) {
    if (m * p >= value * (1.0 - 1e-12)) return m * p;
  }
  return 10.0 * p;
}

std::string Format(double v) {
  char buffer[32];
  std::snprintf(buffer, sizeof(buffer), std::abs(v) >= 100 || v == std::floor(v) ? "%.0f" : "%.2g", v);
  return buffer;
}

cv::Scalar Colour(std::size_t k) {
  static const cv::Scalar kColours[] = {{200, 90, 30},  {40, 120, 230}, {60, 160, 60}, {40, 40, 200},
                                        {170, 80, 160}, {30, 170, 200}, {120, 120, 120}, {150, 150, 0}};
  return kColours[k % (sizeof(kColours) / sizeof(kColours[0]))];
}

struct Panel {
  cv::Rect area;
  double x_max = 1.0, y_max = 1.0;
  cv::Point Map(double x, double y) const {
    const double fx = std::clamp(x / x_max, 0.0, 1.0), fy = std::clamp(y / y_max, 0.0, 1.0);
    return {area.x + static_cast<int>(std::lround(fx * area.width)),
            area.y + area.height - static_cast<int>(std::lround(fy * area.height))};
  }
};

void DrawAxes(cv::Mat* canvas, const Panel& p, const std::string& x_label, const std::string& y_label,
              const std::string& title) {
  const cv::Scalar black(0, 0, 0), grid(225, 225, 225);
  for (int k = 0; k <= 5; ++k) {
    const double x = p.x_max * k / 5.0, y = p.y_max * k / 5.0;
    cv::line(*canvas, p.Map(x, 0), p.Map(x, p.y_max), grid, 1);
    cv::line(*canvas, p.Map(0, y), p.Map(p.x_max, y), grid, 1);
    cv::putText(*canvas, Format(x), p.Map(x, 0) + cv::Point(-10, 20), cv::FONT_HERSHEY_SIMPLEX, 0.45, black, 1,
                cv::LINE_AA);
    cv::putText(*canvas, Format(y), p.Map(0, y) + cv::Point(-45, 5), cv::FONT_HERSHEY_SIMPLEX, 0.45, black, 1,
                cv::LINE_AA);
  }
  cv::rectangle(*canvas, p.area, black, 1);
  cv::putText(*canvas, x_label, cv::Point(p.area.x + p.area.width / 2 - 60, p.area.y + p.area.height + 42),
              cv::FONT_HERSHEY_SIMPLEX, 0.5, black, 1, cv::LINE_AA);
  cv::putText(*canvas, y_label, cv::Point(p.area.x - 60, p.area.y - 12), cv::FONT_HERSHEY_SIMPLEX, 0.5, black, 1,
              cv::LINE_AA);
  cv::putText(*canvas, title, cv::Point(p.area.x + 80, p.area.y - 30), cv::FONT_HERSHEY_SIMPLEX, 0.55, black, 1,
              cv::LINE_AA);
}

void DrawCdf(cv::Mat* canvas, const Panel& p, std::vector<double> errors, const cv::Scalar& colour, int thickness,
             std::size_t total = 0) {
  if (errors.empty()) return;
  std::sort(errors.begin(), errors.end());
  const double n = static_cast<double>(std::max(total, errors.size()));
  cv::Point previous = p.Map(0.0, 0.0);
  double reached = 0.0;  // fraction of views with error up to the right edge
  for (std::size_t k = 0; k < errors.size() && errors[k] <= p.x_max; ++k) {
    reached = static_cast<double>(k + 1) / n;
    const cv::Point step = p.Map(errors[k], static_cast<double>(k) / n);
    const cv::Point up = p.Map(errors[k], reached);
    cv::line(*canvas, previous, step, colour, thickness, cv::LINE_AA);
    cv::line(*canvas, step, up, colour, thickness, cv::LINE_AA);
    previous = up;
  }
  // Flat to the right edge: errors beyond it do not raise the curve here.
  cv::line(*canvas, previous, p.Map(p.x_max, reached), colour, thickness, cv::LINE_AA);
}

bool Write(const std::string& path, const cv::Mat& canvas, std::string* error) {
  bool written = false;
  try {
    written = cv::imwrite(path, canvas);
  } catch (const cv::Exception& e) {
    if (error) *error = e.what();
    return false;
  }
  if (!written && error) *error = "cannot write " + path;
  return written;
}

}  // namespace

bool WriteErrorPlot(const std::string& path, const std::string& title, const std::vector<ErrorSeries>& series,
                    std::string* error) {
  std::vector<double> all_errors;
  double t_max = 0.0;
  for (const ErrorSeries& s : series) {
    for (std::size_t k = 0; k < s.error_deg.size() && k < s.time_s.size(); ++k) {
      if (!std::isfinite(s.error_deg[k]) || !std::isfinite(s.time_s[k])) continue;
      all_errors.push_back(s.error_deg[k]);
      t_max = std::max(t_max, s.time_s[k]);
    }
  }
  if (all_errors.empty()) {
    if (error) *error = "no finite errors to plot";
    return false;
  }
  std::vector<double> sorted = all_errors;
  std::sort(sorted.begin(), sorted.end());
  // The 99th percentile sets the scale so that one wild keyframe does not
  // flatten the rest (points beyond are drawn on the top edge).
  const double e99 = sorted[std::min(sorted.size() - 1, static_cast<std::size_t>(0.99 * sorted.size()))];
  const int width = 2 * (kMarginLeft + kPanelWidth) + 70, height = kMarginTop + kPanelHeight + kMarginBottom + 40;
  cv::Mat canvas(height, width, CV_8UC3, cv::Scalar(255, 255, 255));
  cv::putText(canvas, title, cv::Point(kMarginLeft, 28), cv::FONT_HERSHEY_SIMPLEX, 0.7, cv::Scalar(0, 0, 0), 1,
              cv::LINE_AA);

  Panel over_time{cv::Rect(kMarginLeft, kMarginTop + 30, kPanelWidth, kPanelHeight), NiceCeiling(t_max),
                  NiceCeiling(e99 * 1.05)};
  DrawAxes(&canvas, over_time, "keyframe capture time (s)", "error (deg)", "orientation error per keyframe");
  Panel cdf{cv::Rect(2 * kMarginLeft + kPanelWidth + 40, kMarginTop + 30, kPanelWidth, kPanelHeight),
            NiceCeiling(e99 * 1.05), 1.0};
  DrawAxes(&canvas, cdf, "error threshold (deg)", "fraction below", "cumulative distribution");

  int legend_y = over_time.area.y + 18;
  for (std::size_t k = 0; k < series.size(); ++k) {
    const ErrorSeries& s = series[k];
    std::vector<std::pair<double, double>> points;
    for (std::size_t i = 0; i < s.error_deg.size() && i < s.time_s.size(); ++i) {
      if (std::isfinite(s.error_deg[i]) && std::isfinite(s.time_s[i])) points.emplace_back(s.time_s[i], s.error_deg[i]);
    }
    std::sort(points.begin(), points.end());
    for (std::size_t i = 0; i < points.size(); ++i) {
      const cv::Point at = over_time.Map(points[i].first, points[i].second);
      if (i > 0) cv::line(canvas, over_time.Map(points[i - 1].first, points[i - 1].second), at, Colour(k), 1, cv::LINE_AA);
      cv::circle(canvas, at, 3, Colour(k), cv::FILLED, cv::LINE_AA);
    }
    std::vector<double> errors;
    for (const auto& p : points) errors.push_back(p.second);
    DrawCdf(&canvas, cdf, errors, Colour(k), 1);
    cv::putText(canvas, s.label + " (" + std::to_string(points.size()) + ")",
                cv::Point(over_time.area.x + 10, legend_y), cv::FONT_HERSHEY_SIMPLEX, 0.45, Colour(k), 1, cv::LINE_AA);
    legend_y += 18;
  }
  if (series.size() > 1) {
    DrawCdf(&canvas, cdf, all_errors, cv::Scalar(0, 0, 0), 2);
    cv::putText(canvas, "all keyframes", cv::Point(cdf.area.x + cdf.area.width - 130, cdf.area.y + cdf.area.height - 12),
                cv::FONT_HERSHEY_SIMPLEX, 0.45, cv::Scalar(0, 0, 0), 1, cv::LINE_AA);
  }
  return Write(path, canvas, error);
}

bool WriteCdfPlot(const std::string& path, const std::string& title, const std::vector<CdfSeries>& series,
                  std::size_t num_views, double x_max_deg, std::string* error) {
  std::vector<std::vector<double>> finite(series.size());  // each series' finite errors, sorted
  std::vector<double> p90;
  for (std::size_t k = 0; k < series.size(); ++k) {
    std::vector<double>& e = finite[k];
    for (double v : series[k].error_deg)
      if (std::isfinite(v)) e.push_back(v);
    if (e.empty()) continue;
    std::sort(e.begin(), e.end());
    p90.push_back(e[std::min(e.size() - 1, static_cast<std::size_t>(0.9 * e.size()))]);
  }
  if (p90.empty()) {
    if (error) *error = "no finite errors to plot";
    return false;
  }
  // Default x range: the median method's 90th percentile, so that the curves
  // separate where they differ.
  std::sort(p90.begin(), p90.end());
  const double x_max = x_max_deg > 0.0 ? x_max_deg : NiceCeiling(1.5 * p90[p90.size() / 2]);
  const int width = kMarginLeft + kPanelWidth + 60, height = kMarginTop + kPanelHeight + kMarginBottom + 40;
  cv::Mat canvas(height, width, CV_8UC3, cv::Scalar(255, 255, 255));
  cv::putText(canvas, title, cv::Point(20, 28), cv::FONT_HERSHEY_SIMPLEX, 0.6, cv::Scalar(0, 0, 0), 1, cv::LINE_AA);
  Panel cdf{cv::Rect(kMarginLeft, kMarginTop + 30, kPanelWidth, kPanelHeight), x_max, 1.0};
  DrawAxes(&canvas, cdf, "rotation error threshold (deg)", "fraction of views below", "");
  int legend_y = cdf.area.y + cdf.area.height - 12 - 18 * static_cast<int>(series.size() - 1);
  for (std::size_t k = 0; k < series.size(); ++k) {
    DrawCdf(&canvas, cdf, finite[k], Colour(k), 2, num_views);
    cv::putText(canvas, series[k].label, cv::Point(cdf.area.x + cdf.area.width / 2 - 20, legend_y),
                cv::FONT_HERSHEY_SIMPLEX, 0.42, Colour(k), 1, cv::LINE_AA);
    legend_y += 18;
  }
  return Write(path, canvas, error);
}

bool WriteLinePlot(const std::string& path, const std::string& title, const std::string& x_label,
                   const std::string& y_label, const std::vector<LineSeries>& series, std::string* error) {
  std::vector<double> ys;
  double x_max = 0.0;
  for (const LineSeries& s : series) {
    for (std::size_t i = 0; i < s.x.size() && i < s.y.size(); ++i) {
      if (!std::isfinite(s.x[i]) || !std::isfinite(s.y[i])) continue;
      ys.push_back(s.y[i]);
      x_max = std::max(x_max, s.x[i]);
    }
  }
  if (ys.empty()) {
    if (error) *error = "no finite points to plot";
    return false;
  }
  std::sort(ys.begin(), ys.end());
  const double y99 = ys[std::min(ys.size() - 1, static_cast<std::size_t>(0.99 * ys.size()))];
  const int width = kMarginLeft + kPanelWidth + 60, height = kMarginTop + kPanelHeight + kMarginBottom + 40;
  cv::Mat canvas(height, width, CV_8UC3, cv::Scalar(255, 255, 255));
  cv::putText(canvas, title, cv::Point(20, 28), cv::FONT_HERSHEY_SIMPLEX, 0.6, cv::Scalar(0, 0, 0), 1, cv::LINE_AA);
  Panel panel{cv::Rect(kMarginLeft, kMarginTop + 30, kPanelWidth, kPanelHeight), NiceCeiling(x_max),
              NiceCeiling(y99 * 1.05)};
  DrawAxes(&canvas, panel, x_label, y_label, "");
  int legend_y = panel.area.y + 18;
  for (std::size_t k = 0; k < series.size(); ++k) {
    const LineSeries& s = series[k];
    bool have_previous = false;
    cv::Point previous;
    for (std::size_t i = 0; i < s.x.size() && i < s.y.size(); ++i) {
      if (!std::isfinite(s.x[i]) || !std::isfinite(s.y[i])) continue;
      const cv::Point at = panel.Map(s.x[i], s.y[i]);
      if (have_previous) cv::line(canvas, previous, at, Colour(k), 1, cv::LINE_AA);
      previous = at;
      have_previous = true;
    }
    cv::putText(canvas, s.label, cv::Point(panel.area.x + 10, legend_y), cv::FONT_HERSHEY_SIMPLEX, 0.45, Colour(k), 1,
                cv::LINE_AA);
    legend_y += 18;
  }
  return Write(path, canvas, error);
}

}  // namespace rotation_averaging
