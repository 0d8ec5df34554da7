// rotavg: solve and score rotation averaging problems from files.
//
//   rotavg solve INPUT [--format auto|1dsfm|g2o|toro|irotavg] [--loss magsac|...]
//                [--weighting covariance|none|inliers|trace|frobenius] [--solver irls|ceres|l1_irls]
//                [--sigma-max S] [--normalization std|paper] [--no-gnc] [--max-iterations N]
//                [--self-calibration loss_scale|floor]
//                [--gt PATH [--gt-format ...]] --output orientations.csv
//   rotavg eval --estimate orientations.csv|images.txt [--estimate-format csv|colmap] --gt PATH
//               [--gt-format auto|csv|strecha|colmap|chain] [--json] [--per-view]
//   rotavg eval --graph graph.txt --gt PATH [--floor-deg S] [--view-term-from ADJUSTED.csv] [--per-edge]
//   rotavg images ...  runs rotavg_images (beside this program) with the same arguments
//   rotavg vocabulary ...  runs rotavg_vocabulary likewise
//
// This program links the core library only (no OpenCV, no ROS), so that it
// starts in milliseconds; the image front end lives in rotavg_images.
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <iomanip>
#include <iostream>
#include <string>
#include <vector>

#include "cli.h"
#include "rotation_averaging/core/scene/synthetic_graph.h"
#include "rotation_averaging/util/freed_memory.h"

namespace {

using namespace rotation_averaging_cli;  // NOLINT: the tool's own helpers

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
      --self-calibration C  when covariances prove optimistic (residual scale above 1.5): loss_scale
                            (default: widen the loss by that scale) or floor (add an isotropic floor,
                            estimated from the residuals, to every edge's covariance; images' default)
      --gt PATH             also score the result against ground truth (see eval)
      --gt-format F         auto (default), csv, strecha, colmap, chain
  rotavg eval --estimate orientations.csv --gt PATH [--gt-format F] [--estimate-format E] [--json] [--per-view]
      prints views in ground truth / estimated / common, median and mean error, AUC@2/5/10/20 (--per-view:
      then each view's error); --estimate-format csv (default) or colmap (a COLMAP text model's images.txt,
      or its folder: another tool's reconstruction scored the same way)
  rotavg eval --graph graph.txt --gt PATH [--graph-format F] [--floor-deg S] [--view-term-from ADJUSTED.csv]
              [--per-edge]
      calibration of the edges' covariances against the ground truth: each edge's error and
      NEES = eta^T C^-1 eta (median 2.37, mean 3 and 95% below 7.81 if calibrated), as given and with
      the covariance floor that rotavg images adds (estimated by solving the graph as it does, or
      --floor-deg); then the same after the per-view offsets that best explain the errors (an error
      all of a view's pairs share: the reference's own, or one of that image that its pairs inherit;
      neither their consistency nor the floor can see it); --view-term-from: then the same with the
      view term added to both views of each pair, estimated from the per-view offsets against ADJUSTED
      (orientations of a bundle adjustment of the same images, e.g. the output of rotavg images, as it
      prints it); --per-edge: then
      "edge NAME1 NAME2 ERROR_DEG NEES NEES_WITH_FLOOR" per edge and
      "view NAME OFFSET_DEG X Y Z" per view (the offset as a rotation vector in the camera frame)
  rotavg images --images DIR --intrinsics K.txt|cameras.txt [--downsample F] [--features sift|orb] [--max-features N]
               [--pairs exhaustive|sequential:N|list:FILE] [--covariance marginal|conditional] [--graph-out graph.txt]
               [--output orientations.csv] [--gt PATH] [--verbose] [all averaging options of solve]
      features, matching, relative poses with rotation covariances, then averaging; prints per-stage
      timings and per-pair statistics; --graph-out writes the view graph for `rotavg solve`
  rotavg vocabulary --output FILE [--words N] [--max-features N] [--max-size PX] DIR|IMAGE...
      trains the visual vocabulary of the keyframe front end's loop-closure retrieval (k-means on SIFT
      descriptors, faiss) on the images of the given folders
  rotavg demo [--views N] [--noise-deg D] [--outlier-ratio R] [--seed S]
      built-in synthetic graph with ground truth (default 500 views, 3 deg noise varying 5x from
      edge to edge, 20% outlier edges): solves it with the squared loss, the L1-IRLS baseline and
      MAGSAC with covariance weights, and prints the scores of each
)";

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

// The covariance floor `rotavg images` adds to this graph's edges: that of
// its largest component when solved with its averaging defaults.
double ImagesCovarianceFloor(const ra::ViewGraph& graph) {
  ra::RotationAveragingOptions options;
  options.self_calibration = ra::CovarianceSelfCalibration::kFloor;
  ra::ViewOrientations orientations;
  ra::RotationAveragingSummary summary;
  ra::SolveRotationAveraging(graph, options, &orientations, &summary);
  return summary.LargestComponentFloorRad();
}

// eval --graph: how well the edges' covariances predict their errors against
// the ground truth, as given and with the floor the averaging adds.
int EvalGraph(const Args& args, const ra::NamedOrientations& gt) {
  ra::GraphFormat format;
  if (!ra::ParseGraphFormat(args.Get("--graph-format", "auto"), &format)) return Fail("unknown --graph-format");
  ra::ViewGraph graph;
  const ra::ReadReport report = ra::ReadViewGraph(args.Get("--graph"), format, &graph);
  if (!report.ok()) return Fail(report.error);
  double floor_rad = 0.0;
  if (args.Has("--floor-deg")) {
    char* end = nullptr;
    const std::string text = args.Get("--floor-deg");
    const double floor_deg = std::strtod(text.c_str(), &end);
    if (end == text.c_str() || *end != '\0' || !(floor_deg >= 0.0) || !std::isfinite(floor_deg)) {
      return Fail("--floor-deg must be a finite number >= 0, got '" + text + "'");
    }
    floor_rad = floor_deg * M_PI / 180.0;
  } else {
    floor_rad = ImagesCovarianceFloor(graph);
  }
  // The orientations the view term is estimated against (a bundle adjustment
  // of the same images), read before anything is printed.
  ra::NamedOrientations adjusted;
  if (args.Has("--view-term-from")) {
    std::string error;
    if (!ReadGroundTruthArg(args.Get("--view-term-from"), "auto", &adjusted, &error)) return Fail(error);
  }
  const ra::EdgeCalibration raw = ra::EvaluateEdgeCovariances(graph, gt);
  if (raw.edges_scored == 0) {
    return Fail("no edge of " + args.Get("--graph") + " has a covariance and both views in the ground truth");
  }
  const ra::EdgeCalibration floored = ra::EvaluateEdgeCovariances(graph, gt, floor_rad);
  std::cout << "covariances as given\n" << raw.ToText() << "\n\ncovariances with the floor ("
            << (args.Has("--floor-deg") ? "--floor-deg" : "estimated by the averaging, as rotavg images does")
            << ")\n" << floored.ToText() << std::endl;
  if (args.Has("--view-term-from")) {
    // The error each view's pairs share, as rotavg images estimates it: from
    // the views' offsets against a bundle adjustment of the same images.
    const double view_rad = ra::ViewTermRad(ra::EvaluateEdgeCovariances(graph, adjusted, floor_rad));
    if (!std::isfinite(view_rad)) {
      return Fail("no edge of " + args.Get("--graph") + " has a covariance and both views in " +
                  args.Get("--view-term-from"));
    }
    const ra::EdgeCalibration viewed =
        ra::EvaluateEdgeCovariances(graph, gt, ra::FloorWithViewTermRad(floor_rad, view_rad));
    std::cout << "\ncovariances with the floor and the view term (" << std::fixed << std::setprecision(4)
              << view_rad * 180.0 / M_PI << " deg per axis, from the per-view offsets against "
              << args.Get("--view-term-from") << ")\n" << viewed.ToText() << std::endl;
  }
  if (args.Has("--per-edge")) {
    std::cout << std::defaultfloat << std::setprecision(10);
    for (std::size_t k = 0; k < raw.scored.size(); ++k) {
      const ra::EdgeCalibration::Edge& e = raw.scored[k];
      std::cout << "edge " << e.name1 << " " << e.name2 << " " << e.error_deg << " " << e.nees << " "
                << floored.scored[k].nees << "\n";
    }
    for (const ra::EdgeCalibration::ViewOffset& v : raw.view_offsets) {
      std::cout << "view " << v.name << " " << v.offset_deg.norm() << " " << v.offset_deg.x() << " "
                << v.offset_deg.y() << " " << v.offset_deg.z() << "\n";
    }
  }
  return 0;
}

int EvalCommand(int argc, char** argv) {
  Args args;
  std::string error;
  if (!ParseArgs(argc, argv, 2, {"--json", "--per-view", "--per-edge"}, &args, &error)) return Fail(error);
  if (!CheckKnown(args, {"--estimate", "--estimate-format", "--gt", "--gt-format", "--graph", "--graph-format",
                         "--floor-deg", "--view-term-from"},
                  &error)) {
    return Fail(error);
  }
  if (!args.Has("--gt") || (!args.Has("--estimate") && !args.Has("--graph"))) {
    return Fail("eval needs --gt and --estimate or --graph (or both)\n" + std::string(kUsage));
  }
  if (args.Has("--graph")) {
    if (args.Has("--json")) return Fail("--json scores an --estimate; the edge calibration of --graph is text only");
    ra::NamedOrientations gt;
    if (!ReadGroundTruthArg(args.Get("--gt"), args.Get("--gt-format", "auto"), &gt, &error)) return Fail(error);
    const int rc = EvalGraph(args, gt);
    if (rc != 0 || !args.Has("--estimate")) return rc;
    std::cout << "\n";
  }
  // Another tool's reconstruction (COLMAP's images.txt) is scored by the same
  // alignment and errors as ours.
  const std::string estimate_format = args.Get("--estimate-format", "csv");
  ra::NamedOrientations estimate;
  ra::ReadReport report;
  if (estimate_format == "csv") {
    report = ra::ReadOrientationsCsv(args.Get("--estimate"), &estimate);
  } else if (estimate_format == "colmap") {
    report = ra::ReadColmapGroundTruth(args.Get("--estimate"), &estimate);
  } else {
    return Fail("unknown --estimate-format " + estimate_format + " (csv or colmap)");
  }
  if (!report.ok()) return Fail(report.error);
  return Evaluate(estimate, args.Get("--gt"), args.Get("--gt-format", "auto"), args.Has("--json"),
                  args.Has("--per-view"));
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

// Replaces this process by `name` (rotavg_images, rotavg_vocabulary) from the
// same folder, passing the arguments after the command.
int RunProgram(const char* name, int argc, char** argv) {
  std::error_code ec;
  const std::filesystem::path self = std::filesystem::read_symlink("/proc/self/exe", ec);
  const std::filesystem::path program = (ec ? std::filesystem::path(argv[0]) : self).parent_path() / name;
  std::vector<char*> args;
  const std::string program_text = program.string();
  args.push_back(const_cast<char*>(program_text.c_str()));
  for (int k = 2; k < argc; ++k) args.push_back(argv[k]);
  args.push_back(nullptr);
  execv(program_text.c_str(), args.data());
  return Fail("cannot run " + program_text + ": " + std::strerror(errno));
}

}  // namespace

int main(int argc, char** argv) {
  rotation_averaging::KeepFreedMemoryForReuse();  // util/freed_memory.h: buffers of each image reused, not faulted in again
  // The solver holds OpenBLAS to one thread (see src/core/util/backends.h). Said here,
  // before any thread exists, so that OpenBLAS never starts its pool of
  // workers when a solve loads it, nor in the programs this one runs.
  setenv("OPENBLAS_NUM_THREADS", "1", /*overwrite=*/0);
  if (argc < 2 || std::string(argv[1]) == "--help" || std::string(argv[1]) == "-h") {
    std::cout << kUsage;
    return argc < 2 ? 2 : 0;
  }
  const std::string command = argv[1];
  // "rotavg eval --help": the usage, not a complaint that --help has no value.
  if (argc >= 3 && (std::string(argv[2]) == "--help" || std::string(argv[2]) == "-h") && command != "images" &&
      command != "vocabulary") {
    std::cout << kUsage;
    return 0;
  }
  try {
    if (command == "solve") return Solve(argc, argv);
    if (command == "eval") return EvalCommand(argc, argv);
    if (command == "demo") return Demo(argc, argv);
    if (command == "images") return RunProgram("rotavg_images", argc, argv);
    if (command == "vocabulary") return RunProgram("rotavg_vocabulary", argc, argv);
  } catch (const std::exception& e) {
    return Fail(e.what());
  }
  return Fail("unknown command '" + command + "'\n" + kUsage);
}
