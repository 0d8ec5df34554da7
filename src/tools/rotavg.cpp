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

#include "rotation_averaging/controllers/image_pipeline.h"
#include "rotation_averaging/estimators/rotation_averaging.h"
#include "rotation_averaging/eval/rotation_evaluation.h"
#include "rotation_averaging/io/graph_io.h"
#include "rotation_averaging/io/orientation_io.h"
#include "rotation_averaging/scene/synthetic_graph.h"

namespace ra = rotation_averaging;

namespace {

const char* kUsage = R"(usage:
  rotavg solve INPUT --output orientations.csv [options]
      INPUT                 1DSfM EGs.txt (or its folder; cc.txt beside it is used), g2o, TORO or iRotAvg file
      --format F            auto (default), 1dsfm, g2o, toro, irotavg, rotavg (the package's graph file)
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
  rotavg images --images DIR --intrinsics K.txt|cameras.txt [--downsample F] [--features sift|orb] [--max-features N]
               [--pairs exhaustive|sequential:N|list:FILE] [--covariance marginal|conditional] [--graph-out graph.txt]
               [--output orientations.csv] [--gt PATH] [--verbose] [all averaging options of solve]
      features, matching, relative poses with rotation covariances, then averaging; prints per-stage
      timings and per-pair statistics; --graph-out writes the view graph for `rotavg solve`
  rotavg demo [--views N] [--noise-deg D] [--outlier-ratio R] [--seed S]
      built-in synthetic graph with ground truth (default 500 views, 3 deg noise varying 5x from
      edge to edge, 20% outlier edges): solves it with the squared loss, the L1-IRLS baseline and
      MAGSAC with covariance weights, and prints the scores of each
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

const std::vector<std::string> kAveragingFlags = {"--solver", "--loss", "--weighting", "--sigma-max",
                                                  "--normalization", "--max-iterations"};

bool ParseAveragingOptions(const Args& args, ra::RotationAveragingOptions* options, std::string* error) {
  auto fail = [error](const std::string& e) {
    *error = e;
    return false;
  };
  if (!ra::ParseSolverType(args.Get("--solver", "irls"), &options->solver)) return fail("unknown --solver");
  if (!ra::ParseLossType(args.Get("--loss", "magsac"), &options->loss)) return fail("unknown --loss");
  if (!ra::ParseEdgeWeighting(args.Get("--weighting", "covariance"), &options->weighting)) {
    return fail("unknown --weighting");
  }
  if (!ra::ParseCovarianceNormalization(args.Get("--normalization", "std"), &options->covariance_normalization)) {
    return fail("unknown --normalization (std or paper)");
  }
  if (args.Has("--sigma-max")) {
    options->loss_scale = std::atof(args.Get("--sigma-max").c_str());
    if (!(options->loss_scale > 0.0)) return fail("--sigma-max must be positive");
  }
  if (args.Has("--max-iterations")) {
    options->max_iterations = std::atoi(args.Get("--max-iterations").c_str());
    if (options->max_iterations < 0) return fail("--max-iterations must be >= 0");
  }
  if (args.Has("--no-gnc")) options->gnc_initial_scale_factor = 1.0;
  return true;
}

std::vector<std::string> Concat(std::vector<std::string> a, const std::vector<std::string>& b) {
  a.insert(a.end(), b.begin(), b.end());
  return a;
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

// --output: write the orientations; --gt: score them. Returns an exit code.
int WriteAndScore(const Args& args, const ra::NamedOrientations& named) {
  const std::string output = args.Get("--output");
  std::string error;
  if (!output.empty()) {
    if (!ra::WriteOrientationsCsv(output, named, &error)) return Fail(error);
    std::cout << "wrote " << named.size() << " orientations to " << output << std::endl;
  }
  if (args.Has("--gt")) return Evaluate(named, args.Get("--gt"), args.Get("--gt-format", "auto"), args.Has("--json"));
  return 0;
}

int Solve(int argc, char** argv) {
  Args args;
  std::string error;
  if (!ParseArgs(argc, argv, 2, {"--no-gnc", "--json"}, &args, &error)) return Fail(error);
  if (!CheckKnown(args, Concat({"--format", "--output", "--gt", "--gt-format"}, kAveragingFlags), &error)) {
    return Fail(error);
  }
  if (args.positional.size() != 1) return Fail("solve takes exactly one INPUT\n" + std::string(kUsage));
  ra::RotationAveragingOptions options;
  ra::GraphFormat format;
  if (!ra::ParseGraphFormat(args.Get("--format", "auto"), &format)) return Fail("unknown --format");
  if (!ParseAveragingOptions(args, &options, &error)) return Fail(error);
  const std::string output = args.Get("--output");
  if (output.empty() && !args.Has("--gt")) return Fail("solve needs --output (and/or --gt)");

  const auto read_start = std::chrono::steady_clock::now();
  ra::ViewGraph graph;
  const ra::ReadReport report = ra::ReadViewGraph(args.positional[0], format, &graph);
  if (!report.ok()) return Fail(report.error);
  const double read_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - read_start).count();
  for (std::size_t k = 0; k < report.warnings.size() && k < 10; ++k) std::cerr << "warning: " << report.warnings[k] << "\n";
  if (report.warnings.size() > 10) std::cerr << "warning: ... " << report.warnings.size() - 10 << " more\n";

  ra::ViewOrientations orientations;
  ra::RotationAveragingSummary summary;
  const bool ok = ra::SolveRotationAveraging(graph, options, &orientations, &summary);
  std::cout << "input: " << args.positional[0] << " (" << ra::GraphFormatName(ra::DetectGraphFormat(args.positional[0]))
            << ")\nviews: " << graph.NumViews() << "\nedges: " << graph.NumEdges()
            << "\nedges rejected on input: " << graph.Stats().Rejected()
            << "\ncomponents: " << graph.ConnectedComponents().size() << "\nsolver: " << ra::SolverTypeName(options.solver)
            << ", loss: " << ra::LossTypeName(options.loss) << ", weighting: " << ra::EdgeWeightingName(options.weighting)
            << "\nread time: " << std::setprecision(4) << read_s << " s\n"
            << summary.Report() << std::endl;
  const int rc = WriteAndScore(args, ra::NameOrientations(graph, orientations));
  return rc != 0 ? rc : (ok ? 0 : 1);
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

int Images(int argc, char** argv) {
  Args args;
  std::string error;
  if (!ParseArgs(argc, argv, 2, {"--no-gnc", "--json", "--verbose"}, &args, &error)) return Fail(error);
  if (!CheckKnown(args,
                  Concat({"--images", "--intrinsics", "--downsample", "--features", "--max-features", "--pairs",
                          "--covariance", "--graph-out", "--output", "--gt", "--gt-format"},
                         kAveragingFlags),
                  &error)) {
    return Fail(error);
  }
  if (!args.Has("--images") || !args.Has("--intrinsics")) return Fail("images needs --images DIR and --intrinsics K.txt");
  ra::ImagePipelineOptions pipeline;
  if (!ra::ParseFeatureType(args.Get("--features", "sift"), &pipeline.features.type)) return Fail("unknown --features");
  pipeline.features.downsample = std::atof(args.Get("--downsample", "1").c_str());
  if (!(pipeline.features.downsample > 0.0 && pipeline.features.downsample <= 1.0)) {
    return Fail("--downsample must be in (0, 1] (0.25 = a quarter of the width)");
  }
  pipeline.features.max_features = std::atoi(args.Get("--max-features", "8000").c_str());
  if (pipeline.features.max_features < 10) return Fail("--max-features must be >= 10");
  if (!ra::PairSelection::Parse(args.Get("--pairs", "exhaustive"), &pipeline.pairs, &error)) {
    return Fail(error.empty() ? "--pairs must be exhaustive, sequential:N or list:FILE" : error);
  }
  if (!ra::ParseRotationCovarianceModel(args.Get("--covariance", "marginal"), &pipeline.relative_pose.covariance_model)) {
    return Fail("--covariance must be marginal or conditional");
  }
  ra::RotationAveragingOptions options;
  if (!ParseAveragingOptions(args, &options, &error)) return Fail(error);
  const std::string output = args.Get("--output");
  if (output.empty() && !args.Has("--gt") && !args.Has("--graph-out")) {
    return Fail("images needs --output, --graph-out or --gt");
  }
  ra::CameraIntrinsics k;
  if (!ra::ReadCameraIntrinsics(args.Get("--intrinsics"), &k, &error)) return Fail(error);
  const std::vector<std::string> images = ra::ListImages(args.Get("--images"));
  if (images.size() < 2) return Fail("need at least two images in " + args.Get("--images"));

  const ra::ImagePipelineResult front = ra::BuildViewGraphFromImages(images, k, pipeline);
  std::cout << front.Report() << "\n";
  const bool verbose = args.Has("--verbose");
  std::cout << "per pair (image1 image2: matches, inliers, sigma px, parallax deg, homography inlier share, ms, result):\n";
  int shown = 0;
  for (const ra::PairReport& p : front.pairs) {
    if (!verbose && shown >= 20) break;
    ++shown;
    std::cout << "  " << front.graph.FindView(p.image1)->name << " " << front.graph.FindView(p.image2)->name << ": "
              << p.matches << ", " << p.pose.inliers.size() << ", " << std::setprecision(3) << p.pose.sigma_px << ", "
              << p.pose.median_parallax_deg << ", " << p.pose.homography_inlier_ratio << ", " << p.milliseconds << ", "
              << (p.pose.success ? "ok" : std::string(ra::TwoViewFailureName(p.pose.failure)) + " (" + p.pose.message + ")")
              << "\n";
  }
  if (!verbose && front.pairs.size() > 20) std::cout << "  ... " << front.pairs.size() - 20 << " more (--verbose)\n";
  if (args.Has("--graph-out")) {
    if (!ra::WriteRotavgGraph(args.Get("--graph-out"), front.graph, &error)) return Fail(error);
    std::cout << "wrote the view graph to " << args.Get("--graph-out") << "\n";
  }
  ra::ViewOrientations orientations;
  ra::RotationAveragingSummary summary;
  const bool ok = ra::SolveRotationAveraging(front.graph, options, &orientations, &summary);
  std::cout << "averaging: " << summary.Report() << std::endl;
  const int rc = WriteAndScore(args, ra::NameOrientations(front.graph, orientations));
  return rc != 0 ? rc : (ok ? 0 : 1);
}

int Demo(int argc, char** argv) {
  Args args;
  std::string error;
  if (!ParseArgs(argc, argv, 2, {}, &args, &error)) return Fail(error);
  if (!CheckKnown(args, {"--views", "--noise-deg", "--outlier-ratio", "--seed"}, &error)) return Fail(error);
  ra::SyntheticGraphOptions go;
  go.num_views = std::atoi(args.Get("--views", "500").c_str());
  go.noise_deg = std::atof(args.Get("--noise-deg", "3").c_str());
  go.outlier_ratio = std::atof(args.Get("--outlier-ratio", "0.2").c_str());
  go.seed = std::strtoull(args.Get("--seed", "1").c_str(), nullptr, 10);
  go.noise_spread = 5.0;
  go.anisotropic = true;
  if (go.num_views < 2 || !(go.noise_deg >= 0.0) || !(go.outlier_ratio >= 0.0 && go.outlier_ratio < 1.0)) {
    return Fail("demo needs --views >= 2, --noise-deg >= 0 and 0 <= --outlier-ratio < 1");
  }
  const ra::SyntheticGraph sg = ra::MakeSyntheticGraph(go);
  std::cout << "synthetic view graph: " << sg.graph.NumViews() << " views, " << sg.graph.NumEdges() << " edges, "
            << go.noise_deg << " deg noise (per-edge spread x" << go.noise_spread << ", anisotropic, covariances known), "
            << 100.0 * go.outlier_ratio << "% outlier edges\n\n";
  struct Method {
    std::string label;
    ra::RotationAveragingOptions options;
  };
  std::vector<Method> methods(3);
  methods[0].label = "squared loss, no weighting";
  methods[0].options.loss = ra::LossType::kSquared;
  methods[0].options.weighting = ra::EdgeWeighting::kNone;
  methods[1].label = "L1-IRLS baseline (Chatterjee-Govindu)";
  methods[1].options.solver = ra::SolverType::kL1Irls;
  methods[2].label = "MAGSAC + covariance weights (default)";
  std::cout << std::left << std::setw(40) << "method" << std::right << std::setw(12) << "median deg" << std::setw(10)
            << "AUC@2" << std::setw(10) << "AUC@5" << std::setw(10) << "AUC@10" << std::setw(10) << "AUC@20"
            << std::setw(12) << "solve s" << "\n";
  for (const Method& m : methods) {
    ra::ViewOrientations orientations;
    ra::RotationAveragingSummary summary;
    ra::SolveRotationAveraging(sg.graph, m.options, &orientations, &summary);
    const ra::EvaluationResult e = ra::EvaluateOrientations(ra::NameOrientations(sg.graph, orientations),
                                                            ra::NameOrientations(sg.graph, sg.ground_truth));
    std::cout << std::left << std::setw(40) << m.label << std::right << std::fixed << std::setprecision(3)
              << std::setw(12) << e.median_error_deg << std::setprecision(1);
    for (const auto& [t, a] : e.auc) std::cout << std::setw(9) << 100.0 * a << "%";
    std::cout << std::setprecision(4) << std::setw(12) << summary.solve_time_s << "\n";
  }
  return 0;
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
    if (command == "demo") return Demo(argc, argv);
    if (command == "images") return Images(argc, argv);
  } catch (const std::exception& e) {
    return Fail(e.what());
  }
  return Fail("unknown command '" + command + "'\n" + kUsage);
}
