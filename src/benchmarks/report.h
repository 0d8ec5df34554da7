// Small helpers shared by the benchmark tools that write markdown reports.
#ifndef ROTATION_AVERAGING_SRC_BENCHMARKS_REPORT_H_
#define ROTATION_AVERAGING_SRC_BENCHMARKS_REPORT_H_

#include <spawn.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <map>
#include <set>
#include <stdexcept>
#include <sstream>
#include <string>
#include <vector>

#include "rotation_averaging/core/estimators/rotation_averaging.h"

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

// The peak resident memory of this process (VmHWM of /proc/self/status),
// printed by a child run as its last line for RunChildProcess. The child's
// rusage cannot give it: Linux carries ru_maxrss over from the parent's
// memory at fork, through exec, so every child of a benchmark that holds
// 45 MiB would report at least that.
inline void PrintOwnPeakMemory() {
  std::ifstream status("/proc/self/status");
  std::string line;
  while (std::getline(status, line)) {
    if (line.rfind("VmHWM:", 0) == 0) std::cout << "\npeak_rss_kib " << std::atol(line.c_str() + 6) << std::endl;
  }
}

// Runs this program again (`self` = argv[0]) with `args` in a child process,
// for a figure of its own: what it writes to stdout goes to `out` (may be
// null), its peak resident memory (MiB, as it printed it with
// PrintOwnPeakMemory; -1 if it did not) to `peak_mib` and its CPU time
// (user + system, seconds) to `cpu_s` (both may be null). Started by
// posix_spawn, which does not copy this process's page tables as fork does:
// a timed child then costs what it costs when a shell starts it. False if
// the child did not exit with status 0.
inline bool RunChildProcess(const char* self, const std::vector<std::string>& args, std::string* out,
                            double* peak_mib, double* cpu_s = nullptr) {
  int fds[2];
  if (pipe(fds) != 0) return false;
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_adddup2(&actions, fds[1], STDOUT_FILENO);
  posix_spawn_file_actions_addclose(&actions, fds[0]);
  posix_spawn_file_actions_addclose(&actions, fds[1]);
  std::vector<char*> argv{const_cast<char*>(self)};
  for (const std::string& a : args) argv.push_back(const_cast<char*>(a.c_str()));
  argv.push_back(nullptr);
  pid_t pid = -1;
  const int spawned = posix_spawn(&pid, self, &actions, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  close(fds[1]);
  std::string text;
  char buffer[256];
  for (ssize_t got; spawned == 0 && (got = read(fds[0], buffer, sizeof(buffer))) > 0;) {
    text.append(buffer, static_cast<std::size_t>(got));
  }
  close(fds[0]);
  int status = 0;
  struct rusage usage {};
  if (spawned != 0 || wait4(pid, &status, 0, &usage) < 0 || !WIFEXITED(status) || WEXITSTATUS(status) != 0) {
    return false;
  }
  if (out) *out = text;
  if (peak_mib) {
    const std::size_t at = text.rfind("peak_rss_kib ");
    *peak_mib = at == std::string::npos ? -1.0 : std::atof(text.c_str() + at + 13) / 1024.0;
  }
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

// A report's text from its template (src/benchmarks/templates/NAME): the
// prose lives there, the figures come from the program. Each {{key}} is
// replaced by values[key]; a key the template holds and `values` lacks, or
// one given and unused, throws std::runtime_error, so the two cannot drift
// apart unnoticed.
inline std::string FillTemplate(const std::string& name, const std::map<std::string, std::string>& values) {
  const std::string path = std::string(ROTAVG_TEMPLATE_DIR) + "/" + name;
  std::ifstream in(path);
  if (!in) throw std::runtime_error("cannot read the report template " + path);
  std::stringstream buffer;
  buffer << in.rdbuf();
  const std::string text = buffer.str();
  std::string out;
  std::set<std::string> used;
  std::size_t at = 0;
  for (std::size_t open = text.find("{{"); open != std::string::npos; open = text.find("{{", at)) {
    const std::size_t close = text.find("}}", open);
    if (close == std::string::npos) throw std::runtime_error(path + ": unclosed {{");
    const std::string key = text.substr(open + 2, close - open - 2);
    const auto it = values.find(key);
    if (it == values.end()) throw std::runtime_error(path + ": no value for {{" + key + "}}");
    out += text.substr(at, open - at) + it->second;
    used.insert(key);
    at = close + 2;
  }
  out += text.substr(at);
  for (const auto& [key, value] : values) {
    if (!used.count(key)) throw std::runtime_error(path + ": {{" + key + "}} is given but not in the template");
  }
  return out;
}

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_SRC_BENCHMARKS_REPORT_H_
