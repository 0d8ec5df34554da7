// PNG figure of orientation errors, drawn with OpenCV (no plotting library
// needed): left, the error of each keyframe against its capture time, one
// colour per series (camera); right, the cumulative distribution of the
// errors (fraction of keyframes with error below x), per series and for all.
#ifndef ROTATION_AVERAGING_FRONTEND_EVAL_ERROR_PLOT_H_
#define ROTATION_AVERAGING_FRONTEND_EVAL_ERROR_PLOT_H_

#include <string>
#include <vector>

namespace rotation_averaging {

struct ErrorSeries {
  std::string label;
  std::vector<double> time_s;     // x of the left panel
  std::vector<double> error_deg;  // same length
};

// Writes the figure; false (with `error`) if there is nothing to draw or the
// file cannot be written.
bool WriteErrorPlot(const std::string& path, const std::string& title, const std::vector<ErrorSeries>& series,
                    std::string* error);

// One panel, like the paper's figure: for each method, the fraction of views
// whose error is below x (the recall curve whose area gives the AUC). Views a
// method did not estimate count as failures: `num_views` is the total (0 =
// the size of each series). x runs to `x_max_deg` (0 = chosen from the data).
struct CdfSeries {
  std::string label;
  std::vector<double> error_deg;
};
bool WriteCdfPlot(const std::string& path, const std::string& title, const std::vector<CdfSeries>& series,
                  std::size_t num_views, double x_max_deg, std::string* error);

// One panel of lines, y against x (e.g. the front end's cost per keyframe
// against the keyframe count). The y axis is scaled to the 99th percentile.
struct LineSeries {
  std::string label;
  std::vector<double> x, y;  // same length
};
bool WriteLinePlot(const std::string& path, const std::string& title, const std::string& x_label,
                   const std::string& y_label, const std::vector<LineSeries>& series, std::string* error);

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_FRONTEND_EVAL_ERROR_PLOT_H_
