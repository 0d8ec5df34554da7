// Command-line helpers shared by rotavg and rotavg_images: a minimal
// "--flag value" parser, the averaging options both accept, writing and
// scoring a solution.
#ifndef ROTATION_AVERAGING_SRC_TOOLS_CLI_H_
#define ROTATION_AVERAGING_SRC_TOOLS_CLI_H_

#include <algorithm>
#include <cstdlib>
#include <iostream>
#include <map>
#include <string>
#include <vector>

#include "rotation_averaging/core/estimators/rotation_averaging.h"
#include "rotation_averaging/core/eval/rotation_evaluation.h"
#include "rotation_averaging/core/io/graph_io.h"
#include "rotation_averaging/core/io/orientation_io.h"
#include "rotation_averaging/util/freed_memory.h"

namespace rotation_averaging_cli {

namespace ra = rotation_averaging;

inline int Fail(const std::string& message) {
  std::cerr << "rotavg: " << message << "\n";
  return 2;
}

// Minimal "--flag value" parser; positional arguments are collected in order.
struct Args {
  std::map<std::string, std::string> values;
  std::vector<std::string> flags, positional;
  bool Has(const std::string& f) const {
    return values.count(f) || std::find(flags.begin(), flags.end(), f) != flags.end();
  }
  std::string Get(const std::string& f, const std::string& fallback = "") const {
    auto it = values.find(f);
    return it == values.end() ? fallback : it->second;
  }
};

inline bool ParseArgs(int argc, char** argv, int first, const std::vector<std::string>& boolean_flags, Args* args,
                      std::string* error) {
  for (int k = first; k < argc; ++k) {
    const std::string a = argv[k];
    if (a.rfind("--", 0) == 0) {
      if (std::find(boolean_flags.begin(), boolean_flags.end(), a) != boolean_flags.end()) {
        args->flags.push_back(a);
      } else if (k + 1 < argc) {
        args->values[a] = argv[++k];
      } else {
        *error = "option " + a + " needs a value";
        return false;
      }
    } else {
      args->positional.push_back(a);
    }
  }
  return true;
}

inline bool CheckKnown(const Args& args, const std::vector<std::string>& known, std::string* error) {
  for (const auto& [k, v] : args.values) {
    if (std::find(known.begin(), known.end(), k) == known.end()) {
      *error = "unknown option " + k;
      return false;
    }
  }
  return true;
}

inline const std::vector<std::string> kAveragingFlags = {"--solver", "--loss", "--weighting", "--sigma-max",
                                                         "--normalization", "--max-iterations",
                                                         "--self-calibration"};

inline bool ParseAveragingOptions(const Args& args, ra::RotationAveragingOptions* options, std::string* error) {
  auto fail = [error](const std::string& e) {
    *error = e;
    return false;
  };
  // The caller's options hold the defaults: a flag not given keeps it.
  if (!ra::ParseSolverType(args.Get("--solver", ra::SolverTypeName(options->solver)), &options->solver)) {
    return fail("unknown --solver (" + ra::SolverTypeChoices() + ")");
  }
  if (!ra::ParseLossType(args.Get("--loss", ra::LossTypeName(options->loss)), &options->loss)) {
    return fail("unknown --loss (" + ra::LossTypeChoices() + ")");
  }
  if (!ra::ParseEdgeWeighting(args.Get("--weighting", ra::EdgeWeightingName(options->weighting)), &options->weighting)) {
    return fail("unknown --weighting (" + ra::EdgeWeightingChoices() + ")");
  }
  if (!ra::ParseCovarianceNormalization(
          args.Get("--normalization", ra::CovarianceNormalizationName(options->covariance_normalization)),
          &options->covariance_normalization)) {
    return fail("unknown --normalization (" + ra::CovarianceNormalizationChoices() + ")");
  }
  if (!ra::ParseCovarianceSelfCalibration(
          args.Get("--self-calibration", ra::CovarianceSelfCalibrationName(options->self_calibration)),
          &options->self_calibration)) {
    return fail("unknown --self-calibration (" + ra::CovarianceSelfCalibrationChoices() + ")");
  }
  if (args.Has("--sigma-max")) {
    options->loss_scale = std::atof(args.Get("--sigma-max").c_str());
    if (!(options->loss_scale > 0.0)) return fail("--sigma-max must be positive");
  }
  if (args.Has("--max-iterations")) options->max_iterations = std::atoi(args.Get("--max-iterations").c_str());
  if (args.Has("--no-gnc")) options->robust_start.gnc_initial_scale_factor = 1.0;
  return options->Validate(error);
}

inline std::vector<std::string> Concat(std::vector<std::string> a, const std::vector<std::string>& b) {
  a.insert(a.end(), b.begin(), b.end());
  return a;
}

// The ground truth of --gt and --gt-format; false (with `error`) if either is wrong.
inline bool ReadGroundTruthArg(const std::string& gt_path, const std::string& gt_format_text, ra::NamedOrientations* gt,
                               std::string* error) {
  ra::GroundTruthFormat gt_format;
  if (!ra::ParseGroundTruthFormat(gt_format_text, &gt_format)) {
    *error = "unknown --gt-format " + gt_format_text;
    return false;
  }
  const ra::ReadReport report = ra::ReadGroundTruth(gt_path, gt_format, gt);
  if (!report.ok()) *error = report.error;
  return report.ok();
}

// per_view (text only): then one line "view NAME ERROR_DEG" per common view.
inline int Evaluate(const ra::NamedOrientations& estimate, const std::string& gt_path, const std::string& gt_format_text,
             bool json, bool per_view = false) {
  ra::NamedOrientations gt;
  std::string error;
  if (!ReadGroundTruthArg(gt_path, gt_format_text, &gt, &error)) return Fail(error);
  const ra::EvaluationResult result = ra::EvaluateOrientations(estimate, gt);
  std::cout << (json ? result.ToJson() : result.ToText()) << std::endl;
  if (per_view && !json) {
    for (const auto& [name, error] : result.errors_deg) std::cout << "view " << name << " " << error << "\n";
  }
  return 0;
}

// --output: write the orientations; --gt: score them. Returns an exit code.
inline int WriteAndScore(const Args& args, const ra::NamedOrientations& named) {
  const std::string output = args.Get("--output");
  std::string error;
  if (!output.empty()) {
    if (!ra::WriteOrientationsCsv(output, named, &error)) return Fail(error);
    std::cout << "wrote " << named.size() << " orientations to " << output << std::endl;
  }
  if (args.Has("--gt")) return Evaluate(named, args.Get("--gt"), args.Get("--gt-format", "auto"), args.Has("--json"));
  return 0;
}

// main() of a program with one command (rotavg_images, rotavg_vocabulary):
// no arguments or --help print the usage; an exception becomes a message.
inline int RunCommand(int argc, char** argv, const char* usage, int (*command)(int, char**)) {
  rotation_averaging::KeepFreedMemoryForReuse();  // util/freed_memory.h: buffers of each image reused, not faulted in again
  if (argc < 2 || std::string(argv[1]) == "--help" || std::string(argv[1]) == "-h") {
    std::cout << usage;
    return argc < 2 ? 2 : 0;
  }
  try {
    return command(argc, argv);
  } catch (const std::exception& e) {
    return Fail(e.what());
  }
}

}  // namespace rotation_averaging_cli

#endif  // ROTATION_AVERAGING_SRC_TOOLS_CLI_H_
