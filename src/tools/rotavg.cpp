// rotavg: solve and score rotation averaging problems from files.
//
//   rotavg solve INPUT [--format auto|1dsfm|g2o|toro|irotavg] [--loss magsac|...]
//                [--weighting covariance|none|inliers|trace|frobenius] [--solver irls|ceres|l1_irls]
//                [--sigma-max S] [--normalization std|paper] [--no-gnc] [--max-iterations N]
//                [--gt PATH [--gt-format ...]] --output orientations.csv
//   rotavg eval --estimate orientations.csv --gt PATH [--gt-format auto|csv|strecha|colmap|chain] [--json]
#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <iomanip>
#include <iostream>
#include <map>
#include <string>
#include <vector>

#include "rotation_averaging/estimators/rotation_averaging.h"
#include "rotation_averaging/eval/rotation_evaluation.h"
#include "rotation_averaging/io/graph_io.h"
#include "rotation_averaging/io/orientation_io.h"

namespace ra = rotation_averaging;

namespace {

const char* kUsage = R"(usage:
  rotavg solve INPUT --output orientations.csv [options]
      INPUT                 1DSfM EGs.txt (or its folder; cc.txt beside it is used), g2o, TORO or iRotAvg file
      --format F            auto (default), 1dsfm, g2o, toro, irotavg
      --solver S            irls (default, fast sparse IRLS), ceres, l1_irls (Chatterjee-Govindu baseline)
      --loss L              magsac (default), squared, huber, soft_l1, l0.5, cauchy, geman_mcclure, tukey
      --weighting W         covariance (default), none, inliers, trace, frobenius
      --sigma-max S         loss scale (sigma_max for magsac): standard deviations for covariance
                            weighting, radians otherwise; default 3 std / 5 deg (0.02 with --normalization paper)
      --normalization N     std (default: covariances in rad^2) or paper (C scaled by 1e8, the paper's code)
      --no-gnc              start redescending losses at their final scale (the paper's setting)
      --max-iterations N    per component (default 100)
      --gt PATH             also score the result against ground truth (see eval)
      --gt-format F         auto (default), csv, strecha, colmap, chain
  rotavg eval --estimate orientations.csv --gt PATH [--gt-format F] [--json]
      prints views in ground truth / estimated / common, median and mean error, AUC@2/5/10/20
)";

int Fail(const std::string& message) {
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

bool ParseArgs(int argc, char** argv, int first, const std::vector<std::string>& boolean_flags, Args* args,
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

bool CheckKnown(const Args& args, const std::vector<std::string>& known, std::string* error) {
  for (const auto& [k, v] : args.values) {
    if (std::find(known.begin(), known.end(), k) == known.end()) {
      *error = "unknown option " + k;
      return false;
    }
  }
  return true;
}

int Evaluate(const ra::NamedOrientations& estimate, const std::string& gt_path, const std::string& gt_format_text,
             bool json) {
  ra::GroundTruthFormat gt_format;
  if (!ra::ParseGroundTruthFormat(gt_format_text, &gt_format)) return Fail("unknown --gt-format " + gt_format_text);
  ra::NamedOrientations gt;
  const ra::ReadReport report = ra::ReadGroundTruth(gt_path, gt_format, &gt);
  if (!report.ok()) return Fail(report.error);
  const ra::EvaluationResult result = ra::EvaluateOrientations(estimate, gt);
  std::cout << (json ? result.ToJson() : result.ToText()) << std::endl;
  return 0;
}

int Solve(int argc, char** argv) {
  Args args;
  std::string error;
  if (!ParseArgs(argc, argv, 2, {"--no-gnc", "--json"}, &args, &error)) return Fail(error);
  if (!CheckKnown(args, {"--format", "--solver", "--loss", "--weighting", "--sigma-max", "--normalization",
                         "--max-iterations", "--output", "--gt", "--gt-format"},
                  &error)) {
    return Fail(error);
  }
  if (args.positional.size() != 1) return Fail("solve takes exactly one INPUT\n" + std::string(kUsage));
  ra::RotationAveragingOptions options;
  ra::GraphFormat format;
  if (!ra::ParseGraphFormat(args.Get("--format", "auto"), &format)) return Fail("unknown --format");
  if (!ra::ParseSolverType(args.Get("--solver", "irls"), &options.solver)) return Fail("unknown --solver");
  if (!ra::ParseLossType(args.Get("--loss", "magsac"), &options.loss)) return Fail("unknown --loss");
  if (!ra::ParseEdgeWeighting(args.Get("--weighting", "covariance"), &options.weighting)) {
    return Fail("unknown --weighting");
  }
  if (!ra::ParseCovarianceNormalization(args.Get("--normalization", "std"), &options.covariance_normalization)) {
    return Fail("unknown --normalization (std or paper)");
  }
  if (args.Has("--sigma-max")) {
    options.loss_scale = std::atof(args.Get("--sigma-max").c_str());
    if (!(options.loss_scale > 0.0)) return Fail("--sigma-max must be positive");
  }
  if (args.Has("--max-iterations")) {
    options.max_iterations = std::atoi(args.Get("--max-iterations").c_str());
    if (options.max_iterations < 0) return Fail("--max-iterations must be >= 0");
  }
  if (args.Has("--no-gnc")) options.gnc_initial_scale_factor = 1.0;
  const std::string output = args.Get("--output");
  if (output.empty() && !args.Has("--gt")) return Fail("solve needs --output (and/or --gt)");

  const auto read_start = std::chrono::steady_clock::now();
  ra::ViewGraph graph;
  const ra::ReadReport report = ra::ReadViewGraph(args.positional[0], format, &graph);
  if (!report.ok()) return Fail(report.error);
  const double read_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - read_start).count();
  for (std::size_t k = 0; k < report.warnings.size() && k < 10; ++k) std::cerr << "warning: " << report.warnings[k] << "\n";
  if (report.warnings.size() > 10) std::cerr << "warning: ... " << report.warnings.size() - 10 << " more\n";

  ra::Orientations orientations;
  ra::RotationAveragingSummary summary;
  const bool ok = ra::SolveRotationAveraging(graph, options, &orientations, &summary);
  std::cout << "input: " << args.positional[0] << " (" << ra::GraphFormatName(ra::DetectGraphFormat(args.positional[0]))
            << ")\nviews: " << graph.NumViews() << "\nedges: " << graph.NumEdges()
            << "\nedges rejected on input: " << graph.Stats().Rejected()
            << "\ncomponents: " << graph.ConnectedComponents().size() << "\nsolver: " << ra::SolverTypeName(options.solver)
            << ", loss: " << ra::LossTypeName(options.loss) << ", weighting: " << ra::EdgeWeightingName(options.weighting)
            << "\nread time: " << std::setprecision(4) << read_s << " s\n"
            << summary.Report() << std::endl;
  const ra::NamedOrientations named = ra::NameOrientations(graph, orientations);
  if (!output.empty()) {
    if (!ra::WriteOrientationsCsv(output, named, &error)) return Fail(error);
    std::cout << "wrote " << named.size() << " orientations to " << output << std::endl;
  }
  if (args.Has("--gt")) {
    const int rc = Evaluate(named, args.Get("--gt"), args.Get("--gt-format", "auto"), args.Has("--json"));
    if (rc != 0) return rc;
  }
  return ok ? 0 : 1;
}

int EvalCommand(int argc, char** argv) {
  Args args;
  std::string error;
  if (!ParseArgs(argc, argv, 2, {"--json"}, &args, &error)) return Fail(error);
  if (!CheckKnown(args, {"--estimate", "--gt", "--gt-format"}, &error)) return Fail(error);
  if (!args.Has("--estimate") || !args.Has("--gt")) return Fail("eval needs --estimate and --gt\n" + std::string(kUsage));
  ra::NamedOrientations estimate;
  const ra::ReadReport report = ra::ReadOrientationsCsv(args.Get("--estimate"), &estimate);
  if (!report.ok()) return Fail(report.error);
  return Evaluate(estimate, args.Get("--gt"), args.Get("--gt-format", "auto"), args.Has("--json"));
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2 || std::string(argv[1]) == "--help" || std::string(argv[1]) == "-h") {
    std::cout << kUsage;
    return argc < 2 ? 2 : 0;
  }
  const std::string command = argv[1];
  try {
    if (command == "solve") return Solve(argc, argv);
    if (command == "eval") return EvalCommand(argc, argv);
  } catch (const std::exception& e) {
    return Fail(e.what());
  }
  return Fail("unknown command '" + command + "'\n" + kUsage);
}
