// rotavg_benchmark: speed, memory and accuracy of the rotation averaging
// solvers on the real graphs in ../shared/data and on synthetic graphs.
//
//   rotavg_benchmark [--data DIR] [--repeats N] [--output results/core_benchmark.md] [--quick]
//
// Times are of the solve alone (no file reading), single-threaded, median of
// N runs in this process. Peak memory is the maximum resident set size of a
// child process that reads the graph and solves it once (its own VmHWM).
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <sstream>
#include <thread>
#include <string>
#include <unordered_map>
#include <vector>

#include "core/linalg/block_sparse_system.h"
#include "rotation_averaging/core/estimators/rotation_averaging.h"
#include "rotation_averaging/core/eval/rotation_evaluation.h"
#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/core/io/graph_io.h"
#include "rotation_averaging/core/io/orientation_io.h"
#include "rotation_averaging/core/scene/synthetic_graph.h"
#include "report.h"

namespace ra = rotation_averaging;
namespace fs = std::filesystem;
using rotation_averaging::Fixed;
using rotation_averaging::Median;

namespace {

struct Dataset {
  std::string name, path;
  double glomap_s;  // GLOMAP 1.1.0's rotation averager on this machine type (reference figure; not run here)
};

std::vector<Dataset> RealDatasets(const std::string& data_dir) {
  return {
      {"Madrid Metropolis (1DSfM)", data_dir + "/relative_rotations/madrid_metropolis", 0.62},
      {"iRotAvg input", data_dir + "/relative_rotations/irotavg/ravg_input.txt", 0.036},
      {"sphere2500 (g2o)", data_dir + "/pose_graphs/sphere2500.g2o", 0.19},
      {"torus3D", data_dir + "/pose_graphs/torus3D.g2o", 2.5},
      {"parking-garage", data_dir + "/pose_graphs/parking-garage.g2o", 0.036},
      {"cubicle", data_dir + "/pose_graphs/cubicle.g2o", 0.49},
  };
}

struct Config {
  std::string label;
  ra::RotationAveragingOptions options;
};

std::vector<Config> Configs() {
  std::vector<Config> configs;
  ra::RotationAveragingOptions fast;  // defaults: IRLS, MAGSAC, covariance weighting
  configs.push_back({"irls magsac+cov", fast});
  ra::RotationAveragingOptions ceres = fast;
  ceres.solver = ra::SolverType::kCeres;
  configs.push_back({"ceres magsac+cov", ceres});
  ra::RotationAveragingOptions l1 = fast;
  l1.solver = ra::SolverType::kL1Irls;
  l1.weighting = ra::EdgeWeighting::kNone;
  configs.push_back({"l1_irls (baseline)", l1});
  return configs;
}


// Child mode: read and solve once, print the peak resident memory, exit.
int RunSingle(const std::string& path, int config_index) {
  ra::ViewGraph graph;
  if (!ra::ReadViewGraph(path, ra::GraphFormat::kAuto, &graph).ok()) return 1;
  ra::ViewOrientations orientations;
  ra::RotationAveragingSummary summary;
  ra::SolveRotationAveraging(graph, Configs()[config_index].options, &orientations, &summary);
  ra::PrintOwnPeakMemory();
  return 0;
}

double PeakMemoryMiB(const char* self, const std::string& path, int config_index) {
  double mib = -1.0;
  return ra::RunChildProcess(self, {"--single", path, std::to_string(config_index)}, nullptr, &mib) ? mib : -1.0;
}


// Entries per column of the Cholesky factor of the graph's 3x3-block normal
// equations (every view a block), as BlockSparseSystem predicts them.
double FactorEntriesPerColumn(const ra::ViewGraph& graph) {
  std::unordered_map<ra::ViewId, int> index;
  for (const ra::RelativeRotation& e : graph.Edges()) {
    index.emplace(e.view1, static_cast<int>(index.size()));
    index.emplace(e.view2, static_cast<int>(index.size()));
  }
  std::vector<std::pair<int, int>> pairs;
  for (const ra::RelativeRotation& e : graph.Edges()) pairs.emplace_back(index.at(e.view1), index.at(e.view2));
  return ra::BlockSparseSystem(static_cast<int>(index.size()), pairs).PredictedFactorEntriesPerColumn();
}

// The same solves with every factorised 3x3-block system through
// BlockCholesky and through CHOLMOD's supernodal factor (multigrid off), on
// graphs whose factors range from thin to dense: where the default of
// block_cholesky_max_column_count comes from.
void FactorisationSection(const std::string& data_dir, bool quick, int repeats, std::ostringstream& md) {
  struct Case {
    std::string name;
    ra::ViewGraph graph;
  };
  std::vector<Case> cases;
  for (const char* name : {"parking-garage", "cubicle"}) {
    Case c{name, {}};
    if (ra::ReadViewGraph(data_dir + "/pose_graphs/" + name + ".g2o", ra::GraphFormat::kAuto, &c.graph).ok())
      cases.push_back(std::move(c));
  }
  // The scale benchmark's anisotropic graphs (1 deg noise spread 10x, 10%
  // outliers), grid locality and degree chosen for a range of densities.
  const struct {
    int views, locality;
    double degree;
  } synthetic[] = {{5000, 3, 3}, {5000, 2, 4}, {5000, 2, 6}, {3000, 2, 8}, {5000, 2, 10}};
  for (const auto& g : synthetic) {
    ra::SyntheticGraphOptions o;
    o.num_views = quick ? g.views / 5 : g.views;
    o.locality = g.locality;
    o.mean_degree = g.degree;
    o.noise_deg = 1.0;
    o.noise_spread = 10.0;
    o.anisotropic = true;
    o.outlier_ratio = 0.1;
    std::ostringstream name;
    name << "synthetic " << o.num_views << " views, degree " << g.degree << ", locality " << g.locality;
    cases.push_back({name.str(), ra::MakeSyntheticGraph(o).graph});
  }
  md << "\n## Factorisation of 3x3-block systems\n\nThe same solve (defaults, multigrid off) with every factorised "
        "3x3-block system through the package's block Cholesky factor (`BlockCholesky`) and through CHOLMOD's "
        "supernodal factor (`block_cholesky_max_column_count` 1e9 and 0); entries per column of the factor as "
        "predicted from the block graph (the figure the default, "
     << ra::RotationAveragingOptions().linear.block_cholesky_max_column_count
     << ", is compared with). Real graphs: median of " << repeats << " solves; synthetic graphs (anisotropic "
     << "covariances as in results/scale.md): one solve each.\n\n"
     << "| graph | views | factor entries per column | BlockCholesky (s) | supernodal (s) | supernodal / BlockCholesky | default takes |\n"
     << "|---|---|---|---|---|---|---|\n";
  for (const Case& c : cases) {
    double seconds[2] = {0.0, 0.0};
    for (int method = 0; method < 2; ++method) {
      ra::RotationAveragingOptions options;
      options.linear.multigrid_min_views = 0;
      options.linear.block_cholesky_max_column_count = method == 0 ? 1e9 : 0.0;
      std::vector<double> times;
      const int runs = c.name.rfind("synthetic", 0) == 0 ? 1 : repeats;
      for (int r = 0; r < runs; ++r) {
        ra::ViewOrientations orientations;
        ra::RotationAveragingSummary summary;
        ra::SolveRotationAveraging(c.graph, options, &orientations, &summary);
        times.push_back(summary.solve_time_s);
      }
      seconds[method] = Median(times);
    }
    const double per_column = FactorEntriesPerColumn(c.graph);
    md << "| " << c.name << " | " << c.graph.NumViews() << " | " << Fixed(per_column, 1) << " | " << Fixed(seconds[0], 3)
       << " | " << Fixed(seconds[1], 3) << " | " << Fixed(seconds[1] / seconds[0], 2) << " | "
       << (per_column <= ra::RotationAveragingOptions().linear.block_cholesky_max_column_count ? "BlockCholesky" : "supernodal")
       << " |\n";
    std::cerr << "factorisation: " << c.name << " " << seconds[0] << " / " << seconds[1] << " s\n";
  }
}

// The solvers on the real graphs of `data_dir`: time, iterations, final cost,
// peak memory, against GLOMAP's reference times.
void RealGraphsSection(const char* self, const std::vector<Dataset>& datasets, bool quick, int repeats,
                       std::ostringstream& md) {
  const std::vector<Config> configs = Configs();
  md << "## Real graphs\n\nGLOMAP 1.1.0 reference times: its rotation averager on a machine of this type (2 cores), "
        "reference figures (GLOMAP is not packaged for Debian; not re-run by this benchmark). Speed-up = GLOMAP time / our time. Madrid and iRotAvg have no covariances, so "
        "covariance weighting falls back to none there.\n\n"
     << "| graph | views | edges | solver | time (s) | iterations | final cost | peak MiB | GLOMAP (s) | speed-up |\n"
     << "|---|---|---|---|---|---|---|---|---|---|\n";
  for (const Dataset& d : datasets) {
    ra::ViewGraph graph;
    const ra::ReadReport report = ra::ReadViewGraph(d.path, ra::GraphFormat::kAuto, &graph);
    if (!report.ok()) {
      md << "| " << d.name << " | - | - | - | read failed: " << report.error << " | | | | | |\n";
      continue;
    }
    for (std::size_t c = 0; c < configs.size(); ++c) {
      if (quick && c == 1 && graph.NumViews() > 3000) continue;  // Ceres on the largest graphs is slow
      std::vector<double> times;
      ra::RotationAveragingSummary summary;
      for (int r = 0; r < repeats; ++r) {
        ra::ViewOrientations orientations;
        ra::SolveRotationAveraging(graph, configs[c].options, &orientations, &summary);
        times.push_back(summary.solve_time_s);
      }
      int iterations = 0;
      double cost = 0.0;
      for (const auto& cs : summary.components) {
        iterations += cs.iterations;
        cost += cs.final_cost;
      }
      const double t = Median(times);
      const double mib = quick ? -1.0 : PeakMemoryMiB(self, d.path, static_cast<int>(c));
      md << "| " << d.name << " | " << graph.NumViews() << " | " << graph.NumEdges() << " | " << configs[c].label
         << " | " << Fixed(t, 4) << " | " << iterations << " | " << std::setprecision(6) << cost << " | "
         << (mib > 0 ? Fixed(mib, 0) : std::string("-")) << " | " << d.glomap_s << " | " << Fixed(d.glomap_s / t, 1)
         << "x |\n";
      std::cerr << d.name << " / " << configs[c].label << ": " << t << " s\n";
    }
  }
}

// What a user of `rotavg solve` waits for: start-up (loading the libraries),
// reading, solving, writing. rotavg links the core library only, which loads
// CHOLMOD and OpenBLAS when a solve first needs them (src/core/util/backends.h):
// inside the solve time of the graphs that do.
void ProcessSection(const char* self, const std::string& data_dir, std::vector<Dataset> timed, int repeats,
                    std::ostringstream& md) {
  const fs::path rotavg = fs::path(self).parent_path() / "rotavg";
  if (!fs::exists(rotavg)) return;
  md << "\n## Reading, and `rotavg solve` as a whole process\n\nRead: `ReadViewGraph` in this process (median of "
     << repeats << "). Whole process: wall time of `rotavg solve GRAPH --output FILE` from posix_spawn to exit (median of "
     << repeats << "), against the read and solve times it prints itself, and its CPU time (user + system, "
     << "all threads); start-up: `rotavg --help`.\n\n"
     << "| graph | read (s) | solve (s) | read / solve | whole process (s) | process / (read + solve) | CPU (s) |\n"
     << "|---|---|---|---|---|---|---|\n";
  const std::string csv = (fs::temp_directory_path() / ("rotavg_benchmark_" + std::to_string(::getpid()) + ".csv")).string();
  const auto process_s = [&](const std::vector<std::string>& args, std::string* out, double* cpu_s = nullptr) {
    const auto start = std::chrono::steady_clock::now();
    if (!ra::RunChildProcess(rotavg.c_str(), args, out, nullptr, cpu_s)) return -1.0;
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  };
  const auto printed = [](const std::string& out, const std::string& label) {
    const std::size_t at = out.find(label);
    return at == std::string::npos ? -1.0 : std::atof(out.c_str() + at + label.size());
  };
  timed.push_back({"smallGrid3D (125 views)", data_dir + "/pose_graphs/smallGrid3D.g2o", 0.0});
  for (const Dataset& d : timed) {
    std::vector<double> reads, processes, printed_read, printed_solve, cpus;
    for (int r = 0; r < repeats; ++r) {
      ra::ViewGraph graph;
      const auto start = std::chrono::steady_clock::now();
      if (!ra::ReadViewGraph(d.path, ra::GraphFormat::kAuto, &graph).ok()) break;
      reads.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
      std::string out;
      double cpu = 0.0;
      const double wall = process_s({"solve", d.path, "--output", csv}, &out, &cpu);
      if (wall < 0.0) break;
      processes.push_back(wall);
      cpus.push_back(cpu);
      printed_read.push_back(printed(out, "read time: "));
      printed_solve.push_back(printed(out, "solve time: "));
    }
    if (processes.empty()) {
      md << "| " << d.name << " | failed | | | | | |\n";
      continue;
    }
    const double read = Median(printed_read), solve = Median(printed_solve), whole = Median(processes);
    md << "| " << d.name << " | " << Fixed(Median(reads), 4) << " | " << Fixed(solve, 4) << " | "
       << Fixed(Median(reads) / solve, 2) << " | " << Fixed(whole, 4) << " | " << Fixed(whole / (read + solve), 2)
       << " | " << Fixed(Median(cpus), 4) << " |\n";
  }
  std::remove(csv.c_str());
  std::vector<double> startups;
  for (int r = 0; r < std::max(repeats, 5); ++r) startups.push_back(process_s({"--help"}, nullptr));
  md << "\nStart-up of `rotavg` (`rotavg --help`, median of " << startups.size() << "): "
     << Fixed(1000.0 * Median(startups), 1) << " ms.\n";
}

// The noisy sphere2500 solved and scored against its chained noise-free
// ground truth.
void Sphere2500Section(const std::string& data_dir, std::ostringstream& md) {
  ra::NamedOrientations gt;
  const std::string gt_path = data_dir + "/pose_graphs/sphere2500_groundtruth.txt";
  if (!ra::ReadChainedGroundTruth(gt_path, ra::GraphFormat::kToro, &gt).ok()) return;
  md << "\n## sphere2500 accuracy\n\nNoisy `sphere2500.txt` (TORO, covariances from its information matrices) "
        "solved and scored against the chained noise-free `sphere2500_groundtruth.txt`. Target: median <= 1.6 deg "
        "(a least-squares fit started at ground truth reaches about 1.58).\n\n"
     << "| solver | loss | weighting | median (deg) | mean (deg) | AUC@2 | AUC@5 |\n|---|---|---|---|---|---|---|\n";
  ra::ViewGraph graph;
  ra::ReadViewGraph(data_dir + "/pose_graphs/sphere2500.txt", ra::GraphFormat::kToro, &graph);
  std::vector<Config> accuracy = Configs();
  ra::RotationAveragingOptions squared_none;
  squared_none.loss = ra::LossType::kSquared;
  squared_none.weighting = ra::EdgeWeighting::kNone;
  accuracy.push_back({"irls squared+none", squared_none});
  ra::RotationAveragingOptions squared_cov;
  squared_cov.loss = ra::LossType::kSquared;
  accuracy.push_back({"irls squared+cov", squared_cov});
  for (const Config& c : accuracy) {
    ra::ViewOrientations orientations;
    ra::RotationAveragingSummary summary;
    ra::SolveRotationAveraging(graph, c.options, &orientations, &summary);
    const ra::EvaluationResult e = ra::EvaluateOrientations(ra::NameOrientations(graph, orientations), gt);
    md << "| " << ra::SolverTypeName(c.options.solver) << " | "
       << (c.options.solver == ra::SolverType::kL1Irls ? "l1 + geman_mcclure" : ra::LossTypeName(c.options.loss))
       << " | " << ra::EdgeWeightingName(c.options.weighting) << " | " << Fixed(e.median_error_deg, 3) << " | "
       << Fixed(e.mean_error_deg, 3) << " | " << Fixed(100 * e.auc[0].second, 1) << " | "
       << Fixed(100 * e.auc[1].second, 1) << " |\n";
  }
}

// Accuracy on synthetic graphs with known truth: the paper's start against
// ours, for a few losses and weightings.
void SyntheticSection(bool quick, std::ostringstream& md) {
  md << "\n## Synthetic graphs (ground truth known)\n\n";
  struct Scenario {
    std::string name;
    ra::SyntheticGraphOptions graph;
  };
  std::vector<Scenario> scenarios;
  {
    ra::SyntheticGraphOptions o;
    o.num_views = quick ? 200 : 500;
    o.noise_deg = 3.0;
    o.outlier_ratio = 0.2;
    scenarios.push_back({"3 deg noise, 20% outliers", o});
    for (double ratio : {0.2, 0.35}) {
      ra::SyntheticGraphOptions a = o;
      a.num_views = 300;
      a.outlier_ratio = ratio;
      a.noise_spread = 3.0;
      a.anisotropic = true;
      scenarios.push_back({"300 views, 3 deg x [1/3, 3] anisotropic noise, " + std::to_string(int(100 * ratio)) +
                               "% outliers",
                           a});
    }
    ra::SyntheticGraphOptions v = o;
    v.outlier_ratio = 0.1;
    v.noise_deg = 1.0;
    v.noise_spread = 10.0;
    v.anisotropic = true;
    scenarios.push_back({"1 deg x [0.1, 10] anisotropic noise, 10% outliers", v});
  }
  md << "Start: `tree` is the paper's (maximum spanning tree, robust loss at its final scale); `L1+GNC` is ours "
        "(L1 refinement of the tree, then graduated non-convexity, both skipped when the tree agrees with >= 98% of "
        "edges). Views off: views more than 10 deg from ground truth, summed over the seeds.\n\n| scenario | loss | weighting | start | median (deg) | AUC@2 | AUC@5 | AUC@10 | views off |\n|---|---|---|---|---|---|---|---|---|\n";
  for (const Scenario& s : scenarios) {
    const int seeds = quick ? 1 : 3;
    struct Row {
      ra::LossType loss;
      ra::EdgeWeighting weighting;
      bool robust_start;
    };
    const std::vector<Row> rows = {{ra::LossType::kSquared, ra::EdgeWeighting::kNone, false},
                                   {ra::LossType::kSquared, ra::EdgeWeighting::kCovariance, false},
                                   {ra::LossType::kHuber, ra::EdgeWeighting::kCovariance, false},
                                   {ra::LossType::kCauchy, ra::EdgeWeighting::kCovariance, false},
                                   {ra::LossType::kMagsac, ra::EdgeWeighting::kNone, true},
                                   {ra::LossType::kMagsac, ra::EdgeWeighting::kCovariance, false},
                                   {ra::LossType::kMagsac, ra::EdgeWeighting::kCovariance, true}};
    // Rows with robust_start = false use the paper's start: the tree alone.
    for (const Row& row : rows) {
      std::vector<double> medians, auc2, auc5, auc10;
      int views_off = 0;
      for (int seed = 1; seed <= seeds; ++seed) {
        ra::SyntheticGraphOptions go = s.graph;
        go.seed = seed;
        const ra::SyntheticGraph sg = ra::MakeSyntheticGraph(go);
        ra::RotationAveragingOptions o;
        o.loss = row.loss;
        o.weighting = row.weighting;
        o.robust_start.gnc_initial_scale_factor = row.robust_start ? 8.0 : 1.0;
        o.robust_start.l1_initialization = row.robust_start;
        ra::ViewOrientations orientations;
        ra::RotationAveragingSummary summary;
        ra::SolveRotationAveraging(sg.graph, o, &orientations, &summary);
        const ra::EvaluationResult e = ra::EvaluateOrientations(ra::NameOrientations(sg.graph, orientations),
                                                                ra::NameOrientations(sg.graph, sg.ground_truth));
        medians.push_back(e.median_error_deg);
        for (const auto& [name, error] : e.errors_deg) views_off += error > 10.0;
        views_off += static_cast<int>(e.views_in_ground_truth - e.views_common);
        auc2.push_back(e.auc[0].second);
        auc5.push_back(e.auc[1].second);
        auc10.push_back(e.auc[2].second);
      }
      md << "| " << s.name << " | " << ra::LossTypeName(row.loss) << " | " << ra::EdgeWeightingName(row.weighting)
         << " | " << (row.robust_start ? "L1+GNC" : "tree") << " | " << Fixed(Median(medians), 3) << " | "
         << Fixed(100 * Median(auc2), 1) << " | " << Fixed(100 * Median(auc5), 1) << " | "
         << Fixed(100 * Median(auc10), 1) << " | " << views_off << " |\n";
    }
  }
  md << "\nSynthetic rows: median over " << (quick ? 1 : 3) << " seeds.\n";
}

// The paper's loss x weighting table on synthetic graphs.
void PaperTableSection(bool quick, std::ostringstream& md) {
  ra::SyntheticGraphOptions go;
  go.num_views = quick ? 100 : 300;
  go.noise_deg = 1.0;
  go.noise_spread = 10.0;
  go.anisotropic = true;
  go.outlier_ratio = 0.1;
  const int seeds = quick ? 1 : 3;
  const std::vector<ra::LossType>& losses = ra::PaperTableLosses();
  const std::vector<ra::EdgeWeighting>& weightings = ra::PaperTableWeightings();
  md << "\n## Loss x weighting (synthetic)\n\nThe paper's table on synthetic graphs with known truth: " << go.num_views
     << " views, mean degree 10, 1 deg x [1/10, 10] anisotropic noise per edge with its true covariance, 10% outlier "
        "edges, inlier counts all equal (so inlier weighting is no weighting). Each cell: median error (deg) / AUC@2 / "
        "AUC@5 / AUC@10 / AUC@20 (percent), medians over "
     << seeds << " seeds. Our default start (L1 + GNC) for every loss.\n\n| loss |";
  for (ra::EdgeWeighting w : weightings) md << " " << ra::EdgeWeightingName(w) << " |";
  md << "\n|---|";
  for (std::size_t k = 0; k < weightings.size(); ++k) md << "---|";
  md << "\n";
  std::vector<ra::SyntheticGraph> graphs;
  for (int seed = 1; seed <= seeds; ++seed) {
    go.seed = 100 + seed;
    graphs.push_back(ra::MakeSyntheticGraph(go));
  }
  for (ra::LossType loss : losses) {
    md << "| " << ra::LossTypeName(loss) << " |";
    for (ra::EdgeWeighting w : weightings) {
      std::vector<double> median, auc[4];
      for (const ra::SyntheticGraph& sg : graphs) {
        ra::RotationAveragingOptions o;
        o.loss = loss;
        o.weighting = w;
        ra::ViewOrientations orientations;
        ra::RotationAveragingSummary summary;
        ra::SolveRotationAveraging(sg.graph, o, &orientations, &summary);
        const ra::EvaluationResult e =
            ra::EvaluateOrientations(ra::NameOrientations(sg.graph, orientations),
                                     ra::NameOrientations(sg.graph, sg.ground_truth), {2.0, 5.0, 10.0, 20.0});
        median.push_back(e.median_error_deg);
        for (int t = 0; t < 4; ++t) auc[t].push_back(100.0 * e.auc[t].second);
      }
      md << " " << Fixed(Median(median), 2);
      for (int t = 0; t < 4; ++t) md << " / " << Fixed(Median(auc[t]), 0);
      md << " |";
    }
    md << "\n";
  }
}

}  // namespace

int main(int argc, char** argv) {
  std::string data_dir, output = "results/core_benchmark.md";
  int repeats = 5;
  bool quick = false;
  for (int k = 1; k < argc; ++k) {
    const std::string a = argv[k];
    if (a == "--single" && k + 2 < argc) return RunSingle(argv[k + 1], std::atoi(argv[k + 2]));
    if (a == "--data" && k + 1 < argc) data_dir = argv[++k];
    else if (a == "--repeats" && k + 1 < argc) repeats = std::max(1, std::atoi(argv[++k]));
    else if (a == "--output" && k + 1 < argc) output = argv[++k];
    else if (a == "--quick") quick = true;
    else {
      std::cerr << "usage: rotavg_benchmark [--data DIR] [--repeats N] [--output FILE] [--quick]\n";
      return 2;
    }
  }
  const std::string command = ra::CommandLine("rotavg_benchmark", argc, argv);
  if (quick) repeats = 1;

  std::ostringstream md;
  const std::time_t now = std::time(nullptr);
  md << "# Core solver benchmark\n\nReproduce with: `" << command << "` (built by `scripts/benchmark_core.sh`).\n"
     << "Generated " << std::put_time(std::gmtime(&now), "%Y-%m-%d %H:%M UTC") << " on a " << std::thread::hardware_concurrency()
     << "-core machine. Single-threaded; solve time excludes file reading; median of " << repeats
     << " runs. Peak memory: maximum RSS of a child process that reads and solves once.\n\n";
  if (data_dir.empty() || !fs::exists(data_dir)) {
    md << "Real graphs skipped: data folder not given or absent (pass --data ../shared/data).\n\n";
  } else {
    const std::vector<Dataset> datasets = RealDatasets(data_dir);
    RealGraphsSection(argv[0], datasets, quick, repeats, md);
    FactorisationSection(data_dir, quick, repeats, md);
    ProcessSection(argv[0], data_dir, datasets, repeats, md);
    Sphere2500Section(data_dir, md);
  }
  SyntheticSection(quick, md);
  PaperTableSection(quick, md);
  ra::WriteReport(output, md.str());
  return 0;
}
