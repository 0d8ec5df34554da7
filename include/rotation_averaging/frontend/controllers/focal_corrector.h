// focal_calibration: apply. Corrects a camera's focal length when its
// focal-length check (FocalChecker) disagrees with camera_info: the camera's
// pairs are estimated again with the corrected focal length and their edges
// replace the old ones in the graph. Once corrected, the focal length is
// refined further by the loops of the averaging as loop closures arrive
// (core/estimators/loop_calibration.h). No ROS type: the node and the replay
// run it through their keyframe pipeline, and anything that holds a
// KeyframeFrontend, a FocalChecker and an averager can.
#ifndef ROTATION_AVERAGING_FRONTEND_CONTROLLERS_FOCAL_CORRECTOR_H_
#define ROTATION_AVERAGING_FRONTEND_CONTROLLERS_FOCAL_CORRECTOR_H_

#include <cstdint>
#include <functional>
#include <map>
#include <mutex>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "rotation_averaging/core/controllers/rig_model.h"
#include "rotation_averaging/core/estimators/loop_calibration.h"
#include "rotation_averaging/frontend/controllers/focal_monitor.h"
#include "rotation_averaging/frontend/controllers/keyframe_frontend.h"
#include "rotation_averaging/core/controllers/online_averager.h"
#include "rotation_averaging/frontend/estimators/bundle_adjustment.h"

namespace rotation_averaging {

// What the refinement's estimate of a camera's focal length
// (KeyframeRefinerStats::focal, relative to the one in use) says of it:
// kDisagrees when it is further from 1 than `min_correction` and than 3 of
// its deviations; kAgrees when not, and it is precise enough to have seen
// such an error (deviation at most min_correction); kCannotTell otherwise
// (too few keyframes, or motion that cannot separate the focal length from
// the points' depths or the principal point: its deviation says so).
enum class FocalVerdict { kAgrees, kDisagrees, kCannotTell };
FocalVerdict JudgeFocalEstimate(const BundleAdjustmentFocal::Estimate& estimate, double min_correction);
// "x1.0309 +- 0.0005 (matches 0.0005, principal point 0.0001), 60 keyframes",
// with decimals enough for two significant digits of every deviation.
std::string DescribeFocalEstimate(const BundleAdjustmentFocal::Estimate& estimate);

struct FocalCorrectorOptions {
  // After a correction, refine the focal length by the loops (RefineByLoops).
  bool loop_refinement = true;
  // A rig camera's other cameras count as checked when their estimate's
  // standard deviation (relative) is at most this: FocalCalibrationOptions::min_correction.
  double min_correction = 0.01;
  // A lens camera_info leaves out is given on one estimate of the check
  // when it moves a corner keypoint by at least this (px); otherwise two
  // estimates in a row must see it. 10: the one false alarm measured, on
  // rectified images of a real car's forward camera after 20 pairs, moved
  // the corners by 6.4 px, and the lenses of results/lens.md by 17-47 px; a
  // small scene (fountain-P11's 11 photographs) has one estimate only.
  double min_single_estimate_lens_px = 10.0;
  // The averaging the loops are solved with (the averager's).
  RotationAveragingOptions averaging;
};

class FocalCorrector {
 public:
  // Puts an edge into the graph (through the rig model, as the front end's
  // own edges go); false, with `error`, when it is refused.
  using AddEdge = std::function<bool(const KeyframeRelativeRotation&, std::string* error)>;

  // The front end is used only while `frontend_mutex` is held (the thread
  // that adds keyframes holds it too); every other part is read only.
  FocalCorrector(const FocalCorrectorOptions& options, KeyframeFrontend* frontend, std::mutex* frontend_mutex,
                 FocalChecker* checker, RigModel* rig, OnlineAverager* averager, AddEdge add_edge);

  // First, a camera whose check sees a radial distortion camera_info does
  // not describe (CameraFocalCheck::distortion_unmodelled) at two estimates
  // in a row that agree (within 3 standard deviations of their difference),
  // or at one that moves the corners by min_single_estimate_lens_px, gets
  // that lens (KeyframeFrontend::ApplyLensCorrection: the later estimate's
  // division model), once; its pairs' new edges replace the old ones and
  // its check starts again with the lens. One estimate of a slight lens is
  // not enough: the first, of a few pairs, can see a distortion in
  // rectified images that later ones withdraw (forward motion hardly tells
  // it from a focal length). Then it
  // corrects each camera whose latest check disagrees and has not been
  // decided yet. A rig camera only when the rig's other cameras are checked
  // as precisely as a correction needs, or corrected; never a camera whose
  // images show a lens camera_info does not describe. Edges the graph
  // refuses are reported in `warnings`. Called before each keyframe, on the
  // thread that adds keyframes.
  void ApplyCorrections(std::vector<std::string>* warnings);
  // The corrected cameras' focal lengths estimated together from the loops
  // of the graph, each pair's derivative from the front end
  // (KeyframeFrontend::FocalSensitivities), the focal check's estimate as
  // the prior; applied as a correction when the loops know the focal
  // length at least twice as precisely as the check, agree with it (within
  // 3 of its standard deviations) and move it by more than their own
  // deviation; the pairs' edges then move by their derivatives
  // (ApplyFocalCorrection, linearised). Runs when the front end's loop
  // closures (`loop_closure_edges`) have grown by a tenth since it last ran
  // (or since a correction): at a cost that grows with the log of their
  // number, and for as long as the camera's pairs are held
  // (max_correction_pairs). Called after ApplyCorrections.
  void RefineByLoops(std::uint64_t loop_closure_edges);
  // The refinement's focal estimates (KeyframeRefinerStats::focal) from its
  // refinement number `refinement`: a camera they put off (kDisagrees) is
  // corrected by its estimate, its pairs estimated again as for a check's
  // correction. The refinement estimates a rig's cameras together, so a rig
  // camera is corrected when every other camera of its rig is told there
  // too (agrees or disagrees) or was corrected; never a camera whose images
  // show a lens camera_info does not describe (its focal check says so).
  // Each refinement is looked at once; an estimate made before a
  // correction is relative to the corrected focal length by then. Called
  // before each keyframe, on the thread that adds keyframes.
  void ApplyRefinementEstimates(const std::map<std::string, BundleAdjustmentFocal::Estimate>& estimates,
                                std::uint64_t refinement, std::vector<std::string>* warnings);

  // The product of the corrections applied to each camera's focal length,
  // by camera (cameras never corrected are not listed).
  std::map<std::string, double> Corrections() const;
  // The lens given to each camera whose camera_info describes none: the
  // check's estimate it was given (cameras without one are not listed).
  std::map<std::string, RadialDistortion> LensCorrections() const;
  // Each corrected camera's latest estimate from the loops and what became
  // of it, as its log line says it (cameras the loops have not estimated
  // are not listed).
  std::map<std::string, std::string> LoopRefinements() const;
  // Log lines since the last call, each with whether it is a warning.
  std::vector<std::pair<std::string, bool>> TakeNotices();

 private:
  // The camera is held back for `reason`; says so unless the last notice
  // of it gave the same reason.
  void HoldBack(const std::string& camera, const std::string& reason);
  // The other cameras of `camera`'s rig that are not checked precisely
  // enough for it to be corrected ("a, b"; "" when there are none), given
  // the checks, the corrections (`corrected`) and the rig's cameras
  // (RigModel::RigCameras) as this round began.
  using RigCameraMap = std::map<std::string, std::pair<std::string, Eigen::Matrix3d>>;
  std::string UncheckedRigCameras(const std::string& camera, const std::map<std::string, CameraFocalCheck>& checks,
                                  const std::map<std::string, double>& corrected,
                                  const RigCameraMap& rig_cameras) const;
  // The other cameras of `camera`'s rig that are neither corrected nor
  // `settled` ("a, b"; "" when there are none or it is on no rig).
  static std::string UnsettledRigCameras(const std::string& camera, const std::map<std::string, double>& corrected,
                                         const RigCameraMap& rig_cameras,
                                         const std::function<bool(const std::string&)>& settled);
  // Gives `camera` the lens its check sees; true if it did.
  bool CorrectLens(const std::string& camera, const CameraFocalCheck& check, std::vector<std::string>* warnings);
  // Applies one check's correction, with its notice.
  void Correct(const std::string& camera, const CameraFocalCheck& check, std::vector<std::string>* warnings);
  // Multiplies the focal length in use, `given_px`, by `scale`; `estimate_px`
  // (with its deviation) is the loops' prior. `source` names the estimate
  // in the notice.
  void Correct(const std::string& camera, double scale, double given_px, std::pair<double, double> estimate_px,
               const std::string& source, std::vector<std::string>* warnings);
  // Each sensitivity's derivative as one of the graph's edges (the rig's
  // variables; an edge stored from its other end turned round), parameter p
  // being the p-th camera of `sensitivities`.
  std::vector<EdgeParameterDerivative> EdgeDerivatives(
      const ViewGraph& graph, const std::map<KeyframeKey, ViewId>& ids,
      const std::vector<std::vector<FocalSensitivity>>& sensitivities) const;
  // The loops' estimate of one camera applied (or not), as its log line's ending.
  std::string RefineOne(const std::string& camera, double e, double sigma, double center, double prior_sigma,
                        bool* disagrees);

  FocalCorrectorOptions options_;
  KeyframeFrontend* frontend_;
  std::mutex* frontend_mutex_;
  FocalChecker* checker_;
  RigModel* rig_;
  OnlineAverager* averager_;
  AddEdge add_edge_;

  // The thread that adds keyframes only.
  std::uint64_t loops_at_refinement_ = 0;
  std::uint64_t refinement_seen_ = 0;  // ApplyRefinementEstimates' latest
  // Per corrected camera: the focal length in use, px, and the latest focal
  // check's estimate of it with its deviation, px (the loops' prior).
  std::map<std::string, double> focal_in_use_px_;
  std::map<std::string, std::pair<double, double>> focal_prior_px_;
  std::map<std::string, std::pair<double, std::uint64_t>> applied_checks_;  // camera -> (given px, pairs) applied
  std::set<std::string> refused_;
  std::set<std::string> lens_decided_;  // CorrectLens tried, applied or not
  std::map<std::string, CameraFocalCheck> lens_seen_;  // the latest check that saw a lens, awaiting the next
  // The reason a camera's correction was last held back: each new estimate
  // that is held back for the same reason says nothing new.
  std::map<std::string, std::string> held_back_;

  mutable std::mutex mutex_;  // what other threads read: the three below
  std::vector<std::pair<std::string, bool>> notices_;
  std::map<std::string, double> corrections_;
  std::map<std::string, RadialDistortion> lens_corrections_;
  std::map<std::string, std::string> loop_refinements_;
};

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_FRONTEND_CONTROLLERS_FOCAL_CORRECTOR_H_
