// Small helpers shared by the benchmark tools that write markdown reports.
#ifndef ROTATION_AVERAGING_TOOLS_REPORT_H_
#define ROTATION_AVERAGING_TOOLS_REPORT_H_

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <sstream>
#include <string>
#include <vector>

#include "rotation_averaging/estimators/rotation_averaging.h"

namespace rotation_averaging {

// The paper's loss x weighting comparison, in the paper's order.
inline const std::vector<LossType>& PaperTableLosses() {
  static const std::vector<LossType> losses = {LossType::kSquared, LossType::kHuber,  LossType::kCauchy,
                                               LossType::kGemanMcClure, LossType::kTukey, LossType::kLHalf,
                                               LossType::kSoftL1, LossType::kMagsac};
  return losses;
}
inline const std::vector<EdgeWeighting>& PaperTableWeightings() {
  static const std::vector<EdgeWeighting> weightings = {EdgeWeighting::kNone, EdgeWeighting::kInliers,
                                                        EdgeWeighting::kTrace, EdgeWeighting::kFrobenius,
                                                        EdgeWeighting::kCovariance};
  return weightings;
}

inline std::string Fixed(double v, int digits) {
  std::ostringstream s;
  s << std::fixed << std::setprecision(digits) << v;
  return s.str();
}

// Median (the mean of the two middle values for an even count); NaN if empty.
inline double Median(std::vector<double> v) {
  if (v.empty()) return NAN;
  std::sort(v.begin(), v.end());
  return v.size() % 2 ? v[v.size() / 2] : 0.5 * (v[v.size() / 2 - 1] + v[v.size() / 2]);
}

// The command line as typed, for the "reproduce with" line of a report.
inline std::string CommandLine(const std::string& program, int argc, char** argv) {
  std::string command = program;
  for (int k = 1; k < argc; ++k) command += std::string(" ") + argv[k];
  return command;
}

// Prints the report and writes it to `path` (creating its folder).
inline void WriteReport(const std::string& path, const std::string& text) {
  std::cout << text;
  if (path.empty()) return;
  std::error_code ec;
  if (std::filesystem::path(path).has_parent_path()) {
    std::filesystem::create_directories(std::filesystem::path(path).parent_path(), ec);
  }
  std::ofstream(path) << text;
  std::cerr << "wrote " << path << "\n";
}

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_TOOLS_REPORT_H_
