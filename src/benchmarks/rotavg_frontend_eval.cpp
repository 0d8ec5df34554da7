// rotavg_frontend_eval: the two-view front end on real images with ground
// truth (Strecha scenes, lund_door): calibration of the rotation covariances,
// rotation-averaging accuracy per loss and weighting, and speed.
//
//   rotavg_frontend_eval --data DIR [--scales 1,0.25,w640] [--output results/frontend.md] [--quick]
//
// A scale is a downsampling factor (0.25 = a quarter of the width) or wN for
// images resized to N pixels wide.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <limits>
#include <numeric>
#include <sstream>
#include <string>
#include <vector>

#include "rotation_averaging/frontend/controllers/image_pipeline.h"
#include "rotation_averaging/frontend/controllers/keyframe_frontend.h"
#include "rotation_averaging/frontend/estimators/bundle_adjustment.h"
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include "rotation_averaging/core/estimators/rotation_averaging.h"
#include "rotation_averaging/frontend/eval/error_plot.h"
#include "rotation_averaging/sim/focal_scene.h"
#include "rotation_averaging/core/eval/rotation_evaluation.h"
#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/core/io/orientation_io.h"
#include "rotation_averaging/util/text_lines.h"
#include "report.h"
#include "rotation_averaging/util/freed_memory.h"

namespace ra = rotation_averaging;
namespace fs = std::filesystem;
using rotation_averaging::Fixed;
using rotation_averaging::Median;

namespace {

const std::vector<ra::LossType>& kLosses = ra::PaperTableLosses();
const char* const kColmapLabel =
    "COLMAP incremental SfM + bundle adjustment, full resolution (scripts/benchmark_colmap.sh)";
const char* const kRefinedLabel =
    "magsac + covariance, then refined on the correspondences (rotavg images --refine --no-bundle-adjustment)";
const char* const kBundleLabel = "magsac + covariance, then bundle adjusted (rotavg images defaults)";
const char* const kPaperLabel = "paper: magsac + unscaled conditional covariance x1e8, sigma_max 0.02, tree start";
const std::vector<ra::EdgeWeighting>& kWeightings = ra::PaperTableWeightings();

// The averaging defaults of `rotavg images`.
ra::RotationAveragingOptions ImagesDefaults() {
  ra::RotationAveragingOptions o;
  o.self_calibration = ra::CovarianceSelfCalibration::kFloor;
  return o;
}

struct Scene {
  std::string name, images, intrinsics, ground_truth;
  bool exact_intrinsics;     // K comes with the ground truth (Strecha), not from a reconstruction
};

// A method's row of the long table (loss_table.md): median and every AUC.
std::string LongTableRow(const std::string& scene, const std::string& scale, const std::string& label,
                         const ra::EvaluationResult& e) {
  std::ostringstream row;
  row << "| " << scene << " | " << scale << " | " << label << " | " << Fixed(e.median_error_deg, 4);
  for (const auto& [t, a] : e.auc) row << " | " << Fixed(100.0 * a, 1);
  row << " |\n";
  return row.str();
}

// A row of a scene's "other method" table: median and the first four AUCs.
std::string OtherMethodRow(const std::string& label, const ra::EvaluationResult& e) {
  std::ostringstream row;
  row << "| " << label << " | " << Fixed(e.median_error_deg, 4);
  for (std::size_t t = 0; t < 4; ++t) row << " | " << Fixed(100.0 * e.auc[t].second, 1);
  row << " |\n";
  return row.str();
}



double Mean(const std::vector<double>& v) {
  return v.empty() ? NAN : std::accumulate(v.begin(), v.end(), 0.0) / v.size();
}

std::vector<double> Ranks(const std::vector<double>& v) {
  std::vector<int> order(v.size());
  std::iota(order.begin(), order.end(), 0);
  std::sort(order.begin(), order.end(), [&](int a, int b) { return v[a] < v[b]; });
  std::vector<double> rank(v.size());
  for (std::size_t k = 0; k < order.size(); ++k) rank[order[k]] = static_cast<double>(k);
  return rank;
}

// Spearman rank correlation.
double Spearman(const std::vector<double>& a, const std::vector<double>& b) {
  if (a.size() < 3) return NAN;
  const std::vector<double> ra_ = Ranks(a), rb = Ranks(b);
  const double ma = Mean(ra_), mb = Mean(rb);
  double sab = 0, saa = 0, sbb = 0;
  for (std::size_t i = 0; i < a.size(); ++i) {
    sab += (ra_[i] - ma) * (rb[i] - mb);
    saa += (ra_[i] - ma) * (ra_[i] - ma);
    sbb += (rb[i] - mb) * (rb[i] - mb);
  }
  return sab / std::sqrt(saa * sbb);
}

// A copy of the front end's graph whose edges carry another covariance.
ra::ViewGraph WithCovariance(const ra::ImagePipelineResult& front,
                             int which /*0 marginal, 1 conditional, 2 paper, 3 marginal of the pixel model alone*/) {
  ra::ViewGraph g;
  for (const ra::View& v : front.graph.Views()) g.AddView(v.id, v.name);
  for (const ra::PairReport& p : front.pairs) {
    if (!p.pose.success) continue;
    ra::RelativeRotation e = ra::EdgeFromPair(p);
    e.covariance = which == 0   ? p.pose.covariance_marginal
                   : which == 1 ? p.pose.covariance_conditional
                   : which == 2 ? p.pose.covariance_paper
                                : p.pose.covariance_marginal_pixel;
    g.AddEdge(e);
  }
  return g;
}


// eta = Log(R_12_true^T R_12_est) of a pair against the ground truth; false
// if either image has none.
bool PairError(const ra::NamedOrientations& gt, const std::string& name1, const std::string& name2,
               const ra::RelativePoseResult& pose, Eigen::Vector3d* eta) {
  const auto a = gt.find(name1), b = gt.find(name2);
  if (a == gt.end() || b == gt.end()) return false;
  *eta = ra::LogSO3((a->second * b->second.transpose()).transpose() * pose.EdgeRotation());
  return true;
}

// What moves the two-view rotations: the pairs of one scene and scale,
// matched once, re-estimated under variants of `rotavg images`' defaults
// (the relative-pose options of the pipeline above). Each row: the
// median rotation error and NEES of the pairs against the ground truth, and
// the median error of rotation averaging (defaults) on them.
struct Variant {
  std::string label;
  ra::RelativePoseOptions options;
  double focal_factor;          // the intrinsics are scaled by this (1 = as given)
  bool calibrate_focal = false;  // then the focal length is estimated from the pairs (rotavg images)
};

std::string VariantRows(const std::string& scene, const std::string& scale_text,
                        const std::vector<ra::ImageFeatures>& features, const std::vector<std::string>& names,
                        const Eigen::Matrix3d& k, const ra::NamedOrientations& gt,
                        const ra::RelativePoseOptions& defaults) {
  struct Matched {
    int i, j;
    std::vector<Eigen::Vector2d> p1, p2;
  };
  std::vector<Matched> pairs;
  for (std::size_t i = 0; i < features.size(); ++i) {
    for (std::size_t j = i + 1; j < features.size(); ++j) {
      Matched m{static_cast<int>(i), static_cast<int>(j), {}, {}};
      for (const auto& [a, b] : ra::MatchFeatures(features[i], features[j])) {
        m.p1.push_back(features[i].keypoints_px[a]);
        m.p2.push_back(features[j].keypoints_px[b]);
      }
      pairs.push_back(std::move(m));
    }
  }
  std::vector<Variant> variants(6);
  variants[0] = {"defaults (robust estimation repeated at 3 sigma of the pair's noise)", defaults, 1.0};
  variants[1] = {"fixed 3 px threshold (adaptive_threshold_sigmas 0)", defaults, 1.0};
  variants[1].options.adaptive_threshold_sigmas = 0.0;
  variants[2] = {"defaults, focal length 1% short", defaults, 0.99};
  variants[3] = {"defaults, focal length 1% long", defaults, 1.01};
  variants[4] = {"defaults, focal length 1% short, self-calibrated", defaults, 0.99, true};
  variants[5] = {"defaults, focal length 1% long, self-calibrated", defaults, 1.01, true};
  std::ostringstream rows;
  for (const Variant& v : variants) {
    Eigen::Matrix3d kv = k;
    kv(0, 0) *= v.focal_factor;
    kv(1, 1) *= v.focal_factor;
    std::vector<ra::PairReport> reports;
    for (const Matched& m : pairs) reports.push_back(ra::EstimatePair(m.i, m.j, m.p1, m.p2, kv, v.options));
    std::string label = v.label;
    if (v.calibrate_focal) {
      ra::FocalCalibrationOptions focal_options;
      focal_options.enabled = true;
      std::vector<ra::FocalPair> focal_pairs;
      for (std::size_t p = 0; p < pairs.size(); ++p) focal_pairs.push_back({&pairs[p].p1, &pairs[p].p2, &reports[p].pose});
      const ra::FocalCalibration focal = ra::EstimateFocalScale(focal_pairs, kv, focal_options);
      std::ostringstream note;
      note << std::fixed << std::setprecision(4) << " (estimated x" << focal.scale << ", true x"
           << 1.0 / v.focal_factor;
      if (ra::ShouldApplyFocalScale(focal, focal_options)) {
        kv(0, 0) *= focal.scale;
        kv(1, 1) *= focal.scale;
        reports.clear();
        for (const Matched& m : pairs) reports.push_back(ra::EstimatePair(m.i, m.j, m.p1, m.p2, kv, v.options));
      } else {
        note << ", not applied";
      }
      label += note.str() + ")";
    }
    ra::ImagePipelineResult front;
    front.k = kv;
    ra::ViewGraph& graph = front.graph;
    for (std::size_t i = 0; i < names.size(); ++i) graph.AddView(static_cast<ra::ViewId>(i), names[i]);
    std::vector<double> errors, nees;
    for (ra::PairReport& report : reports) {
      Eigen::Vector3d eta;
      if (!report.pose.success || !PairError(gt, names[report.image1], names[report.image2], report.pose, &eta)) continue;
      graph.AddEdge(ra::EdgeFromPair(report));
      errors.push_back(ra::RadToDeg(eta.norm()));
      nees.push_back(eta.dot(report.pose.covariance.ldlt().solve(eta)));
      front.pairs.push_back(std::move(report));
    }
    ra::ViewOrientations out;
    ra::RotationAveragingSummary summary;
    ra::SolveRotationAveraging(graph, ImagesDefaults(), &out, &summary);
    const ra::EvaluationResult e = ra::EvaluateOrientations(ra::NameOrientations(graph, out), gt);
    // Both refinements start from the same averaging and the same matches.
    const std::vector<ra::EdgeCorrespondences> correspondences = ra::CorrespondencesOfEdges(front);
    ra::ViewOrientations adjusted = out;
    ra::CorrespondenceRefinementSummary refinement;
    ra::RefineRotationsWithCorrespondences(correspondences, ra::CorrespondenceRefinementOptions(), &out, &refinement);
    const ra::EvaluationResult refined = ra::EvaluateOrientations(ra::NameOrientations(graph, out), gt);
    ra::BundleAdjustmentSummary adjustment;
    ra::RefineRotationsWithBundleAdjustment(correspondences, ra::BundleAdjustmentOptions(), &adjusted, &adjustment);
    const ra::EvaluationResult bundle = ra::EvaluateOrientations(ra::NameOrientations(graph, adjusted), gt);
    int over_one = 0;
    for (double x : errors) over_one += x > 1.0;
    rows << "| " << scene << " | " << scale_text << " | " << label << " | " << errors.size() << " | "
         << Fixed(Median(errors), 3) << " | " << over_one << " | " << Fixed(Median(nees), 0) << " | "
         << Fixed(e.median_error_deg, 4) << " | " << Fixed(refined.median_error_deg, 4) << " | "
         << Fixed(bundle.median_error_deg, 4) << " |\n";
  }
  return rows.str();
}

struct Args {
  std::string data_dir = "../shared/data", output = "results/frontend.md", scales_text = "1,0.25,w640";
  std::string plot_dir = "results/plots";
  // COLMAP's models of the scenes (scripts/benchmark_colmap.sh), scored here
  // by the same evaluator as every method.
  std::string colmap_dir = "build/benchmark_colmap";
  bool quick = false;
  std::vector<std::string> scales;  // "0.25" or "w640"
};

bool ParseArgs(int argc, char** argv, Args* args) {
  for (int k = 1; k < argc; ++k) {
    const std::string a = argv[k];
    if (a == "--data" && k + 1 < argc) args->data_dir = argv[++k];
    else if (a == "--output" && k + 1 < argc) args->output = argv[++k];
    else if (a == "--scales" && k + 1 < argc) args->scales_text = argv[++k];
    else if (a == "--plots" && k + 1 < argc) args->plot_dir = argv[++k];
    else if (a == "--colmap" && k + 1 < argc) args->colmap_dir = argv[++k];
    else if (a == "--quick") args->quick = true;
    else {
      std::cerr << "usage: rotavg_frontend_eval [--data DIR] [--scales 1,0.25] [--output FILE] [--plots DIR] "
                   "[--colmap DIR] [--quick]\n";
      return false;
    }
  }
  for (const std::string& t : ra::SplitTokens(args->scales_text, true)) {
    double s;
    const bool width = !t.empty() && t[0] == 'w';
    if (!ra::ParseDouble(width ? t.substr(1) : t, &s) || !(s > 0.0) || (!width && s > 1.0)) {
      std::cerr << "bad scale '" << t << "'\n";
      return false;
    }
    args->scales.push_back(t);
  }
  if (args->quick) args->scales = {"0.25"};
  return true;
}

std::vector<Scene> Scenes(const std::string& data_dir, bool quick) {
  std::vector<Scene> scenes;
  for (const std::string name : {"fountain-P11", "entry-P10", "castle-P19"}) {
    const std::string dir = data_dir + "/strecha/" + name;
    scenes.push_back({name, dir + "/images", dir + "/images/K.txt", dir, true});
  }
  scenes.push_back({"lund_door", data_dir + "/lund_door/images", data_dir + "/lund_door/colmap_ground_truth/cameras.txt",
                    data_dir + "/lund_door/colmap_ground_truth", false});
  if (quick) scenes.resize(2);
  return scenes;
}

// The rows of each table of the report, filled scene by scene.
struct Tables {
  std::ostringstream calibration, floor, accuracy, variants, focal, principal_points, speed;
  std::ostringstream long_table;  // every method, every scene (loss_table.md)
};

// A method of the accuracy comparison: averaging options, the graph's
// covariance (WithCovariance) and what follows the averaging.
struct Method {
  std::string label;
  ra::RotationAveragingOptions options;
  int covariance;
  enum class Then { kNothing, kRefine, kBundleAdjust } then = Then::kNothing;
};

// The paper's table first (every loss x every weighting), then the others.
std::vector<Method> Methods() {
  std::vector<Method> methods;
  for (ra::LossType loss : kLosses) {
    for (ra::EdgeWeighting w : kWeightings) {
      ra::RotationAveragingOptions o = ImagesDefaults();
      o.loss = loss;
      o.weighting = w;
      methods.push_back({std::string(ra::LossTypeName(loss)) + " + " + ra::EdgeWeightingName(w), o, 0});
    }
  }
  ra::RotationAveragingOptions o = ImagesDefaults();
  methods.push_back({kRefinedLabel, o, 0, Method::Then::kRefine});
  methods.push_back({kBundleLabel, o, 0, Method::Then::kBundleAdjust});
  methods.push_back({"magsac + covariance (conditional)", o, 1});
  methods.push_back({"magsac + covariance (marginal of the pixel model alone, no cell jackknife)", o, 3});
  ra::RotationAveragingOptions widened = o;
  widened.self_calibration = ra::CovarianceSelfCalibration::kLossScale;
  methods.push_back({"magsac + covariance, loss widened instead of a covariance floor (--self-calibration "
                     "loss_scale)",
                     widened, 0});
  o.covariance_normalization = ra::CovarianceNormalization::kPaper;
  o.robust_start.gnc_initial_scale_factor = 1.0;
  o.robust_start.l1_initialization = false;
  methods.push_back({kPaperLabel, o, 2});
  ra::RotationAveragingOptions l1;
  l1.solver = ra::SolverType::kL1Irls;
  l1.weighting = ra::EdgeWeighting::kNone;
  methods.push_back({"L1-IRLS baseline", l1, 0});
  return methods;
}

// Calibration of the pairs' covariances against the ground truth, without
// and with the covariance floor `floor_rad`: a row of the calibration table
// and the first columns of the floor table.
void CalibrationRows(const Scene& scene, const std::string& scale_text, const ra::ImagePipelineResult& front,
                     const std::vector<std::string>& names, const ra::NamedOrientations& gt, double floor_rad,
                     Tables* tables) {
  // eta = Log(R_ij_true^T R_ij_est) for every successful pair.
  std::vector<double> nees_m, nees_p, nees_c, nees_f, err, std_m, std_c, sigmas;
  // Per inlier class (< 100, 100-499, >= 500): NEES without and with the floor.
  std::vector<double> class_nees[3], class_nees_f[3];
  int ok = 0;
  for (const ra::PairReport& p : front.pairs) {
    if (!p.pose.success) continue;
    ++ok;
    Eigen::Vector3d eta;
    if (!PairError(gt, names[p.image1], names[p.image2], p.pose, &eta)) continue;
    nees_m.push_back(eta.dot(p.pose.covariance_marginal.ldlt().solve(eta)));
    nees_p.push_back(eta.dot(p.pose.covariance_marginal_pixel.ldlt().solve(eta)));
    nees_c.push_back(eta.dot(p.pose.covariance_conditional.ldlt().solve(eta)));
    const Eigen::Matrix3d floored = p.pose.covariance_marginal + floor_rad * floor_rad * Eigen::Matrix3d::Identity();
    nees_f.push_back(eta.dot(floored.ldlt().solve(eta)));
    const int inliers = static_cast<int>(p.pose.inliers.size());
    const int c = inliers < 100 ? 0 : inliers < 500 ? 1 : 2;
    class_nees[c].push_back(nees_m.back());
    class_nees_f[c].push_back(nees_f.back());
    err.push_back(eta.norm());
    std_m.push_back(std::sqrt(p.pose.covariance_marginal.trace()));
    std_c.push_back(std::sqrt(p.pose.covariance_conditional.trace()));
    sigmas.push_back(p.pose.sigma_px);
  }
  tables->calibration << "| " << scene.name << " | " << scale_text << " | " << ok << " / " << front.pairs.size()
                      << " | " << Fixed(Mean(nees_m), 2) << " | " << Fixed(Median(nees_m), 2) << " | "
                      << Fixed(Median(nees_p), 2) << " | " << Fixed(Mean(nees_c), 2) << " | "
                      << Fixed(Median(nees_c), 2) << " | " << Fixed(Spearman(std_m, err), 2) << " | "
                      << Fixed(Spearman(std_c, err), 2) << " | " << Fixed(Median(sigmas), 3) << " |\n";
  tables->floor << "| " << scene.name << " | " << scale_text << " | " << Fixed(ra::RadToDeg(floor_rad), 4) << " | "
                << Fixed(Median(nees_m), 1) << " | " << Fixed(Median(nees_f), 2) << " | " << Fixed(Mean(nees_f), 2);
  for (int c = 0; c < 3; ++c) {
    tables->floor << " | " << class_nees[c].size() << ": " << Fixed(Median(class_nees[c]), 1) << " -> "
                  << Fixed(Median(class_nees_f[c]), 2);
  }
}

// The pairs against the bundle adjustment of their own inliers (a reference
// that shares their features, not the ground truth's error), split into views
// and pairs against the ground truth, and with the view term the offsets
// against the bundle adjustment give: the last columns of the floor table.
void ViewTermColumns(const ra::ViewGraph& graph, const ra::NamedOrientations& gt,
                     const ra::NamedOrientations& bundle_adjusted, double floor_rad, Tables* tables) {
  const ra::EdgeCalibration against_gt = ra::EvaluateEdgeCovariances(graph, gt, floor_rad);
  const ra::EdgeCalibration against_bundle = ra::EvaluateEdgeCovariances(graph, bundle_adjusted, floor_rad);
  const double view_rad = ra::ViewTermRad(against_bundle);
  tables->floor << " | " << Fixed(against_bundle.nees_median, 2) << " | " << Fixed(against_gt.median_view_offset_deg, 4)
                << " | " << Fixed(against_gt.nees_median_after_view_offsets, 2) << " | "
                << Fixed(view_rad * 180.0 / M_PI, 4) << " | "
                << Fixed(ra::EvaluateEdgeCovariances(graph, gt, ra::FloorWithViewTermRad(floor_rad, view_rad)).nees_median,
                         2)
                << " |\n";
}

// Solves with every method and scores each; `bundle_adjusted` gets the
// bundle adjusted orientations.
std::vector<ra::EvaluationResult> RunMethods(const std::vector<Method>& methods, const ra::ViewGraph graphs[4],
                                             const ra::ImagePipelineResult& front, const ra::NamedOrientations& gt,
                                             const std::vector<double>& thresholds,
                                             ra::NamedOrientations* bundle_adjusted) {
  std::vector<ra::EvaluationResult> results;
  for (const Method& m : methods) {
    ra::ViewOrientations out;
    ra::RotationAveragingSummary summary;
    ra::SolveRotationAveraging(graphs[m.covariance], m.options, &out, &summary);
    if (m.then == Method::Then::kRefine) {
      ra::CorrespondenceRefinementSummary refinement;
      ra::RefineRotationsWithCorrespondences(ra::CorrespondencesOfEdges(front), ra::CorrespondenceRefinementOptions(),
                                             &out, &refinement);
      std::cerr << "  " << refinement.Report() << "\n";
    } else if (m.then == Method::Then::kBundleAdjust) {
      ra::BundleAdjustmentSummary adjustment;
      ra::RefineRotationsWithBundleAdjustment(ra::CorrespondencesOfEdges(front), ra::BundleAdjustmentOptions(), &out,
                                              &adjustment);
      std::cerr << "  " << adjustment.Report() << "\n";
      *bundle_adjusted = ra::NameOrientations(graphs[m.covariance], out);
    }
    results.push_back(ra::EvaluateOrientations(ra::NameOrientations(graphs[m.covariance], out), gt, thresholds));
  }
  return results;
}

// A scene's accuracy section: the loss x weighting matrix of medians, then
// the other methods (and COLMAP's model at full resolution).
void AccuracySection(const Scene& scene, const std::string& scale_text, const ra::NamedOrientations& gt,
                     const std::vector<Method>& methods, const std::vector<ra::EvaluationResult>& results,
                     const Args& args, const std::vector<double>& thresholds, Tables* tables) {
  std::ostringstream& accuracy = tables->accuracy;
  accuracy << "\n**" << scene.name << ", scale " << scale_text << "** (" << gt.size()
           << " views): median error (deg) per loss and weighting; best in bold.\n\n| loss |";
  for (ra::EdgeWeighting w : kWeightings) accuracy << " " << ra::EdgeWeightingName(w) << " |";
  accuracy << "\n|---|";
  for (std::size_t k = 0; k < kWeightings.size(); ++k) accuracy << "---|";
  double best = std::numeric_limits<double>::infinity();
  for (std::size_t k = 0; k < kLosses.size() * kWeightings.size(); ++k) best = std::min(best, results[k].median_error_deg);
  for (std::size_t l = 0; l < kLosses.size(); ++l) {
    accuracy << "\n| " << ra::LossTypeName(kLosses[l]) << " |";
    for (std::size_t w = 0; w < kWeightings.size(); ++w) {
      const double median = results[l * kWeightings.size() + w].median_error_deg;
      accuracy << (median == best ? " **" + Fixed(median, 4) + "** |" : " " + Fixed(median, 4) + " |");
    }
  }
  accuracy << "\n\n| other method | median (deg) | AUC@0.1 | AUC@0.5 | AUC@1 | AUC@2 |\n|---|---|---|---|---|---|\n";
  for (std::size_t k = kLosses.size() * kWeightings.size(); k < methods.size(); ++k) {
    accuracy << OtherMethodRow(methods[k].label, results[k]);
  }
  // COLMAP's reconstruction from the full-resolution images, scored as the
  // methods above.
  const fs::path colmap_model = fs::path(args.colmap_dir) / scene.name / "images.txt";
  if (scale_text == "1" && fs::exists(colmap_model)) {
    ra::NamedOrientations colmap;
    const ra::ReadReport read = ra::ReadColmapGroundTruth(colmap_model.string(), &colmap);
    if (read.ok()) {
      const ra::EvaluationResult e = ra::EvaluateOrientations(colmap, gt, thresholds);
      accuracy << OtherMethodRow(kColmapLabel, e);
      tables->long_table << LongTableRow(scene.name, scale_text, kColmapLabel, e);
    } else {
      std::cerr << "  COLMAP model left out: " << read.error << "\n";
    }
  }
}

// The paper's figure: cumulative error distributions of a few methods,
// linked from the accuracy section.
void CdfPlot(const Scene& scene, const std::string& scale_text, const ra::NamedOrientations& gt,
             const std::vector<Method>& methods, const std::vector<ra::EvaluationResult>& results, const Args& args,
             Tables* tables) {
  std::vector<ra::CdfSeries> curves;
  for (const std::string& label : {std::string("squared + none"), std::string("L1-IRLS baseline"),
                                   std::string(kPaperLabel), std::string("magsac + inliers"),
                                   std::string("magsac + trace"), std::string("magsac + covariance"),
                                   std::string(kRefinedLabel), std::string(kBundleLabel)}) {
    for (std::size_t k = 0; k < methods.size(); ++k) {
      if (methods[k].label != label) continue;
      ra::CdfSeries c;
      c.label = label == kPaperLabel     ? "paper's setting"
                : label == kRefinedLabel ? "magsac + covariance, refined"
                : label == kBundleLabel  ? "magsac + covariance, bundle adjusted"
                                         : label;
      for (const auto& [name, e] : results[k].errors_deg) c.error_deg.push_back(e);
      curves.push_back(c);
    }
  }
  if (args.plot_dir.empty()) return;
  const std::string png = args.plot_dir + "/cdf_" + scene.name + "_" + scale_text + ".png";
  std::string plot_error;
  std::filesystem::create_directories(args.plot_dir);
  if (ra::WriteCdfPlot(png, scene.name + ", scale " + scale_text + ": rotation error CDF", curves, gt.size(), 0.0,
                       &plot_error)) {
    const std::string relative = fs::path(png).lexically_relative(fs::path(args.output).parent_path()).string();
    tables->accuracy << "\n![" << scene.name << " " << scale_text << " CDF](" << relative << ")\n";
  } else {
    std::cerr << "plot " << png << ": " << plot_error << "\n";
  }
}

// One scene at one scale: the front end, its calibration, every averaging
// method, the variants, the focal estimate and the speed.
void EvaluateScene(const Scene& scene, const std::vector<std::string>& images, const ra::CameraIntrinsics& intrinsics,
                   const ra::NamedOrientations& gt, const std::string& scale_text, const Args& args, Tables* tables) {
  const int full_width = scene.name == "lund_door" ? 1296 : 3072;
  const int full_height = scene.name == "lund_door" ? 1936 : 2048;
  double scale = 1.0;
  if (scale_text[0] == 'w') {
    ra::ParseDouble(scale_text.substr(1), &scale);
    scale = std::min(1.0, scale / full_width);
  } else {
    ra::ParseDouble(scale_text, &scale);
  }
  ra::ImagePipelineOptions options;
  options.features.downsample = scale;
  options.focal.enabled = true;              // as rotavg images
  options.relative_pose.jackknife_grid = 4;  // as rotavg images
  std::cerr << scene.name << " at scale " << scale << " ..." << std::flush;
  // Features once, for the front end and for the variants.
  std::vector<std::string> names, image_errors;
  const auto features_start = std::chrono::steady_clock::now();
  const std::vector<ra::ImageFeatures> features =
      ra::ExtractImageFeatures(images, intrinsics, options.features, &names, &image_errors);
  const double features_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - features_start).count();
  for (const std::string& e : image_errors) std::cerr << e << "\n";
  const Eigen::Matrix3d feature_k = ra::FeatureIntrinsics(intrinsics, options.features);
  ra::ImagePipelineResult front = ra::BuildViewGraphFromFeatures(features, names, feature_k, options);
  front.features_s = features_s;
  std::cerr << " done (" << front.features_s + front.matching_s + front.relative_pose_s << " s)\n";
  const ra::FocalCalibration& focal = front.focal;
  tables->focal << "| " << scene.name << " | " << scale_text << " | " << focal.pairs << " | "
                << (focal.estimated ? Fixed(focal.scale, 4) + " +- " + Fixed(focal.standard_deviation, 4)
                                    : std::string("not estimated"))
                << " | " << (focal.estimated ? Fixed(focal.matches_deviation, 4) : std::string("-")) << " | "
                << (focal.estimated ? Fixed(focal.principal_point_deviation, 4) : std::string("-")) << " | "
                << (focal.estimated ? Fixed((focal.scale - 1.0) / focal.standard_deviation, 1) : std::string("-"))
                << " | " << (focal.applied ? "yes" : "no") << " | " << Fixed(front.focal_s, 2) << " |\n";
  // lund_door's principal point is COLMAP's, fixed at the centre: not a calibration.
  if (scale_text == args.scales.front() && scene.name != "lund_door") {
    // Where the calibration puts the principal point, against the image
    // centre: how far a nominal (centred) principal point would be off.
    const double cx = 0.5 * (full_width - 1), cy = 0.5 * (full_height - 1);
    tables->principal_points << "| " << scene.name << " | " << full_width << " x " << full_height << " | "
                             << Fixed(100.0 * (intrinsics.k(0, 2) - cx) / full_width, 2) << " | "
                             << Fixed(100.0 * (intrinsics.k(1, 2) - cy) / full_width, 2) << " |\n";
  }

  // The covariance floor the default averaging estimates on these pairs.
  double floor_rad = 0.0;
  {
    ra::ViewOrientations out;
    ra::RotationAveragingSummary summary;
    ra::SolveRotationAveraging(WithCovariance(front, 0), ImagesDefaults(), &out, &summary);
    floor_rad = summary.LargestComponentFloorRad();
  }
  CalibrationRows(scene, scale_text, front, names, gt, floor_rad, tables);

  const std::vector<double> thresholds = {0.1, 0.5, 1.0, 2.0, 5.0, 10.0, 20.0};
  const std::vector<Method> methods = Methods();
  const ra::ViewGraph graphs[4] = {WithCovariance(front, 0), WithCovariance(front, 1), WithCovariance(front, 2),
                                   WithCovariance(front, 3)};
  ra::NamedOrientations bundle_adjusted;
  const std::vector<ra::EvaluationResult> results = RunMethods(methods, graphs, front, gt, thresholds, &bundle_adjusted);
  for (std::size_t k = 0; k < methods.size(); ++k) {
    tables->long_table << LongTableRow(scene.name, scale_text, methods[k].label, results[k]);
  }
  ViewTermColumns(graphs[0], gt, bundle_adjusted, floor_rad, tables);
  AccuracySection(scene, scale_text, gt, methods, results, args, thresholds, tables);
  CdfPlot(scene, scale_text, gt, methods, results, args, tables);
  if (scene.exact_intrinsics) tables->variants << VariantRows(scene.name, scale_text, features, names, feature_k, gt,
                                                          options.relative_pose);

  double mean_features = 0;
  for (int f : front.features_per_image) mean_features += f;
  const int w = static_cast<int>(std::lround(scale * full_width));
  const int h = static_cast<int>(std::lround(scale * full_height));
  tables->speed << "| " << scene.name << " | " << scale_text << " | " << w << "x" << h << " | "
                << Fixed(mean_features / std::max<std::size_t>(1, images.size()), 0) << " | "
                << Fixed(1e3 * front.features_s / std::max<std::size_t>(1, images.size()), 0) << " | "
                << Fixed(1e3 * front.matching_s / std::max<std::size_t>(1, front.pairs.size()), 1) << " | "
                << Fixed(1e3 * front.relative_pose_s / std::max<std::size_t>(1, front.pairs.size()), 1) << " |\n";
}

// The EuRoC cameras' principal points against their image centres (752 x
// 480), rows of the principal point table.
std::string EurocPrincipalPointRows(const std::string& data_dir) {
  std::ostringstream rows;
  for (const char* camera : {"cam0", "cam1"}) {
    const std::string yaml = data_dir + "/euroc_v1_01_micro/mav0/" + camera + "/sensor.yaml";
    ra::CameraIntrinsics intrinsics;
    std::string error;
    if (!fs::exists(yaml) || !ra::ReadCameraIntrinsics(yaml, &intrinsics, &error)) continue;
    rows << "| EuRoC " << camera << " | 752 x 480 | " << Fixed(100.0 * (intrinsics.k(0, 2) - 375.5) / 752.0, 2)
         << " | " << Fixed(100.0 * (intrinsics.k(1, 2) - 239.5) / 752.0, 2) << " |\n";
  }
  return rows.str();
}

// The focal-length estimator on synthetic scenes (frontend/scene/
// focal_scene.h): a path (general motion) and a ring around an object (near
// the critical configuration), the focal length given right or 3% short,
// the principal point right or off; each over `seeds` scenes, with the
// principal point trusted (principal_point_sigma 0: the matches alone) and
// with the default.
std::string SyntheticFocalRows(int seeds) {
  Eigen::Matrix3d k;
  k << 500, 0, 320, 0, 500, 240, 0, 0, 1;
  std::ostringstream rows;
  for (const ra::FocalSceneGeometry geometry : {ra::FocalSceneGeometry::kPath, ra::FocalSceneGeometry::kRing}) {
    for (const double offset : {0.0, 0.005, 0.01}) {  // of the width (640 px), along x and y
      for (const double given : {1.0, 0.97}) {
        Eigen::Matrix3d k_given = k;
        k_given(0, 0) *= given;
        k_given(1, 1) *= given;
        k_given(0, 2) += offset * 640.0;
        k_given(1, 2) += offset * 640.0;
        std::vector<ra::FocalScene> scenes;
        for (int seed = 1; seed <= seeds; ++seed) {
          ra::FocalSceneOptions scene_options;
          scene_options.geometry = geometry;
          scene_options.seed = static_cast<unsigned>(seed);
          scene_options.noise_px = 0.5;
          scenes.push_back(ra::MakeFocalScene(k, k_given, scene_options));
        }
        rows << "| " << (geometry == ra::FocalSceneGeometry::kPath ? "path" : "ring") << " | "
             << Fixed(100.0 * offset, 1) << " | " << Fixed(1.0 / given, 4);
        for (const double sigma : {0.0, ra::FocalCalibrationOptions().principal_point_sigma}) {
          ra::FocalCalibrationOptions options;
          options.enabled = true;
          options.principal_point_sigma = sigma;
          std::ostringstream estimates;
          int applied = 0, estimated = 0;
          double worst = 0.0;
          for (const ra::FocalScene& scene : scenes) {
            const ra::FocalCalibration f = ra::EstimateFocalScale(scene.Pairs(), k_given, options);
            estimates << (estimates.tellp() > 0 ? ", " : "")
                      << (f.estimated ? Fixed(f.scale, 3) + " +- " + Fixed(f.standard_deviation, 3) : "none");
            if (!f.estimated) continue;
            ++estimated;
            worst = std::max(worst, std::abs(f.scale - 1.0 / given) / f.standard_deviation);
            applied += ra::ShouldApplyFocalScale(f, options);
          }
          rows << " | " << estimates.str() << " | " << (estimated > 0 ? Fixed(worst, 1) : std::string("-")) << " | "
               << applied << " of " << seeds;
        }
        rows << " |\n";
      }
    }
  }
  return rows.str();
}

// The node's keyframe front end: castle-P19 as a two-camera rig (even images
// on one camera, odd on the other, one capture per pair), 640x480, at 4000
// features per keyframe. Empty if the scene is absent.
std::string KeyframeRateRows(const std::string& data_dir) {
  const std::string dir = data_dir + "/strecha/castle-P19";
  ra::CameraIntrinsics intrinsics;
  std::string error;
  const std::vector<std::string> images = ra::ListImages(dir + "/images");
  if (images.size() < 2 || !ra::ReadCameraIntrinsics(dir + "/images/K.txt", &intrinsics, &error)) return "";
  std::ostringstream rate;
  for (const ra::FeatureType type : {ra::FeatureType::kSift, ra::FeatureType::kOrb}) {
    ra::KeyframeFrontendOptions options;
    options.features.type = type;
    options.features.max_features = 4000;
    ra::KeyframeFrontend frontend(options);
    for (std::size_t i = 0; i < images.size(); ++i) {
      cv::Mat full = cv::imread(images[i], cv::IMREAD_GRAYSCALE), image;
      cv::resize(full, image, cv::Size(640, 480), 0, 0, cv::INTER_AREA);
      Eigen::Matrix3d k = intrinsics.k;
      k.row(0) *= 640.0 / full.cols;
      k.row(1) *= 480.0 / full.rows;
      const ra::KeyframeKey key{i % 2 ? "cam_b" : "cam_a", 1'000'000'000LL * static_cast<std::int64_t>(1 + i / 2)};
      frontend.AddKeyframe(key, image, k);
    }
    const ra::KeyframeFrontendStats& st = frontend.Stats();
    const double total = st.features_s + st.retrieval_s + st.pairs_s;
    const double per = 1e3 * total / st.keyframes;
    rate << "| " << ra::FeatureTypeName(type) << " | 4000 | " << st.keyframes << " | " << Fixed(per, 0) << " ("
         << Fixed(1e3 * st.features_s / st.keyframes, 0) << " / " << Fixed(1e3 * st.retrieval_s / st.keyframes, 0)
         << " / " << Fixed(1e3 * st.pairs_s / st.keyframes, 0) << ") | " << Fixed(1e3 / per, 1) << " | "
         << st.sequential_edges << ", " << st.rig_edges << ", " << st.loop_closure_edges << " |\n";
  }
  return rate.str();
}

}  // namespace

int main(int argc, char** argv) {
  rotation_averaging::KeepFreedMemoryForReuse();  // util/freed_memory.h: buffers of each image reused, not faulted in again
  Args args;
  if (!ParseArgs(argc, argv, &args)) return 2;
  const std::string command = ra::CommandLine("rotavg_frontend_eval", argc, argv);
  const std::string table_path = (fs::path(args.output).parent_path() / "loss_table.md").string();
  Tables tables;
  for (const Scene& scene : Scenes(args.data_dir, args.quick)) {
    if (!fs::exists(scene.images)) {
      std::cerr << "skipping " << scene.name << ": " << scene.images << " absent\n";
      continue;
    }
    ra::CameraIntrinsics intrinsics;
    std::string error;
    if (!ra::ReadCameraIntrinsics(scene.intrinsics, &intrinsics, &error)) {
      std::cerr << error << "\n";
      return 1;
    }
    ra::NamedOrientations gt;
    const ra::ReadReport gr = ra::ReadGroundTruth(scene.ground_truth, ra::GroundTruthFormat::kAuto, &gt);
    if (!gr.ok()) {
      std::cerr << gr.error << "\n";
      return 1;
    }
    const std::vector<std::string> images = ra::ListImages(scene.images);
    for (const std::string& scale_text : args.scales) {
      EvaluateScene(scene, images, intrinsics, gt, scale_text, args, &tables);
    }
  }
  const std::string rate = KeyframeRateRows(args.data_dir);
  std::cerr << "focal length on synthetic scenes ..." << std::flush;
  const std::string synthetic_focal = SyntheticFocalRows(args.quick ? 1 : 3);
  std::cerr << " done\n";

  const std::time_t now = std::time(nullptr);
  std::ostringstream date;
  date << std::put_time(std::gmtime(&now), "%Y-%m-%d %H:%M UTC");
  const std::string table_file = fs::path(table_path).filename().string();
  ra::WriteReport(args.output,
                  ra::FillTemplate("frontend.md", {{"command", command},
                                                   {"date", date.str()},
                                                   {"calibration", tables.calibration.str()},
                                                   {"floor", tables.floor.str()},
                                                   {"loss_table", table_file},
                                                   {"accuracy", tables.accuracy.str()},
                                                   {"variants", tables.variants.str()},
                                                   {"focal", tables.focal.str()},
                                                   {"principal_points", tables.principal_points.str() +
                                                                            EurocPrincipalPointRows(args.data_dir)},
                                                   {"synthetic_focal", synthetic_focal},
                                                   {"speed", tables.speed.str()},
                                                   {"keyframe_rate", rate.empty() ? "" : ra::FillTemplate(
                                                        "frontend_keyframe_rate.md", {{"rows", rate}})}}));
  ra::WriteReport(table_path, ra::FillTemplate("loss_table.md", {{"command", command},
                                                                 {"output", args.output},
                                                                 {"rows", tables.long_table.str()}}));
  return 0;
}
