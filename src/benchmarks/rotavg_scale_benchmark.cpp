// rotavg_scale_benchmark: how the fast solver scales with the number of views,
// and how quickly the online averager answers as a keyframe graph grows.
//
//   rotavg_scale_benchmark [--sizes 1000,10000,100000,1000000] [--online-keyframes 10000]
//                          [--online-additions 100] [--online-rate 10] [--anisotropic-max 100000]
//                          [--only scale|online] [--output results/scale.md] [--quick]
//
// Scale: synthetic graphs (mean degree 10, 10% outlier edges, noise of 1 deg x
// [1/10, 10] per edge with matching covariances, isotropic or anisotropic,
// views on a square grid with edges to views within 3 cells, as a city-scale
// capture), each generated and solved once (IRLS, MAGSAC, covariance weights)
// in a child process whose peak resident memory the parent reads (wait4's
// rusage).
// Online: see OnlineSection below.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <iomanip>
#include <iostream>
#include <random>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "rotation_averaging/core/controllers/online_averager.h"
#include "rotation_averaging/core/estimators/rotation_averaging.h"
#include "rotation_averaging/core/eval/rotation_evaluation.h"
#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/core/io/orientation_io.h"
#include "rotation_averaging/util/text_lines.h"
#include "rotation_averaging/core/scene/synthetic_graph.h"
#include "report.h"
#include "rotation_averaging/util/random_draws.h"
#include "rotation_averaging/util/time_distribution.h"

namespace ra = rotation_averaging;
using ra::Fixed;
using ra::Median;

namespace {

using Clock = std::chrono::steady_clock;
using ra::SecondsSince;


ra::SyntheticGraphOptions ScaleGraph(int views, bool anisotropic) {
  ra::SyntheticGraphOptions o;
  o.anisotropic = anisotropic;
  o.num_views = views;
  o.mean_degree = 10.0;
  o.noise_deg = 1.0;
  o.noise_spread = 10.0;
  o.outlier_ratio = 0.1;
  o.locality = 3;
  o.seed = 7;
  return o;
}

struct ScaleRun {
  int views = 0;
  std::size_t edges = 0;
  double generate_s = 0, solve_s = 0, median_deg = 0, peak_mib = -1, final_cost = 0;
  int iterations = 0, factorizations = 0, multigrid_solves = 0;
  std::size_t views_off = 0;
  bool ok = false;
};

// Child: generate, solve once, evaluate; one line on stdout. Without
// multigrid: every linear system through the sparse Cholesky factor (the
// baseline rows). Anisotropic: random principal axes and per-axis noise.
// multigrid_tolerance > 0 replaces the default multigrid_linear_solve_tolerance.
int RunChild(int views, bool multigrid, bool anisotropic, double multigrid_tolerance) {
  auto start = Clock::now();
  const ra::SyntheticGraph sg = ra::MakeSyntheticGraph(ScaleGraph(views, anisotropic));
  const double generate_s = SecondsSince(start);
  ra::ViewOrientations orientations;
  ra::RotationAveragingSummary summary;
  ra::RotationAveragingOptions options;
  if (!multigrid) options.linear.multigrid_min_views = 0;
  if (multigrid_tolerance > 0.0) options.linear.multigrid_linear_solve_tolerance = multigrid_tolerance;
  ra::SolveRotationAveraging(sg.graph, options, &orientations, &summary);
  int iterations = 0, factorizations = 0, multigrid_solves = 0;
  double final_cost = 0.0;
  for (const auto& c : summary.components) {
    final_cost += c.final_cost;
    iterations += c.iterations;
    factorizations += c.factorizations;
    multigrid_solves += c.multigrid_solves;
  }
  const ra::EvaluationResult e = ra::EvaluateOrientations(ra::NameOrientations(sg.graph, orientations),
                                                          ra::NameOrientations(sg.graph, sg.ground_truth));
  std::size_t off = e.views_in_ground_truth - e.views_common;
  for (const auto& [name, error] : e.errors_deg) off += error > 10.0;
  std::printf("%zu %.6f %.6f %d %d %d %.6f %zu %.12g\n", sg.graph.NumEdges(), generate_s, summary.solve_time_s,
              iterations, factorizations, multigrid_solves, e.median_error_deg, off, final_cost);
  std::fflush(stdout);
  ra::PrintOwnPeakMemory();
  return 0;
}

ScaleRun RunScale(const char* self, int views, bool multigrid, bool anisotropic, double multigrid_tolerance = 0.0) {
  ScaleRun run;
  run.views = views;
  std::string out;
  std::vector<std::string> args = {"--child", std::to_string(views)};
  if (!multigrid) args.push_back("--no-multigrid");
  if (anisotropic) args.push_back("--anisotropic");
  if (multigrid_tolerance > 0.0) {
    std::ostringstream tolerance;
    tolerance << multigrid_tolerance;
    args.insert(args.end(), {"--multigrid-tolerance", tolerance.str()});
  }
  if (!ra::RunChildProcess(self, args, &out, &run.peak_mib)) return run;
  std::istringstream line(out);
  run.ok = static_cast<bool>(line >> run.edges >> run.generate_s >> run.solve_s >> run.iterations >>
                             run.factorizations >> run.multigrid_solves >> run.median_deg >> run.views_off >>
                             run.final_cost);
  return run;
}

// Least-squares slope of log(y) against log(x).
double GrowthExponent(const std::vector<double>& x, const std::vector<double>& y) {
  double mx = 0, my = 0;
  for (std::size_t k = 0; k < x.size(); ++k) {
    mx += std::log(x[k]) / x.size();
    my += std::log(y[k]) / x.size();
  }
  double sxy = 0, sxx = 0;
  for (std::size_t k = 0; k < x.size(); ++k) {
    sxy += (std::log(x[k]) - mx) * (std::log(y[k]) - my);
    sxx += (std::log(x[k]) - mx) * (std::log(x[k]) - mx);
  }
  return sxx > 0 ? sxy / sxx : NAN;
}

struct ScaleSeries {
  std::vector<double> x, t, m;  // views, solve time, peak memory of the multigrid rows
};

// The growth exponents of solve time and peak memory, per kind of covariance.
std::string GrowthExponents(const ScaleSeries series[2]) {
  std::ostringstream md;
  bool first = true;
  for (const bool anisotropic : {false, true}) {
    const ScaleSeries& s = series[anisotropic];
    if (s.x.size() < 2) continue;
    const std::size_t k = s.x.size();
    md << (first ? "\n" : "") << "Growth exponents, " << (anisotropic ? "anisotropic" : "isotropic")
       << " (least-squares slope of log against log views, multigrid rows): solve time "
       << Fixed(GrowthExponent(s.x, s.t), 2) << ", peak memory " << Fixed(GrowthExponent(s.x, s.m), 2)
       << "; between the two largest sizes: time " << Fixed(std::log(s.t[k - 1] / s.t[k - 2]) / std::log(s.x[k - 1] / s.x[k - 2]), 2)
       << ", memory " << Fixed(std::log(s.m[k - 1] / s.m[k - 2]) / std::log(s.x[k - 1] / s.x[k - 2]), 2) << ".\n";
    first = false;
  }
  return md.str();
}

// The multigrid systems' tolerance against a hundredfold tighter one, on
// the same graphs: the justification of multigrid_linear_solve_tolerance.
// The default is run again here, beside the tight one, so that the two
// times of a pair come from adjacent runs. One table row per run.
std::vector<std::string> ToleranceRows(const char* self, const std::vector<int>& sizes, int anisotropic_max_views) {
  std::vector<std::string> tolerance_rows;
  const double default_tolerance = ra::RotationAveragingOptions().linear.multigrid_linear_solve_tolerance;
  for (int n : sizes) {
    if (n < 10000 || n > 100000) continue;
    for (const bool anisotropic : {false, true}) {
      if (anisotropic && n > anisotropic_max_views) continue;
      std::ostringstream rows;
      for (const double tolerance : {default_tolerance, default_tolerance / 100.0}) {
        const bool is_default = tolerance == default_tolerance;
        std::cerr << "scale: " << n << " views, " << (anisotropic ? "anisotropic" : "isotropic") << ", tolerance "
                  << tolerance << " ..." << std::flush;
        const ScaleRun r = RunScale(self, n, true, anisotropic, is_default ? 0.0 : tolerance);
        std::cerr << (r.ok ? " " + Fixed(r.solve_s, 2) + " s\n" : " failed\n");
        std::ostringstream t;
        t << tolerance;
        rows << "| " << n << " | " << (anisotropic ? "anisotropic" : "isotropic") << " | " << t.str()
             << (is_default ? " (default)" : "") << " | ";
        if (r.ok) {
          rows << Fixed(r.solve_s, 3) << " | " << r.iterations << " | " << ra::Significant(r.final_cost, 9) << " | "
               << Fixed(r.median_deg, 3) << " | " << r.views_off << " |\n";
        } else {
          rows << "failed | | | | |\n";
        }
      }
      tolerance_rows.push_back(rows.str());
    }
  }
  return tolerance_rows;
}

std::string ScaleSection(const char* self, const std::vector<int>& sizes, int anisotropic_max_views) {
  std::ostringstream md;
  md << "## Scale\n\nSynthetic graphs: mean degree 10, 10% outlier edges (random rotations carrying an inlier's "
        "covariance), noise 1 deg x [1/10, 10] per edge with matching covariances, views on a square grid joined to "
        "views within 3 cells (a city-scale capture's locality; a graph whose edges join random views anywhere has a "
        "nearly dense Cholesky factor). Covariances **isotropic** (the same standard deviation about every axis: "
        "every linear system a scalar Laplacian), or **anisotropic** (random principal axes, a factor in [1/10, 10] "
        "per axis: the paper's full 3x3 covariance weighting, every system of the robust solve 3x3 blocks), same "
        "graphs otherwise; anisotropic rows up to "
     << anisotropic_max_views
     << " views. One solve each: IRLS, MAGSAC, covariance weights, L1 start and graduated non-convexity, "
        "single-threaded. Peak memory: maximum RSS of the child process that generates the graph and solves it (the "
        "generator's own data included). Linear systems of 2,000+ views (`multigrid_min_views`) are solved by "
        "multigrid-preconditioned CG (AggregationAmg: Setup for scalar systems, SetupBlocks for 3x3 blocks), smaller "
        "ones through the sparse Cholesky factor; the \"factorisation only\" rows solve the same graph with multigrid "
        "off (`multigrid_min_views = 0`: every system through the sparse Cholesky factor), in the same run. Targets: "
        "isotropic 100,000 views in under 10 s, 1,000,000 views within 24 GiB; anisotropic 10,000 views in under "
        "1.5 s and 100,000 in under 15 s, with the median error and views off of the factorisation.\n\n"
     << "| views | covariances | edges | generate (s) | solve (s) | IRLS iterations | factorisations | multigrid "
        "solves | peak memory (MiB) | final cost | median error (deg) | views > 10 deg off |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  ScaleSeries series[2];  // isotropic, anisotropic
  auto row = [&](int n, bool anisotropic, bool multigrid) {
    const std::string kind = anisotropic ? "anisotropic" : "isotropic";
    std::cerr << "scale: " << n << " views, " << kind << (multigrid ? "" : " (factorisation only)") << " ..."
              << std::flush;
    const ScaleRun r = RunScale(self, n, multigrid, anisotropic);
    std::cerr << (r.ok ? " " + Fixed(r.solve_s, 2) + " s, " + Fixed(r.peak_mib, 0) + " MiB\n" : " failed\n");
    const std::string label = std::to_string(n) + (multigrid ? "" : " (factorisation only)");
    if (!r.ok) {
      md << "| " << label << " | " << kind << " | - | - | failed (child process did not finish) | | | | | | | |\n";
      return r;
    }
    md << "| " << label << " | " << kind << " | " << r.edges << " | " << Fixed(r.generate_s, 2) << " | "
       << Fixed(r.solve_s, 3) << " | " << r.iterations << " | " << r.factorizations << " | " << r.multigrid_solves
       << " | " << Fixed(r.peak_mib, 0) << " | " << ra::Significant(r.final_cost, 9) << " | " << Fixed(r.median_deg, 3) << " | "
       << r.views_off << " |\n";
    return r;
  };
  for (int n : sizes) {
    for (const bool anisotropic : {false, true}) {
      if (anisotropic && n > anisotropic_max_views) continue;
      const ScaleRun r = row(n, anisotropic, true);
      if (!r.ok) continue;
      ScaleSeries& s = series[anisotropic];
      s.x.push_back(n);
      s.t.push_back(r.solve_s);
      s.m.push_back(r.peak_mib);
      // The baseline beside it where multigrid was used, up to 100,000 views
      // (1,000,000 through the factor took 12 minutes).
      if (r.multigrid_solves > 0 && n <= 100000) row(n, anisotropic, false);
    }
  }
  const std::vector<std::string> tolerance_rows = ToleranceRows(self, sizes, anisotropic_max_views);
  md << GrowthExponents(series);
  if (!tolerance_rows.empty()) {
    md << "\n### Multigrid solve tolerance\n\nEach IRLS step solves its linear system by multigrid-preconditioned CG "
          "only to the relative residual `multigrid_linear_solve_tolerance`: IRLS itself converges linearly, so a "
          "step more accurate than its own contraction per iteration buys nothing (inexact Newton, Eisenstat and "
          "Walker 1996). The same graphs solved with the default and with a hundredfold tighter tolerance; the "
          "final cost (robust cost at the solution) shows whether the looser solves end at the same minimum.\n\n"
          "| views | covariances | tolerance | solve (s) | IRLS iterations | final cost | median error (deg) | "
          "views > 10 deg off |\n|---|---|---|---|---|---|---|---|\n";
    for (const std::string& rows : tolerance_rows) md << rows;
  }
  return md.str();
}

// Online: a keyframe graph (one camera; edges to the previous two keyframes,
// a loop closure to a keyframe 60-96 back every 25 and to a random older one
// every 50, 5% outlier edges, per-edge
// noise 0.3 deg x [0.6, 1.6] with matching covariances) of `keyframes`
// keyframes is solved cold; then keyframes are added one at a time, each
// followed by SolveNow (a warm-started solve of the whole graph, as the node's
// worker runs it). Time to an updated solution = the SolveNow call.
struct OnlineRun {
  std::vector<double> ms;
  double cold_s = 0, incremental_median_deg = 0, full_median_deg = 0, median_difference_deg = 0;
  int incremental_off = 0, full_off = 0, differ = 0;
  int local_solves = 0, background_solves = 0;
};

struct OnlineMode {
  std::string label;
  bool anisotropic;  // edge covariances with random principal axes (3x3 blocks) or isotropic
  bool local;       // local re-solves (OnlineAveragerOptions::local_solve_min_views default) or every solve full
  bool background;  // periodic full solves in the background
  double warm_fraction;
  int covariances;
  bool compare_tree_start = true;  // RobustStartOptions::compare_tree_start
};

OnlineRun RunOnline(int keyframes, int additions, double rate_hz, const OnlineMode& mode) {
  std::mt19937 rng(3);
  std::normal_distribution<double> n01(0.0, 1.0), walk(0.0, 0.05);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  std::vector<Eigen::Matrix3d> truth;
  Eigen::Matrix3d r = Eigen::Matrix3d::Identity();
  for (int i = 0; i < keyframes + additions; ++i) {
    truth.push_back(r);
    r = ra::ExpSO3(ra::DrawVector3(rng, walk) + Eigen::Vector3d(0.0, 0.0, 0.05)) * r;
  }
  std::vector<ra::KeyframeRelativeRotation> all;
  auto key = [](int i) { return ra::KeyframeKey{"cam", 1'000'000'000LL + 100'000'000LL * i}; };
  auto edge = [&](int i, int j, ra::EdgeSource source) {
    ra::KeyframeRelativeRotation m;
    m.keyframe1 = key(i);
    m.keyframe2 = key(j);
    // Standard deviation per principal axis (one for all three when
    // isotropic), principal axes random when anisotropic.
    const double sd = ra::DegToRad(0.3) * std::exp(0.5 * n01(rng));
    Eigen::Vector3d sds = Eigen::Vector3d::Constant(sd);
    Eigen::Matrix3d axes = Eigen::Matrix3d::Identity();
    if (mode.anisotropic) {
      for (int a = 1; a < 3; ++a) sds(a) = ra::DegToRad(0.3) * std::exp(0.5 * n01(rng));
      axes = ra::ExpSO3(ra::DrawVector3(rng, n01));
    }
    const Eigen::Vector3d noise = ra::DrawVector3(rng, n01);
    m.rotation = truth[i] * truth[j].transpose() * ra::ExpSO3(axes * sds.cwiseProduct(noise));
    if (unit(rng) < 0.05) m.rotation = m.rotation * ra::ExpSO3(Eigen::Vector3d(1.0, 0.5, 0.0));
    m.has_covariance = true;
    m.covariance = axes * sds.cwiseAbs2().asDiagonal() * axes.transpose();
    m.num_inliers = 100;
    m.source = source;
    all.push_back(m);
    return m;
  };
  auto keyframe_edges = [&](int k) {
    std::vector<ra::KeyframeRelativeRotation> edges;
    if (k >= 1) edges.push_back(edge(k - 1, k, ra::EdgeSource::kSequential));
    if (k >= 2) edges.push_back(edge(k - 2, k, ra::EdgeSource::kSequential));
    if (k >= 100 && k % 25 == 0) edges.push_back(edge(k - 60 - k % 37, k, ra::EdgeSource::kOther));
    // Revisits of places seen long before keep the drift bounded, as in a
    // mapping run that crosses its own path.
    if (k >= 200 && k % 50 == 10) edges.push_back(edge(static_cast<int>(unit(rng) * (k - 100)), k, ra::EdgeSource::kOther));
    return edges;
  };
  ra::OnlineAveragerOptions options;
  options.solve_period_s = 0.0;
  options.max_queue = std::size_t{1} << 30;  // the initial graph arrives in one go
  options.averaging.posterior_covariance_max_views = mode.covariances;
  options.averaging.robust_start.warm_start_min_fraction = mode.warm_fraction;
  options.averaging.robust_start.compare_tree_start = mode.compare_tree_start;
  if (!mode.local) options.local_solve_min_views = 0;
  options.background_full_solves = mode.background;
  ra::OnlineAverager averager(options);
  for (int k = 0; k < keyframes; ++k) {
    for (const auto& m : keyframe_edges(k)) averager.AddRelativeRotation(m);
  }
  OnlineRun run;
  auto start = Clock::now();
  averager.SolveNow();
  run.cold_s = SecondsSince(start);
  // Keyframes arrive at rate_hz (a mapping front end's keyframe rate); the
  // time to each updated solution is measured from the keyframe's arrival.
  auto arrival = Clock::now();
  const auto interval = std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(1.0 / rate_hz));
  for (int k = keyframes; k < keyframes + additions; ++k) {
    const auto edges = keyframe_edges(k);
    arrival += interval;
    std::this_thread::sleep_until(arrival);
    start = Clock::now();
    for (const auto& m : edges) averager.AddRelativeRotation(m);
    averager.SolveNow();
    run.ms.push_back(1e3 * SecondsSince(start));
    if (Clock::now() > arrival) arrival = Clock::now();  // a slow update delays the next keyframe, not stacks them
  }
  const ra::OnlineAveragerStats stats = averager.Stats();
  run.local_solves = static_cast<int>(stats.local_solves);
  run.background_solves = static_cast<int>(stats.background_solves);
  // The same graph solved cold, and both scored against the truth.
  ra::OnlineAveragerOptions full_options = options;
  full_options.local_solve_min_views = 0;
  ra::OnlineAverager full(full_options);
  for (const auto& m : all) full.AddRelativeRotation(m);
  full.SolveNow();
  ra::NamedOrientations gt, incremental, cold;
  for (int i = 0; i < keyframes + additions; ++i) gt[ra::OnlineAverager::KeyframeName(key(i))] = truth[i];
  for (const auto& [k, rot] : averager.Solution()->orientations) incremental[ra::OnlineAverager::KeyframeName(k)] = rot;
  for (const auto& [k, rot] : full.Solution()->orientations) cold[ra::OnlineAverager::KeyframeName(k)] = rot;
  const ra::EvaluationResult ei = ra::EvaluateOrientations(incremental, gt), ef = ra::EvaluateOrientations(cold, gt);
  run.incremental_median_deg = ei.median_error_deg;
  run.full_median_deg = ef.median_error_deg;
  for (const auto& [name, e] : ei.errors_deg) run.incremental_off += e > 5.0;
  for (const auto& [name, e] : ef.errors_deg) run.full_off += e > 5.0;
  const ra::EvaluationResult between = ra::EvaluateOrientations(incremental, cold);
  run.median_difference_deg = between.median_error_deg;
  for (const auto& [name, e] : between.errors_deg) run.differ += e > 1.0;
  return run;
}

double Percentile(std::vector<double> v, double p) {
  if (v.empty()) return NAN;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, static_cast<std::size_t>(std::ceil(p * v.size())) - 1)];
}

std::string OnlineSection(int keyframes, int additions, double rate_hz) {
  std::ostringstream md;
  md << "\n## Online re-solve\n\nA keyframe graph of " << keyframes
     << " keyframes (one camera; edges to the previous two keyframes, a loop closure to a keyframe 60-96 back every 25 "
        "and one to a random older keyframe every 50, 5% outlier edges, noise 0.3 deg x [0.6, 1.6] per edge with "
        "matching covariances: **isotropic**, or **anisotropic** with a standard deviation drawn so for each of three "
        "random principal axes, which makes every linear system 3x3 blocks) solved cold; then "
     << additions << " keyframes arriving at " << Fixed(rate_hz, 0)
     << " per second, each followed by OnlineAverager::SolveNow. Modes: **local** (the default from "
        "local_solve_min_views = 3,000 keyframes): only the neighbourhood of the change is re-solved (3 hops, at most "
        "1,000 keyframes), the rest held fixed, and every 10 local solves a full warm-started solve runs in a "
        "background thread on a snapshot, taken by the first solve after it finishes (edges marked as loop closures "
        "would make it due at once; this graph's revisits are sent as source 'other'); **local, full solves in the "
        "foreground**: the same, the full solve run in the solve that is due (deterministic; the bag replay's "
        "setting); **full**: every solve re-solves the whole graph warm-started (local solves off), and from the "
        "spanning tree alone, keeping the lower cost (compare_tree_start, the default); **full, compare_tree_start "
        "off**: the warm start alone; **full, warm_start_min_fraction 0.99**: the same, keeping the start without a "
        "robust re-start while 99% of the views are warm. Time to an updated solution = adding the keyframe's edges and SolveNow, including building the "
        "solution maps the node publishes. Accuracy: the final solution of the run and a cold full solve of the same "
        "graph against the truth (median, and keyframes more than 5 deg off), and the two against each other. Targets: "
        "95th percentile under 20 ms while as accurate as a full solve, with isotropic and anisotropic covariances; "
        "a full re-solve (the background solves: see the **full** rows) under 1 s.\n\n"
     << "| mode | edge covariances | posterior covariances | cold solve (s) | median (ms) | 95th percentile (ms) | max (ms) | local / "
        "background full solves | median error, run (deg) | median error, cold full solve (deg) | > 5 deg off, run / "
        "cold | run vs cold: median difference (deg), keyframes > 1 deg apart |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  const OnlineMode modes[] = {
      {"local (default)", false, true, true, 1.0, 0},
      {"local (default)", false, true, true, 1.0, 20000},
      {"local, full solves in the foreground", false, true, false, 1.0, 0},
      {"full", false, false, false, 1.0, 0},
      {"full, compare_tree_start off", false, false, false, 1.0, 0, false},
      {"full, warm_start_min_fraction 0.99", false, false, false, 0.99, 0},
      {"local (default)", true, true, true, 1.0, 0},
      {"local (default)", true, true, true, 1.0, 20000},
      {"full", true, false, false, 1.0, 0},
      {"full, compare_tree_start off", true, false, false, 1.0, 0, false},
  };
  for (const OnlineMode& mode : modes) {
    std::cerr << "online: " << keyframes << " keyframes, " << mode.label << ", "
              << (mode.anisotropic ? "anisotropic" : "isotropic") << " edges, posterior covariances "
              << (mode.covariances ? "on" : "off") << " ..." << std::flush;
    const OnlineRun r = RunOnline(keyframes, additions, rate_hz, mode);
    std::cerr << " median " << Fixed(Median(r.ms), 1) << " ms, p95 " << Fixed(Percentile(r.ms, 0.95), 1) << " ms\n";
    md << "| " << mode.label << " | " << (mode.anisotropic ? "anisotropic" : "isotropic") << " | "
       << (mode.covariances ? "on (node default)" : "off (library default)") << " | "
       << Fixed(r.cold_s, 3) << " | " << Fixed(Median(r.ms), 1) << " | " << Fixed(Percentile(r.ms, 0.95), 1) << " | "
       << Fixed(*std::max_element(r.ms.begin(), r.ms.end()), 1) << " | " << r.local_solves << " / "
       << r.background_solves << " | " << Fixed(r.incremental_median_deg, 3) << " | " << Fixed(r.full_median_deg, 3)
       << " | " << r.incremental_off << " / " << r.full_off << " | " << Fixed(r.median_difference_deg, 4) << ", "
       << r.differ << " |\n";
  }
  return md.str();
}

}  // namespace

int main(int argc, char** argv) {
  std::string output = "results/scale.md", sizes_text = "1000,10000,100000,1000000";
  bool quick = false;
  int online_keyframes = 10000, online_additions = 100, anisotropic_max_views = 100000;
  double online_rate_hz = 10.0;
  std::string only;
  for (int k = 1; k < argc; ++k) {
    const std::string a = argv[k];
    if (a == "--child" && k + 1 < argc) {
      bool multigrid = true, anisotropic = false;
      double multigrid_tolerance = 0.0;
      for (int a = k + 2; a < argc; ++a) {
        multigrid = multigrid && std::string(argv[a]) != "--no-multigrid";
        anisotropic = anisotropic || std::string(argv[a]) == "--anisotropic";
        if (std::string(argv[a]) == "--multigrid-tolerance" && a + 1 < argc) multigrid_tolerance = std::atof(argv[a + 1]);
      }
      return RunChild(std::atoi(argv[k + 1]), multigrid, anisotropic, multigrid_tolerance);
    }
    if (a == "--sizes" && k + 1 < argc) sizes_text = argv[++k];
    else if (a == "--online-keyframes" && k + 1 < argc) online_keyframes = std::max(100, std::atoi(argv[++k]));
    else if (a == "--online-additions" && k + 1 < argc) online_additions = std::max(10, std::atoi(argv[++k]));
    else if (a == "--online-rate" && k + 1 < argc) online_rate_hz = std::clamp(std::atof(argv[++k]), 0.1, 1000.0);
    else if (a == "--output" && k + 1 < argc) output = argv[++k];
    else if (a == "--anisotropic-max" && k + 1 < argc) anisotropic_max_views = std::atoi(argv[++k]);
    else if (a == "--only" && k + 1 < argc && (std::string(argv[k + 1]) == "scale" || std::string(argv[k + 1]) == "online")) only = argv[++k];
    else if (a == "--quick") quick = true;
    else {
      std::cerr << "usage: rotavg_scale_benchmark [--sizes 1000,10000,...] [--online-keyframes N] "
                   "[--online-additions N] [--online-rate HZ] [--anisotropic-max N] [--only scale|online] [--output FILE] "
                   "[--quick]\n";
      return 2;
    }
  }
  const std::string command = ra::CommandLine("rotavg_scale_benchmark", argc, argv);
  std::vector<int> sizes;
  for (const std::string& token : ra::SplitTokens(sizes_text, true)) {
    const int n = std::atoi(token.c_str());
    if (n < 10) {
      std::cerr << "bad size '" << token << "'\n";
      return 2;
    }
    sizes.push_back(n);
  }
  if (quick) {
    sizes = {1000, 10000};
    online_keyframes = 3000;  // local re-solves start at 3,000 keyframes
    online_additions = 30;
  }
  std::ostringstream md;
  const std::time_t now = std::time(nullptr);
  md << (only == "scale" ? "# Scale" : only == "online" ? "# Online re-solve" : "# Scale and online re-solve")
     << "\n\nReproduce with: `" << command << "` (built by `scripts/setup.sh`; part of "
     << "`bash scripts/report.sh`). Generated " << std::put_time(std::gmtime(&now), "%Y-%m-%d %H:%M UTC") << " on a "
     << std::thread::hardware_concurrency() << "-core machine.\n\n"
     << (only != "online" ? ScaleSection(argv[0], sizes, anisotropic_max_views) : std::string())
     << (only != "scale" ? OnlineSection(online_keyframes, online_additions, online_rate_hz) : std::string());
  ra::WriteReport(output, md.str());
  return 0;
}
