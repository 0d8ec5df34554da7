// Small helpers shared by the benchmark tools that write markdown reports.
#ifndef ROTATION_AVERAGING_TOOLS_REPORT_H_
#define ROTATION_AVERAGING_TOOLS_REPORT_H_

#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

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

// `digits` significant digits (costs, whose magnitude varies by graph).
inline std::string Significant(double v, int digits) {
  std::ostringstream s;
  s << std::setprecision(digits) << v;
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

// Runs this program again (`self` = argv[0]) with `args` in a child process,
// for a figure of its own: what it writes to stdout goes to `out` (may be
// null), its peak resident memory (MiB, from wait4's rusage) to `peak_mib`
// and its CPU time (user + system, seconds) to `cpu_s` (both may be null).
// False if the child did not exit with status 0.
inline bool RunChildProcess(const char* self, const std::vector<std::string>& args, std::string* out,
                            double* peak_mib, double* cpu_s = nullptr) {
  int fds[2];
  if (pipe(fds) != 0) return false;
  const pid_t pid = fork();
  if (pid == 0) {
    dup2(fds[1], STDOUT_FILENO);
    close(fds[0]);
    close(fds[1]);
    std::vector<char*> argv{const_cast<char*>(self)};
    for (const std::string& a : args) argv.push_back(const_cast<char*>(a.c_str()));
    argv.push_back(nullptr);
    execv(self, argv.data());
    _exit(127);
  }
  close(fds[1]);
  std::string text;
  char buffer[256];
  for (ssize_t got; (got = read(fds[0], buffer, sizeof(buffer))) > 0;) text.append(buffer, static_cast<std::size_t>(got));
  close(fds[0]);
  int status = 0;
  struct rusage usage {};
  if (pid < 0 || wait4(pid, &status, 0, &usage) < 0 || !WIFEXITED(status) || WEXITSTATUS(status) != 0) return false;
  if (out) *out = text;
  if (peak_mib) *peak_mib = usage.ru_maxrss / 1024.0;  // ru_maxrss is in KiB on Linux
  if (cpu_s) {
    *cpu_s = usage.ru_utime.tv_sec + 1e-6 * usage.ru_utime.tv_usec + usage.ru_stime.tv_sec +
             1e-6 * usage.ru_stime.tv_usec;
  }
  return true;
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
