// rotavg_images: `rotavg images`, the image front end then the averaging
// (features, matching, relative poses with rotation covariances). A program of
// its own because it needs OpenCV, which `rotavg solve` and `eval` do not load.
// Run as `rotavg images ARGS` or `rotavg_images ARGS`; `--help` lists them.
#include <cmath>
#include <iomanip>
#include <iostream>
#include <string>
#include <vector>

#include "cli.h"
#include "rotation_averaging/frontend/controllers/image_pipeline.h"
#include "rotation_averaging/frontend/estimators/bundle_adjustment.h"
#include "rotation_averaging/core/eval/rotation_evaluation.h"
#include "rotation_averaging/core/geometry/so3.h"

namespace {

using namespace rotation_averaging_cli;  // NOLINT: the tool's own helpers

const char* kUsage = R"(usage:
  rotavg images --images DIR --intrinsics CAMERA-FILE [--camera camN] [--downsample F] [--features sift|orb] [--max-features N]
               [--pairs exhaustive|sequential:N|list:FILE] [--covariance marginal|conditional] [--jackknife-grid N]
               [--graph-out graph.txt]
               [--output orientations.csv] [--gt PATH [--gt-format F]] [--verbose] [--json] [--refine]
               [--no-bundle-adjustment] [--no-rotation-model] [--no-focal-calibration]
               [the averaging options of rotavg solve: --solver --loss --weighting --sigma-max --normalization
                --no-gnc --max-iterations --self-calibration (default here: floor)]
      CAMERA-FILE: a K.txt (3x3), a COLMAP cameras.txt, or a YAML calibration (ROS camera_calibration,
      EuRoC sensor.yaml, Kalibr camchain: --camera picks one of its cameras); its lens distortion
      (plumb_bob / radtan, rational_polynomial, equidistant) is removed from the keypoints;
      features, matching, relative poses with rotation covariances, averaging (--refine: then the
      orientations refined on every pair's inlier correspondences), then bundle adjustment from the averaged
      orientations: the pairs' inliers linked into tracks, camera centres and points estimated and everything
      adjusted on the reprojection errors (--no-bundle-adjustment: the averaging's orientations), and the
      view term, the error all pairs of a view share, from the views' offsets against it; prints
      per-stage timings and per-pair statistics; --graph-out writes the view graph for `rotavg solve`;
      --no-rotation-model: every pair through the essential matrix (pairs without parallax fail instead of
      using the rotation-only model);
      --jackknife-grid N: each pair's marginal covariance is at least the jackknife's that leaves out one cell
      of an N x N grid over its inliers at a time (default 4; 0: the pixel model alone, every residual
      independent);
      --no-focal-calibration: trust the focal length of the intrinsics (by default it is estimated from the
      pairs and, when it differs by more than 0.5% and its uncertainty, corrected and the pairs estimated again)
)";

// The image pipeline's options from the command line; false with `error`.
bool ParsePipelineOptions(const Args& args, ra::ImagePipelineOptions* pipeline, std::string* error) {
  if (!ra::ParseFeatureType(args.Get("--features", "sift"), &pipeline->features.type)) {
    *error = "unknown --features (" + ra::FeatureTypeChoices() + ")";
    return false;
  }
  pipeline->features.downsample = std::atof(args.Get("--downsample", "1").c_str());
  if (!(pipeline->features.downsample > 0.0 && pipeline->features.downsample <= 1.0)) {
    *error = "--downsample must be in (0, 1] (0.25 = a quarter of the width)";
    return false;
  }
  pipeline->features.max_features = std::atoi(args.Get("--max-features", "8000").c_str());
  if (pipeline->features.max_features < 10) {
    *error = "--max-features must be >= 10";
    return false;
  }
  if (!ra::PairSelection::Parse(args.Get("--pairs", "exhaustive"), &pipeline->pairs, error)) {
    if (error->empty()) *error = "--pairs must be exhaustive, sequential:N or list:FILE";
    return false;
  }
  if (!ra::ParseRotationCovarianceModel(args.Get("--covariance", "marginal"), &pipeline->relative_pose.covariance_model)) {
    *error = "unknown --covariance (" + ra::RotationCovarianceModelChoices() + ")";
    return false;
  }
  // Photographs of real scenes: errors shared by regions of an image
  // (repeated structure) are the rule (results/README.md, "What the far-off
  // pairs hold").
  pipeline->relative_pose.jackknife_grid = std::atoi(args.Get("--jackknife-grid", "4").c_str());
  if (pipeline->relative_pose.jackknife_grid < 0 || pipeline->relative_pose.jackknife_grid > 16) {
    *error = "--jackknife-grid must be in [0, 16] (0: the pixel model's covariance alone)";
    return false;
  }
  pipeline->relative_pose.rotation_model = !args.Has("--no-rotation-model");
  // Image folders come with intrinsics of any quality; the correction is
  // applied only when the pairs clearly ask for it (FocalCalibrationOptions).
  pipeline->focal.enabled = !args.Has("--no-focal-calibration");
  return true;
}

// The pairs' two-view results, the first 20 unless `verbose`.
void PrintPairs(const ra::ImagePipelineResult& front, bool verbose) {
  std::cout << "per pair (image1 image2: matches, inliers, sigma px, parallax deg, homography inlier share, ms, model or failure):\n";
  int shown = 0;
  for (const ra::PairReport& p : front.pairs) {
    if (!verbose && shown >= 20) break;
    ++shown;
    std::cout << "  " << front.graph.FindView(p.image1)->name << " " << front.graph.FindView(p.image2)->name << ": "
              << p.matches << ", " << p.pose.inliers.size() << ", " << std::setprecision(3) << p.pose.sigma_px << ", "
              << p.pose.median_parallax_deg << ", " << p.pose.homography_inlier_ratio << ", " << p.milliseconds << ", "
              << (p.pose.success ? std::string(ra::TwoViewModelName(p.pose.model)) : std::string(ra::TwoViewFailureName(p.pose.failure)) + " (" + p.pose.message + ")")
              << "\n";
  }
  if (!verbose && front.pairs.size() > 20) std::cout << "  ... " << front.pairs.size() - 20 << " more (--verbose)\n";
}

// The averaging sees each pair through its two-view summary; the tracks
// see each point in every view at once, which holds the views that the
// summaries of wide-baseline or repetitive pairs mislead (results/frontend.md,
// "then bundle adjusted" against the averaging alone).
void BundleAdjust(const ra::ImagePipelineResult& front, const ra::RotationAveragingSummary& summary,
                  ra::ViewOrientations* orientations) {
  ra::BundleAdjustmentSummary adjustment;
  ra::RefineRotationsWithBundleAdjustment(ra::CorrespondencesOfEdges(front), ra::BundleAdjustmentOptions(),
                                          orientations, &adjustment);
  std::cout << adjustment.Report() << std::endl;
  // What every pair of a view shares, the averaging cannot see and the
  // adjustment removes: its size says how far the pairs' covariances
  // (with the floor) understate their errors against the true poses.
  const double floor_rad = summary.LargestComponentFloorRad();
  const double view_rad = ra::ViewTermRad(
      ra::EvaluateEdgeCovariances(front.graph, ra::NameOrientations(front.graph, *orientations), floor_rad));
  if (std::isfinite(view_rad)) {
    std::cout << "view term: " << view_rad * 180.0 / M_PI
              << " deg per axis (the error all pairs of a view share, from the views' offsets against the "
                 "bundle adjustment); with the floor, a pair's covariance against the true poses: C + s^2 I, s = "
              << ra::FloorWithViewTermRad(floor_rad, view_rad) * 180.0 / M_PI << " deg"
              << std::endl;
  }
}

int Images(int argc, char** argv) {
  Args args;
  std::string error;
  if (!ParseArgs(argc, argv, 1, {"--no-gnc", "--json", "--verbose", "--refine", "--no-bundle-adjustment", "--no-rotation-model", "--no-focal-calibration"}, &args, &error)) return Fail(error);
  if (!CheckKnown(args,
                  Concat({"--images", "--intrinsics", "--camera", "--downsample", "--features", "--max-features", "--pairs",
                          "--covariance", "--jackknife-grid", "--graph-out", "--output", "--gt", "--gt-format"},
                         kAveragingFlags),
                  &error)) {
    return Fail(error);
  }
  if (!args.Has("--images") || !args.Has("--intrinsics")) return Fail("images needs --images DIR and --intrinsics CAMERA-FILE");
  ra::ImagePipelineOptions pipeline;
  if (!ParsePipelineOptions(args, &pipeline, &error)) return Fail(error);
  ra::RotationAveragingOptions options;
  // Two-view covariances from pixel noise miss the errors that do not
  // shrink with the matches (results/frontend.md, "Calibration").
  options.self_calibration = ra::CovarianceSelfCalibration::kFloor;
  if (!ParseAveragingOptions(args, &options, &error)) return Fail(error);
  const std::string output = args.Get("--output");
  if (output.empty() && !args.Has("--gt") && !args.Has("--graph-out")) {
    return Fail("images needs --output, --graph-out or --gt");
  }
  ra::CameraIntrinsics k;
  if (!ra::ReadCameraIntrinsics(args.Get("--intrinsics"), &k, &error, nullptr, nullptr, args.Get("--camera", ""))) {
    return Fail(error);
  }
  const std::vector<std::string> images = ra::ListImages(args.Get("--images"));
  if (images.size() < 2) return Fail("need at least two images in " + args.Get("--images"));

  const ra::ImagePipelineResult front = ra::BuildViewGraphFromImages(images, k, pipeline);
  std::cout << front.Report() << "\n";
  PrintPairs(front, args.Has("--verbose"));
  if (args.Has("--graph-out")) {
    if (!ra::WriteRotavgGraph(args.Get("--graph-out"), front.graph, &error)) return Fail(error);
    std::cout << "wrote the view graph to " << args.Get("--graph-out") << "\n";
  }
  ra::ViewOrientations orientations;
  ra::RotationAveragingSummary summary;
  const bool ok = ra::SolveRotationAveraging(front.graph, options, &orientations, &summary);
  std::cout << "averaging: " << summary.Report() << std::endl;
  if (args.Has("--refine")) {
    ra::CorrespondenceRefinementSummary refinement;
    ra::RefineRotationsWithCorrespondences(ra::CorrespondencesOfEdges(front), ra::CorrespondenceRefinementOptions(),
                                           &orientations, &refinement);
    std::cout << refinement.Report() << std::endl;
  }
  if (!args.Has("--no-bundle-adjustment")) BundleAdjust(front, summary, &orientations);
  const int rc = WriteAndScore(args, ra::NameOrientations(front.graph, orientations));
  return rc != 0 ? rc : (ok ? 0 : 1);
}

}  // namespace

int main(int argc, char** argv) { return rotation_averaging_cli::RunCommand(argc, argv, kUsage, Images); }
