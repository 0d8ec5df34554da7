#include "rotation_averaging/frontend/controllers/focal_corrector.h"

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <sstream>
#include <tuple>
#include <utility>


namespace rotation_averaging {
namespace {

// Why a camera whose images show a lens camera_info leaves out is not
// corrected, by either estimate.
constexpr char kUnmodelledLens[] =
    "its images are distorted and camera_info has no distortion model, which the estimate cannot tell from a "
    "focal length error; give the model first";

// A focal check's estimate and its standard deviation, px.
std::pair<double, double> FocalEstimatePx(const CameraFocalCheck& check) {
  return {check.given_focal_px * check.calibration.scale, check.given_focal_px * check.calibration.standard_deviation};
}

}  // namespace

FocalVerdict JudgeFocalEstimate(const BundleAdjustmentFocal::Estimate& e, double min_correction) {
  if (!e.determined || !std::isfinite(e.scale) || !std::isfinite(e.sigma)) return FocalVerdict::kCannotTell;
  if (std::abs(e.scale - 1.0) > std::max(min_correction, 3.0 * e.sigma)) return FocalVerdict::kDisagrees;
  return e.sigma <= min_correction ? FocalVerdict::kAgrees : FocalVerdict::kCannotTell;
}

std::string DescribeFocalEstimate(const BundleAdjustmentFocal::Estimate& e) {
  // Decimals enough for two significant digits of the smallest deviation
  // (at least four, at most eight): a rig's refinement over hundreds of
  // keyframes knows its focal length to a few parts in a hundred thousand,
  // which four decimals print as 0.0000.
  double smallest = INFINITY;
  for (const double d : {e.sigma, e.sigma_matches, e.sigma_principal_point}) {
    if (std::isfinite(d) && d > 0.0) smallest = std::min(smallest, d);
  }
  const int decimals =
      std::isfinite(smallest) ? std::clamp(1 - static_cast<int>(std::floor(std::log10(smallest))), 4, 8) : 4;
  std::ostringstream out;
  out << std::fixed << std::setprecision(decimals) << "x" << e.scale << " +- " << e.sigma << " (matches " << e.sigma_matches
      << ", principal point " << e.sigma_principal_point << "), " << e.views << " keyframes";
  return out.str();
}

FocalCorrector::FocalCorrector(const FocalCorrectorOptions& options, KeyframeFrontend* frontend,
                               std::mutex* frontend_mutex, FocalChecker* checker, RigModel* rig,
                               OnlineAverager* averager, AddEdge add_edge)
    : options_(options),
      frontend_(frontend),
      frontend_mutex_(frontend_mutex),
      checker_(checker),
      rig_(rig),
      averager_(averager),
      add_edge_(std::move(add_edge)) {}

std::map<std::string, double> FocalCorrector::Corrections() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return corrections_;
}

std::map<std::string, RadialDistortion> FocalCorrector::LensCorrections() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return lens_corrections_;
}

bool FocalCorrector::CorrectLens(const std::string& camera, const CameraFocalCheck& check,
                                 std::vector<std::string>* warnings) {
  lens_decided_.insert(camera);
  std::vector<KeyframeRelativeRotation> edges;
  std::string why;
  bool applied = false;
  {
    std::lock_guard<std::mutex> lock(*frontend_mutex_);
    applied = frontend_->ApplyLensCorrection(camera, check.distortion.lambda, &edges, &why);
  }
  std::ostringstream text;
  text << std::fixed << std::setprecision(3) << camera
       << ": camera_info describes no lens, and its images show a radial distortion (division model) "
       << check.distortion.lambda << " +- " << check.distortion.standard_deviation << ", "
       << std::setprecision(1) << check.distortion.corner_shift_px << " px at the corners";
  if (!applied) {
    text << ": not corrected: " << why;
    std::lock_guard<std::mutex> lock(mutex_);
    notices_.emplace_back(text.str(), true);
    return false;
  }
  std::size_t refused = 0;
  for (const KeyframeRelativeRotation& e : edges) {
    std::string error;
    if (!add_edge_(e, &error)) {
      ++refused;
      if (warnings) warnings->push_back(camera + ": an edge estimated again with its lens was refused: " + error);
    }
  }
  text << ": its keypoints are undistorted by that lens from now on, " << edges.size() - refused
       << " of its pairs estimated again with it; give camera_info the lens (distortion_model and D)";
  std::lock_guard<std::mutex> lock(mutex_);
  lens_corrections_[camera] = check.distortion;
  notices_.emplace_back(text.str(), true);
  return true;
}

std::map<std::string, std::string> FocalCorrector::LoopRefinements() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return loop_refinements_;
}

std::vector<std::pair<std::string, bool>> FocalCorrector::TakeNotices() {
  std::lock_guard<std::mutex> lock(mutex_);
  std::vector<std::pair<std::string, bool>> out;
  out.swap(notices_);
  return out;
}

void FocalCorrector::HoldBack(const std::string& camera, const std::string& reason) {
  std::string& said = held_back_[camera];
  if (said == reason) return;
  said = reason;
  std::lock_guard<std::mutex> lock(mutex_);
  notices_.emplace_back(camera + ": focal length not corrected: " + reason, true);
}

std::string FocalCorrector::UncheckedRigCameras(const std::string& camera,
                                                const std::map<std::string, CameraFocalCheck>& checks,
                                                const std::map<std::string, double>& corrected,
                                                const RigCameraMap& rig_cameras) const {
  // The cameras of a rig (extrinsics known) share one orientation per
  // capture: correcting one while another stays as wrong makes their edges
  // disagree, which can cost more than an error they share (it did on the
  // demo rig, whose forward camera cannot be checked). So a rig camera is
  // corrected only when each other camera of its rig is checked as
  // precisely as a correction needs (its deviation within
  // min_correction) and agrees, or disagrees too, or was corrected.
  return UnsettledRigCameras(camera, corrected, rig_cameras, [&](const std::string& other) {
    const auto c = checks.find(other);
    return c != checks.end() && c->second.calibration.estimated &&
           (c->second.disagrees || c->second.calibration.standard_deviation <= options_.min_correction);
  });
}

std::string FocalCorrector::UnsettledRigCameras(const std::string& camera,
                                                const std::map<std::string, double>& corrected,
                                                const RigCameraMap& rig_cameras,
                                                const std::function<bool(const std::string&)>& settled) {
  const auto rig = rig_cameras.find(camera);
  std::string unsettled;
  if (rig == rig_cameras.end()) return unsettled;
  for (const auto& [other, other_rig] : rig_cameras) {
    if (other == camera || other_rig.first != rig->second.first || corrected.count(other) || settled(other)) continue;
    unsettled += (unsettled.empty() ? "" : ", ") + other;
  }
  return unsettled;
}

void FocalCorrector::ApplyCorrections(std::vector<std::string>* warnings) {
  const std::map<std::string, CameraFocalCheck> checks = checker_->Checks();
  const std::map<std::string, double> corrected = Corrections();
  const RigCameraMap rig_cameras = rig_->RigCameras();
  // The lens first: until it is given, the check's focal estimate is bent
  // by it. The check measures it precisely (a division model fitted to
  // every pair's matches) and only where it is beyond the noise and not
  // explained as well by the focal length alone.
  for (const auto& [camera, check] : checks) {
    if (lens_decided_.count(camera) || !check.distortion_checked) continue;
    const auto seen = lens_seen_.find(camera);
    if (!check.distortion_unmodelled) {
      if (seen != lens_seen_.end() && seen->second.pairs_seen < check.pairs_seen) lens_seen_.erase(seen);
      continue;
    }
    if (check.distortion.corner_shift_px >= options_.min_single_estimate_lens_px) {
      lens_seen_.erase(camera);
      CorrectLens(camera, check, warnings);
      continue;
    }
    if (seen == lens_seen_.end() || seen->second.pairs_seen >= check.pairs_seen) {
      lens_seen_[camera] = check;  // the first, or of pairs counted afresh
      continue;
    }
    const RadialDistortion& before = seen->second.distortion;
    const double deviation = std::hypot(before.standard_deviation, check.distortion.standard_deviation);
    if (std::abs(check.distortion.lambda - before.lambda) > 3.0 * deviation) {
      seen->second = check;  // not the same lens: wait for the next
      continue;
    }
    lens_seen_.erase(seen);
    CorrectLens(camera, check, warnings);
  }
  for (const auto& [camera, check] : checks) {
    if (!check.disagrees || refused_.count(camera)) continue;
    const auto applied = applied_checks_.find(camera);
    if (applied != applied_checks_.end() && applied->second == std::make_pair(check.given_focal_px, check.pairs_seen)) {
      continue;  // this estimate is decided already
    }
    if (check.distortion_unmodelled) {
      // A lens the model leaves out bends the focal estimate too: correcting
      // it would fit the focal length to the distortion. Once the lens is
      // given, the check starts again with it.
      applied_checks_[camera] = {check.given_focal_px, check.pairs_seen};
      if (!LensCorrections().count(camera)) HoldBack(camera, kUnmodelledLens);
      continue;
    }
    const std::string unchecked = UncheckedRigCameras(camera, checks, corrected, rig_cameras);
    if (!unchecked.empty()) {
      // Not decided for good: the other cameras' checks may settle while
      // this estimate stands (the estimates of a rig's cameras arrive one
      // after the other), and it is looked at again with every keyframe.
      HoldBack(camera, "the other cameras of its rig (" + unchecked +
                           ") are not checked precisely enough, and correcting one camera of a rig alone "
                           "makes its cameras disagree; fix camera_info");
      continue;
    }
    applied_checks_[camera] = {check.given_focal_px, check.pairs_seen};
    held_back_.erase(camera);
    Correct(camera, check, warnings);
  }
}

void FocalCorrector::ApplyRefinementEstimates(const std::map<std::string, BundleAdjustmentFocal::Estimate>& estimates,
                                              std::uint64_t refinement, std::vector<std::string>* warnings) {
  if (refinement == 0 || refinement <= refinement_seen_) return;
  refinement_seen_ = refinement;
  const std::map<std::string, CameraFocalCheck> checks = checker_->Checks();
  const std::map<std::string, double> corrected = Corrections();
  const RigCameraMap rig_cameras = rig_->RigCameras();
  std::map<std::string, FocalVerdict> verdicts;
  for (const auto& [camera, e] : estimates) verdicts[camera] = JudgeFocalEstimate(e, options_.min_correction);
  for (const auto& [camera, e] : estimates) {
    if (verdicts.at(camera) != FocalVerdict::kDisagrees || refused_.count(camera)) continue;
    const auto check = checks.find(camera);
    if (check != checks.end() && check->second.distortion_unmodelled) {
      // (With the lens given since, the estimate was made without it.)
      if (!LensCorrections().count(camera)) HoldBack(camera, kUnmodelledLens);
      continue;
    }
    // The refinement estimates a rig's cameras together: the others are
    // settled when it tells theirs (agrees or disagrees).
    const std::string untold = UnsettledRigCameras(camera, corrected, rig_cameras, [&](const std::string& other) {
      const auto v = verdicts.find(other);
      return v != verdicts.end() && v->second != FocalVerdict::kCannotTell;
    });
    if (!untold.empty()) {
      HoldBack(camera, "the refinement cannot tell the focal lengths of the other cameras of its rig (" + untold +
                           "), and correcting one camera of a rig alone makes its cameras disagree; fix camera_info");
      continue;
    }
    double given_px = 0.0;
    {
      std::lock_guard<std::mutex> lock(*frontend_mutex_);
      given_px = frontend_->FocalInUsePx(camera);
    }
    if (!(given_px > 0.0)) continue;
    held_back_.erase(camera);
    Correct(camera, e.scale, given_px, {given_px * e.scale, given_px * e.sigma},
            "the refinement's estimate " + DescribeFocalEstimate(e), warnings);
  }
}

void FocalCorrector::Correct(const std::string& camera, const CameraFocalCheck& check,
                             std::vector<std::string>* warnings) {
  Correct(camera, check.calibration.scale, check.given_focal_px, FocalEstimatePx(check), "the focal check's estimate",
          warnings);
}

void FocalCorrector::Correct(const std::string& camera, double scale, double given_px,
                             std::pair<double, double> estimate_px, const std::string& source,
                             std::vector<std::string>* warnings) {
  std::vector<KeyframeRelativeRotation> edges;
  std::string why;
  bool ok = false;
  double correction = 1.0;
  {
    std::lock_guard<std::mutex> lock(*frontend_mutex_);
    ok = frontend_->ApplyFocalCorrection(camera, scale, &edges, &why);
    correction = frontend_->FocalCorrection(camera);
    if (ok) checker_->Submit(frontend_->TakeFocalJobs());
  }
  std::ostringstream line;
  line << std::fixed << std::setprecision(4) << camera << ": ";
  if (!ok) {
    refused_.insert(camera);
    line << "focal length not corrected: " << why;
  } else {
    checker_->ExpectFocal(camera, given_px * scale);
    focal_in_use_px_[camera] = given_px * scale;
    focal_prior_px_[camera] = estimate_px;
    loops_at_refinement_ = 0;  // the loops look again at the new focal length
    std::size_t replaced = 0;
    for (const KeyframeRelativeRotation& e : edges) {
      std::string error;
      if (add_edge_(e, &error)) {
        ++replaced;
      } else if (warnings) {
        warnings->push_back("re-estimated edge dropped: " + error);
      }
    }
    line << "focal length corrected by x" << scale << " (x" << correction << " of camera_info's in all; " << source
         << "): " << replaced << " of its pairs estimated again";
  }
  std::lock_guard<std::mutex> lock(mutex_);
  if (ok) corrections_[camera] = correction;
  notices_.emplace_back(line.str(), true);
}

void FocalCorrector::RefineByLoops(std::uint64_t loops) {
  if (!options_.loop_refinement || focal_in_use_px_.empty()) return;
  // Each estimate is at most a tenth of the loops behind: the loops that
  // close last (the longest, around the whole trajectory) decide the most.
  if (loops == 0 || loops <= loops_at_refinement_ || 10 * loops < 11 * loops_at_refinement_) return;
  loops_at_refinement_ = loops;
  // The prior: the latest check of the focal length in use, when there is
  // one (a check at the former focal length is dropped by ExpectFocal).
  for (const auto& [camera, check] : checker_->Checks()) {
    const auto in_use = focal_in_use_px_.find(camera);
    if (in_use == focal_in_use_px_.end() || !check.calibration.estimated ||
        std::abs(check.given_focal_px - in_use->second) > 1e-9 * in_use->second) {
      continue;
    }
    focal_prior_px_[camera] = FocalEstimatePx(check);
  }
  std::vector<std::string> cameras;
  std::vector<std::vector<FocalSensitivity>> sensitivities;
  {
    std::lock_guard<std::mutex> lock(*frontend_mutex_);
    for (const auto& [camera, px] : focal_in_use_px_) {
      std::vector<FocalSensitivity> s = frontend_->FocalSensitivities(camera);
      if (s.empty()) continue;
      cameras.push_back(camera);
      sensitivities.push_back(std::move(s));
    }
  }
  if (cameras.empty()) return;
  ViewGraph graph;
  std::map<KeyframeKey, ViewId> ids;
  ViewOrientations start;
  averager_->PendingGraph(&graph, &ids, &start);
  LoopCalibrationOptions options;
  options.averaging = options_.averaging;
  for (const std::string& camera : cameras) {
    const double in_use = focal_in_use_px_.at(camera);
    const std::pair<double, double>& prior = focal_prior_px_.at(camera);
    options.prior_center.push_back(prior.first / in_use - 1.0);
    options.prior_sigma.push_back(prior.second / in_use);
  }
  const LoopCalibrationResult result =
      EstimateParametersFromLoops(graph, EdgeDerivatives(graph, ids, sensitivities), options, start);
  std::vector<std::pair<std::string, bool>> notices;
  if (!result.success) {
    notices.emplace_back("focal lengths not refined by the loops: " + result.message, false);
  }
  std::map<std::string, std::string> latest;  // camera -> its line
  for (std::size_t p = 0; result.success && p < cameras.size(); ++p) {
    const std::string& camera = cameras[p];
    const double center = options.prior_center[p], prior_sigma = options.prior_sigma[p];
    std::ostringstream line;
    line << std::fixed << std::setprecision(5) << camera << ": the loops put its focal length at x"
         << 1.0 + result.value[p] << " +- " << result.sigma[p] << " of the one in use (the focal check: x"
         << 1.0 + center << " +- " << prior_sigma << "; " << loops << " loop closures, " << result.solves
         << " averaging solves): ";
    bool disagrees = false;
    line << RefineOne(camera, result.value[p], result.sigma[p], center, prior_sigma, &disagrees);
    notices.emplace_back(line.str(), disagrees);
    latest[camera] = line.str();
  }
  std::lock_guard<std::mutex> lock(mutex_);
  notices_.insert(notices_.end(), notices.begin(), notices.end());
  for (auto& [camera, line] : latest) loop_refinements_[camera] = std::move(line);
}

std::vector<EdgeParameterDerivative> FocalCorrector::EdgeDerivatives(
    const ViewGraph& graph, const std::map<KeyframeKey, ViewId>& ids,
    const std::vector<std::vector<FocalSensitivity>>& sensitivities) const {
  // Graph edges by (views, source, channel), as the rig model turns a
  // camera pair into one (RigModel::ToVariables).
  std::map<std::tuple<ViewId, ViewId, EdgeSource, std::uint32_t>, std::size_t> edge_of;
  for (std::size_t k = 0; k < graph.NumEdges(); ++k) {
    const RelativeRotation& e = graph.Edges()[k];
    edge_of[{std::min(e.view1, e.view2), std::max(e.view1, e.view2), e.source, e.channel}] = k;
  }
  std::vector<EdgeParameterDerivative> derivatives;
  for (std::size_t p = 0; p < sensitivities.size(); ++p) {
    for (const FocalSensitivity& s : sensitivities[p]) {
      KeyframeRelativeRotation m;
      m.keyframe1 = s.keyframe1;
      m.keyframe2 = s.keyframe2;
      m.source = s.source;
      KeyframeRelativeRotation v;
      if (!rig_->ToVariables(m, &v)) continue;  // two cameras of one capture: no edge
      const auto id1 = ids.find(v.keyframe1), id2 = ids.find(v.keyframe2);
      if (id1 == ids.end() || id2 == ids.end()) continue;
      const auto edge = edge_of.find({std::min(id1->second, id2->second), std::max(id1->second, id2->second),
                                      v.source, v.channel});
      if (edge == edge_of.end()) continue;  // not in the graph (rejected, or capped)
      // An edge stored from the other end is the inverse, whose right
      // perturbation is -R_21^T times the variable edge's.
      Eigen::Vector3d d = rig_->PerturbationToVariables(s.keyframe2.frame_id, s.derivative);
      const RelativeRotation& stored = graph.Edges()[edge->second];
      if (stored.view1 != id1->second) d = -(stored.rotation.transpose() * d);
      derivatives.push_back(EdgeParameterDerivative{edge->second, static_cast<int>(p), d});
    }
  }
  return derivatives;
}

std::string FocalCorrector::RefineOne(const std::string& camera, double e, double sigma, double center,
                                      double prior_sigma, bool* disagrees) {
  *disagrees = false;
  if (!(sigma <= 0.5 * prior_sigma)) return "not refined, the loops know it no better than the check";
  if (std::abs(e - center) > 3.0 * prior_sigma) {
    // Something else bends the loops (extrinsics, a lens, outliers): the
    // focal length is not the parameter to fit to them.
    *disagrees = true;
    return "not refined, they disagree with the check";
  }
  if (std::abs(e) <= sigma) return "kept, within the loops' deviation";
  std::vector<KeyframeRelativeRotation> edges;
  std::string why;
  bool ok = false;
  double correction = 1.0;
  {
    std::lock_guard<std::mutex> lock(*frontend_mutex_);
    ok = frontend_->ApplyFocalCorrection(camera, 1.0 + e, &edges, &why, /*linearised=*/true);
    correction = frontend_->FocalCorrection(camera);
  }
  if (!ok) {
    *disagrees = true;
    return "not refined: " + why;
  }
  focal_in_use_px_[camera] *= 1.0 + e;
  checker_->ExpectFocal(camera, focal_in_use_px_[camera]);
  std::size_t replaced = 0;
  for (const KeyframeRelativeRotation& edge : edges) {
    if (add_edge_(edge, nullptr)) ++replaced;
  }
  {
    std::lock_guard<std::mutex> lock(mutex_);
    corrections_[camera] = correction;
  }
  // A refinement of a correction already announced: not a warning.
  std::ostringstream refined;
  refined << std::fixed << "refined (x" << std::setprecision(6) << correction << " of camera_info's in all): " << replaced
          << " of its pairs' edges moved by their derivatives";
  return refined.str();
}

}  // namespace rotation_averaging
