#include "ros/keyframe_pipeline.h"

#include <cv_bridge/cv_bridge.h>
#include <sensor_msgs/image_encodings.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <iomanip>
#include <limits>
#include <map>
#include <opencv2/imgcodecs.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/core/io/graph_io.h"
#include "core/estimators/loop_calibration.h"
#include "core/util/option_check.h"
#include "ros/msg_conversion.h"

namespace rotation_averaging {
namespace {

std::string Replace(std::string text, const std::string& key, const std::string& value) {
  for (std::size_t at = text.find(key); at != std::string::npos; at = text.find(key, at + value.size())) {
    text.replace(at, key.size(), value);
  }
  return text;
}

// Reads one parameter into `field`, which holds its default: under `name`,
// else under a former name, with a deprecation warning.
class ParameterReader {
 public:
  ParameterReader(const ParameterSource& params, std::vector<std::string>* warnings)
      : params_(params), warnings_(warnings) {}

  template <typename T>
  void Read(const std::string& name, T* field, std::initializer_list<const char*> former = {}) {
    if (params_.Get(name, field)) return;
    for (const char* old : former) {
      if (params_.Get(old, field)) {
        Warn(std::string("parameter '") + old + "' is deprecated: use '" + name + "'");
        return;
      }
    }
  }
  void Read(const std::string& name, std::size_t* field, std::initializer_list<const char*> former = {}) {
    int value = static_cast<int>(std::min<std::size_t>(*field, static_cast<std::size_t>(std::numeric_limits<int>::max())));
    Read(name, &value, former);
    if (value < 0) {
      Problem(name + " must be at least 0 (got " + std::to_string(value) + ")");
    } else {
      *field = static_cast<std::size_t>(value);
    }
  }
  // An enumeration by name: `parse` turns the text into the value.
  template <typename E>
  void ReadChoice(const std::string& name, E* field, const char* (*to_name)(E), bool (*parse)(const std::string&, E*),
                  const std::string& choices) {
    std::string text = to_name(*field);
    Read(name, &text);
    if (!parse(text, field)) Problem(name + " '" + text + "' is not one of " + choices);
  }
  void Warn(const std::string& warning) {
    if (warnings_) warnings_->push_back(warning);
  }
  void Problem(const std::string& problem) {
    if (problem_.empty()) problem_ = problem;
  }
  const std::string& FirstProblem() const { return problem_; }

 private:
  const ParameterSource& params_;
  std::vector<std::string>* warnings_;
  std::string problem_;
};

// The size a PNG or JPEG declares in its header, read before decoding: the
// decoder allocates the whole image from that header before it reads the
// pixels, so a damaged or hostile header of a few bytes asks for gigabytes.
// PNG and JPEG are what image_transport's compressed transport sends; any
// other format is refused. Returns the format's name, or "" when the bytes are
// neither (or their header is cut short).
std::string CompressedImageSize(const std::vector<std::uint8_t>& d, std::uint32_t* width, std::uint32_t* height) {
  auto be16 = [&d](std::size_t at) { return static_cast<std::uint32_t>(d[at] << 8 | d[at + 1]); };
  auto be32 = [&](std::size_t at) { return be16(at) << 16 | be16(at + 2); };
  static const std::uint8_t kPng[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1A, '\n'};
  if (d.size() >= 24 && std::equal(kPng, kPng + 8, d.begin())) {
    if (d[12] != 'I' || d[13] != 'H' || d[14] != 'D' || d[15] != 'R') return "";
    *width = be32(16);
    *height = be32(20);
    return "PNG";
  }
  if (d.size() < 4 || d[0] != 0xFF || d[1] != 0xD8) return "";
  // JPEG: marker segments up to the first start-of-frame, which holds the size.
  std::size_t at = 2;
  while (at + 4 <= d.size()) {
    if (d[at] != 0xFF) return "";
    const std::uint8_t marker = d[at + 1];
    if (marker == 0xFF) {  // fill byte
      ++at;
      continue;
    }
    if (marker == 0xD9 || marker == 0xDA) return "";  // end of image or scan data before any frame
    const std::uint32_t length = be16(at + 2);
    if (length < 2) return "";
    const bool start_of_frame = marker >= 0xC0 && marker <= 0xCF && marker != 0xC4 && marker != 0xC8 &&
                                marker != 0xCC;
    if (start_of_frame) {
      if (at + 9 > d.size() || length < 7) return "";
      *height = be16(at + 5);
      *width = be16(at + 7);
      return "JPEG";
    }
    at += 2 + length;
  }
  return "";
}

// The largest keyframe accepted, whatever camera_info says: above
// any sensor a mapping stack runs at keyframe rate (134 Mpixel), and a bound
// on what one message can make the decoder allocate (a progressive JPEG holds
// every coefficient of the image while it decodes).
constexpr std::uint64_t kMaxKeyframePixels = std::uint64_t{1} << 27;

}  // namespace

std::string DefaultVocabularyPath() {
  // The devel space's, where the build trains it; else the install space's,
  // where `make install` copies it. Both paths are set by src/ros/CMakeLists.txt.
  std::error_code ec;
  if (!std::filesystem::exists(ROTAVG_DEFAULT_VOCABULARY, ec) && std::filesystem::exists(ROTAVG_INSTALLED_VOCABULARY, ec)) {
    return ROTAVG_INSTALLED_VOCABULARY;
  }
  return ROTAVG_DEFAULT_VOCABULARY;
}

std::string KeyframeFrameName(const std::string& format, const KeyframeKey& key) {
  return Replace(Replace(format, "{frame_id}", key.frame_id), "{stamp_ns}", std::to_string(key.stamp_ns));
}

PipelineConfig::PipelineConfig() {
  // The node's defaults where they differ from the libraries': posterior
  // covariances in ~orientations (an extra output the library leaves off).
  averager.averaging.posterior_covariance_max_views = 20000;
}

bool PipelineConfig::Validate(std::string* error) const {
  std::string averager_error, frontend_error, selection_error;
  return OptionCheck()
      .Require(tf_mode == "all_keyframes" || tf_mode == "latest_per_camera" || tf_mode == "none",
               "tf_mode '" + tf_mode + "' is not one of all_keyframes, latest_per_camera, none")
      .Require(image_transport == "raw" || image_transport == "compressed",
               "image_transport '" + image_transport + "' is not one of raw, compressed")
      .Require(image_type == "auto" || image_type == "raw" || image_type == "rectified",
               "image_type '" + image_type + "' is not one of auto, raw, rectified")
      .Require(keyframe_selection == "motion" || keyframe_selection == "all",
               "keyframe_selection '" + keyframe_selection + "' is not one of motion, all")
      .Require(focal_calibration == "warn" || focal_calibration == "apply" || focal_calibration == "off",
               "focal_calibration '" + focal_calibration + "' is not one of warn, apply, off")
      .Require(selection.Validate(&selection_error), selection_error)
      .AtLeast("max_image_queue", static_cast<double>(max_image_queue), 1)
      .Above("marker_spacing_m", marker_spacing_m, 0.0)
      .AtLeast("marker_max_keyframes", marker_max_keyframes, 1)
      .NotNan("autosave_period_s", autosave_period_s)
      .Require(averager.Validate(&averager_error), averager_error)
      .Require(frontend.Validate(&frontend_error), frontend_error)
      .Ok(error);
}

bool ReadPipelineConfig(const ParameterSource& params, PipelineConfig* config, std::vector<std::string>* warnings,
                        std::string* error) {
  PipelineConfig& c = *config;
  ParameterReader r(params, warnings);
  r.Read("fixed_frame", &c.fixed_frame);
  r.Read("tf_mode", &c.tf_mode);
  r.Read("keyframe_frame_format", &c.keyframe_frame_format);
  r.Read("latest_frame_format", &c.latest_frame_format);
  r.Read("markers", &c.markers);
  r.Read("marker_spacing_m", &c.marker_spacing_m, {"marker_spacing"});
  r.Read("marker_max_keyframes", &c.marker_max_keyframes);

  OnlineAveragerOptions& a = c.averager;
  RotationAveragingOptions& o = a.averaging;
  r.Read("solve_period_s", &a.solve_period_s, {"solve_period"});
  r.Read("solve_early_on_loop_closure", &a.solve_early_on_loop_closure);
  r.ReadChoice("loss", &o.loss, &LossTypeName, &ParseLossType, LossTypeChoices());
  r.ReadChoice("weighting", &o.weighting, &EdgeWeightingName, &ParseEdgeWeighting, EdgeWeightingChoices());
  r.ReadChoice("solver", &o.solver, &SolverTypeName, &ParseSolverType, SolverTypeChoices());
  r.Read("loss_scale", &o.loss_scale, {"sigma_max"});
  r.Read("max_iterations", &o.max_iterations);
  r.Read("local_solve_min_views", &a.local_solve_min_views, {"local_solve_min_keyframes"});
  r.Read("local_solve_hops", &a.local.hops);
  r.Read("local_solve_max_views", &a.local.max_views, {"local_solve_max_keyframes"});
  r.Read("full_solve_every", &a.full_solve_every);
  r.Read("background_full_solves", &a.background_full_solves);
  r.Read("posterior_covariance_max_views", &o.posterior_covariance_max_views, {"covariance_max_keyframes"});

  r.Read("image_topics", &c.image_topics);
  r.Read("image_transport", &c.image_transport);
  r.Read("image_type", &c.image_type);
  KeyframeFrontendOptions& f = c.frontend;
  r.Read("downsample", &f.features.downsample, {"image_downsample"});
  r.ReadChoice("features", &f.features.type, &FeatureTypeName, &ParseFeatureType, FeatureTypeChoices());
  r.Read("max_features", &f.features.max_features);
  r.Read("rig_stamp_tolerance_s", &f.rig_stamp_tolerance_s, {"rig_stamp_tolerance"});
  c.rig.stamp_tolerance_s = f.rig_stamp_tolerance_s;
  c.selection.rig_stamp_tolerance_s = f.rig_stamp_tolerance_s;
  r.Read("keyframe_selection", &c.keyframe_selection);
  r.Read("keyframe_min_motion_deg", &c.selection.min_motion_deg);
  r.Read("keyframe_min_tracked_fraction", &c.selection.min_tracked_fraction);
  r.Read("keyframe_max_interval_s", &c.selection.max_interval_s);
  r.Read("focal_calibration", &c.focal_calibration);
  r.Read("focal_loop_refinement", &c.focal_loop_refinement);
  r.Read("use_rig_extrinsics", &c.rig.enabled);
  r.Read("rig_frame", &c.rig.rig_frame);
  r.Read("covisibility_window", &f.covisibility_window);
  r.Read("window_pairs", &f.window_pairs);
  r.Read("num_threads", &f.num_threads);
  r.Read("max_loop_candidates", &f.max_loop_candidates);
  r.Read("min_loop_inliers", &f.min_loop_inliers);
  r.Read("one_loop_per_place", &f.one_loop_per_place);
  r.Read("jackknife_grid", &f.relative_pose.jackknife_grid, {"covariance_jackknife_grid"});
  r.Read("loop_jackknife_grid", &f.loop_jackknife_grid, {"loop_covariance_jackknife_grid"});
  r.Read("retrieval_sample", &f.retrieval_sample);
  r.Read("compact_features", &f.compact_features);
  r.Read("match_compact_by_vocabulary", &f.match_compact_by_vocabulary, {"match_by_vocabulary"});
  r.Read("min_retrieval_score_ratio", &f.min_retrieval_score_ratio);
  r.Read("vocabulary", &c.vocabulary);
  r.Read("max_image_queue", &c.max_image_queue);

  r.Read("max_queue", &a.max_queue);
  r.Read("max_views", &a.max_views);
  r.Read("max_edges", &a.max_edges);

  r.Read("load_graph", &c.load_graph);
  r.Read("add_maps", &c.add_maps);
  r.Read("save_on_shutdown", &c.save_on_shutdown);
  r.Read("autosave_path", &c.autosave_path);
  r.Read("autosave_period_s", &c.autosave_period_s, {"autosave_period"});

  std::string problem = r.FirstProblem();
  if (problem.empty()) c.Validate(&problem);
  if (!problem.empty()) {
    if (error) *error = "parameter " + problem;
    return false;
  }

  if (c.vocabulary == "default") c.vocabulary = DefaultVocabularyPath();
  if (!c.image_topics.empty() && f.max_loop_candidates > 0) {
    const std::string linear = ": loop-closure candidates are searched for in every keyframe, a cost that grows with the map";
    if (c.vocabulary.empty() || c.vocabulary == "none") {
      c.vocabulary.clear();
      r.Warn("no vocabulary set" + linear + " (train one with `rotavg vocabulary`, see docs/method.md)");
    } else if (f.features.type != FeatureType::kSift) {
      r.Warn(std::string("the vocabulary describes SIFT, not ") + FeatureTypeName(f.features.type) + linear);
    } else {
      std::string load_error;
      std::shared_ptr<const Vocabulary> vocabulary = Vocabulary::Load(c.vocabulary, &load_error);
      if (vocabulary) f.vocabulary = vocabulary;
      else r.Warn("vocabulary not loaded (" + load_error + ")" + linear);
    }
  }
  return true;
}

KeyframePipeline::KeyframePipeline(const PipelineConfig& config)
    : config_(config),
      averager_(std::make_unique<OnlineAverager>(config.averager)),
      rig_(config.rig),
      selector_(config.selection) {
  config_.frontend.focal_monitor.enabled = config_.focal_calibration != "off";
  config_.frontend.focal_monitor.hold_for_correction = config_.focal_calibration == "apply";
  config_.frontend.focal_monitor.focal.num_threads = config_.frontend.num_threads;
  if (!config_.image_topics.empty()) {
    frontend_ = std::make_unique<KeyframeFrontend>(config_.frontend);
    if (config_.frontend.focal_monitor.enabled) {
      focal_checker_ = std::make_unique<FocalChecker>(config_.frontend.focal_monitor.focal);
    }
  }
}

std::map<std::string, CameraFocalCheck> KeyframePipeline::FocalChecks() const {
  return focal_checker_ ? focal_checker_->Checks() : std::map<std::string, CameraFocalCheck>();
}

std::vector<std::pair<std::string, bool>> KeyframePipeline::TakeFocalNotices() {
  std::vector<std::pair<std::string, bool>> out;
  if (focal_checker_) out = focal_checker_->TakeNotices();
  std::lock_guard<std::mutex> lock(mutex_);
  out.insert(out.end(), correction_notices_.begin(), correction_notices_.end());
  correction_notices_.clear();
  return out;
}

std::map<std::string, double> KeyframePipeline::FocalCorrections() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return focal_corrections_;
}

std::map<std::string, std::string> KeyframePipeline::FocalLoopRefinements() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return focal_loop_refinements_;
}

void KeyframePipeline::HoldBackCorrection(const std::string& camera, const std::string& reason) {
  std::string& said = held_back_[camera];
  if (said == reason) return;
  said = reason;
  std::lock_guard<std::mutex> lock(mutex_);
  correction_notices_.emplace_back(camera + ": focal length not corrected: " + reason, true);
}

namespace {

// A focal check's estimate and its standard deviation, px.
std::pair<double, double> FocalEstimatePx(const CameraFocalCheck& check) {
  return {check.given_focal_px * check.calibration.scale, check.given_focal_px * check.calibration.standard_deviation};
}

}  // namespace

void KeyframePipeline::ApplyFocalCorrections(std::vector<std::string>* warnings) {
  if (!focal_checker_ || config_.focal_calibration != "apply") return;
  const std::map<std::string, CameraFocalCheck> checks = focal_checker_->Checks();
  const std::map<std::string, std::pair<std::string, Eigen::Matrix3d>> rig_cameras = rig_.RigCameras();
  const std::map<std::string, double> corrected = FocalCorrections();
  for (const auto& [camera, check] : checks) {
    if (!check.disagrees || corrections_refused_.count(camera)) continue;
    const auto applied = applied_checks_.find(camera);
    if (applied != applied_checks_.end() && applied->second == std::make_pair(check.given_focal_px, check.pairs_seen)) {
      continue;  // this estimate is decided already
    }
    // The cameras of a rig (extrinsics known) share one orientation per
    // capture: correcting one while another stays as wrong makes their edges
    // disagree, which can cost more than an error they share (it did on the
    // demo rig, whose forward camera cannot be checked). So a rig camera is
    // corrected only when each other camera of its rig is checked as
    // precisely as a correction needs (its deviation within
    // min_correction) and agrees, or disagrees too, or was corrected.
    const auto rig = rig_cameras.find(camera);
    std::string unchecked;
    if (rig != rig_cameras.end()) {
      for (const auto& [other, other_rig] : rig_cameras) {
        if (other == camera || other_rig.first != rig->second.first) continue;
        const auto c = checks.find(other);
        const bool settled = corrected.count(other) > 0 ||
                             (c != checks.end() && c->second.calibration.estimated &&
                              (c->second.disagrees || c->second.calibration.standard_deviation <=
                                                          config_.frontend.focal_monitor.focal.min_correction));
        if (!settled) unchecked += (unchecked.empty() ? "" : ", ") + other;
      }
    }
    if (check.distortion_unmodelled) {
      // A lens the model leaves out bends the focal estimate too: correcting
      // it would fit the focal length to the distortion.
      applied_checks_[camera] = {check.given_focal_px, check.pairs_seen};
      HoldBackCorrection(camera, "its images are distorted and camera_info has no distortion model, which the "
                                 "estimate cannot tell from a focal length error; give the model first");
      continue;
    }
    if (!unchecked.empty()) {
      // Not decided for good: the other cameras' checks may settle while
      // this estimate stands (the estimates of a rig's cameras arrive one
      // after the other), and it is looked at again with every keyframe.
      HoldBackCorrection(camera, "the other cameras of its rig (" + unchecked +
                                     ") are not checked precisely enough, and correcting one camera of a rig alone "
                                     "makes its cameras disagree; fix camera_info");
      continue;
    }
    applied_checks_[camera] = {check.given_focal_px, check.pairs_seen};
    held_back_.erase(camera);
    std::vector<KeyframeRelativeRotation> edges;
    std::string why;
    bool ok = false;
    double correction = 1.0;
    {
      std::lock_guard<std::mutex> lock(frontend_mutex_);
      ok = frontend_->ApplyFocalCorrection(camera, check.calibration.scale, &edges, &why);
      correction = frontend_->FocalCorrection(camera);
      if (ok) focal_checker_->Submit(frontend_->TakeFocalJobs());
    }
    std::ostringstream line;
    line << std::fixed << std::setprecision(4) << camera << ": ";
    if (!ok) {
      corrections_refused_.insert(camera);
      line << "focal length not corrected: " << why;
    } else {
      focal_checker_->ExpectFocal(camera, check.given_focal_px * check.calibration.scale);
      focal_in_use_px_[camera] = check.given_focal_px * check.calibration.scale;
      focal_prior_px_[camera] = FocalEstimatePx(check);
      loops_at_refinement_ = 0;  // the loops look again at the new focal length
      std::size_t replaced = 0;
      for (const KeyframeRelativeRotation& e : edges) {
        std::string error;
        if (AddMeasurement(e, &error)) {
          ++replaced;
        } else if (warnings) {
          warnings->push_back("re-estimated edge dropped: " + error);
        }
      }
      line << "focal length corrected by x" << check.calibration.scale << " (x" << correction
           << " of camera_info's in all): " << replaced << " of its pairs estimated again";
    }
    std::lock_guard<std::mutex> lock(mutex_);
    if (ok) focal_corrections_[camera] = correction;
    correction_notices_.emplace_back(line.str(), true);
  }
}

void KeyframePipeline::RefineFocalByLoops() {
  if (!focal_checker_ || config_.focal_calibration != "apply" || !config_.focal_loop_refinement) return;
  if (focal_in_use_px_.empty()) return;
  std::uint64_t loops = 0;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    loops = frontend_stats_.loop_closure_edges;
  }
  // Each estimate is at most a tenth of the loops behind: the loops that
  // close last (the longest, around the whole trajectory) decide the most.
  if (loops == 0 || loops <= loops_at_refinement_ || 10 * loops < 11 * loops_at_refinement_) return;
  loops_at_refinement_ = loops;
  // The prior: the latest check of the focal length in use, when there is
  // one (a check at the former focal length is dropped by ExpectFocal).
  for (const auto& [camera, check] : focal_checker_->Checks()) {
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
    std::lock_guard<std::mutex> lock(frontend_mutex_);
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
  // Graph edges by (views, source, channel), as the rig model turns a
  // camera pair into one (RigModel::ToVariables).
  std::map<std::tuple<ViewId, ViewId, EdgeSource, std::uint32_t>, std::size_t> edge_of;
  for (std::size_t k = 0; k < graph.NumEdges(); ++k) {
    const RelativeRotation& e = graph.Edges()[k];
    edge_of[{std::min(e.view1, e.view2), std::max(e.view1, e.view2), e.source, e.channel}] = k;
  }
  LoopCalibrationOptions options;
  options.averaging = config_.averager.averaging;
  std::vector<EdgeParameterDerivative> derivatives;
  for (std::size_t p = 0; p < cameras.size(); ++p) {
    const double in_use = focal_in_use_px_.at(cameras[p]);
    const std::pair<double, double>& prior = focal_prior_px_.at(cameras[p]);
    options.prior_center.push_back(prior.first / in_use - 1.0);
    options.prior_sigma.push_back(prior.second / in_use);
    for (const FocalSensitivity& s : sensitivities[p]) {
      KeyframeRelativeRotation m;
      m.keyframe1 = s.keyframe1;
      m.keyframe2 = s.keyframe2;
      m.source = s.source;
      KeyframeRelativeRotation v;
      if (!rig_.ToVariables(m, &v)) continue;  // two cameras of one capture: no edge
      const auto id1 = ids.find(v.keyframe1), id2 = ids.find(v.keyframe2);
      if (id1 == ids.end() || id2 == ids.end()) continue;
      const auto edge = edge_of.find({std::min(id1->second, id2->second), std::max(id1->second, id2->second),
                                      v.source, v.channel});
      if (edge == edge_of.end()) continue;  // not in the graph (rejected, or capped)
      // An edge stored from the other end is the inverse, whose right
      // perturbation is -R_21^T times the variable edge's.
      Eigen::Vector3d d = rig_.PerturbationToVariables(s.keyframe2.frame_id, s.derivative);
      const RelativeRotation& stored = graph.Edges()[edge->second];
      if (stored.view1 != id1->second) d = -(stored.rotation.transpose() * d);
      derivatives.push_back(EdgeParameterDerivative{edge->second, static_cast<int>(p), d});
    }
  }
  const LoopCalibrationResult result = EstimateParametersFromLoops(graph, derivatives, options, start);
  std::vector<std::pair<std::string, bool>> notices;
  if (!result.success) {
    notices.emplace_back("focal lengths not refined by the loops: " + result.message, false);
  }
  std::map<std::string, std::string> latest;  // camera -> its line
  for (std::size_t p = 0; result.success && p < cameras.size(); ++p) {
    const std::string& camera = cameras[p];
    const double e = result.value[p], sigma = result.sigma[p];
    const double center = options.prior_center[p], prior_sigma = options.prior_sigma[p];
    std::ostringstream line;
    line << std::fixed << std::setprecision(5) << camera << ": the loops put its focal length at x" << 1.0 + e
         << " +- " << sigma << " of the one in use (the focal check: x" << 1.0 + center << " +- " << prior_sigma
         << "; " << loops << " loop closures, " << result.solves << " averaging solves): ";
    auto say = [&](const std::string& outcome, bool disagrees) {
      line << outcome;
      notices.emplace_back(line.str(), disagrees);
      latest[camera] = line.str();
    };
    if (!(sigma <= 0.5 * prior_sigma)) {
      say("not refined, the loops know it no better than the check", false);
      continue;
    }
    if (std::abs(e - center) > 3.0 * prior_sigma) {
      // Something else bends the loops (extrinsics, a lens, outliers): the
      // focal length is not the parameter to fit to them.
      say("not refined, they disagree with the check", true);
      continue;
    }
    if (std::abs(e) <= sigma) {
      say("kept, within the loops' deviation", false);
      continue;
    }
    std::vector<KeyframeRelativeRotation> edges;
    std::string why;
    bool ok = false;
    double correction = 1.0;
    {
      std::lock_guard<std::mutex> lock(frontend_mutex_);
      ok = frontend_->ApplyFocalCorrection(camera, 1.0 + e, &edges, &why, /*linearised=*/true);
      correction = frontend_->FocalCorrection(camera);
    }
    if (!ok) {
      say("not refined: " + why, true);
      continue;
    }
    focal_in_use_px_[camera] *= 1.0 + e;
    focal_checker_->ExpectFocal(camera, focal_in_use_px_[camera]);
    std::size_t replaced = 0;
    for (const KeyframeRelativeRotation& edge : edges) {
      if (AddMeasurement(edge, nullptr)) ++replaced;
    }
    std::ostringstream refined;
    refined << std::fixed << "refined (x" << std::setprecision(6) << correction << " of camera_info's in all): " << replaced
            << " of its pairs' edges moved by their derivatives";
    say(refined.str(), false);  // a refinement of a correction already announced
    std::lock_guard<std::mutex> lock(mutex_);
    focal_corrections_[camera] = correction;
  }
  std::lock_guard<std::mutex> lock(mutex_);
  correction_notices_.insert(correction_notices_.end(), notices.begin(), notices.end());
  for (auto& [camera, line] : latest) focal_loop_refinements_[camera] = std::move(line);
}

void KeyframePipeline::WaitForFocalChecks() {
  if (focal_checker_) focal_checker_->Wait();
}

KeyframePipeline::~KeyframePipeline() = default;

bool KeyframePipeline::Reject(std::uint64_t* counter, const std::string& why, std::string* error) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    ++*counter;
  }
  if (error) *error = why;
  return false;
}

// Into the averager through the rig model (one variable per rig capture).
bool KeyframePipeline::AddMeasurement(const KeyframeRelativeRotation& m, std::string* error, bool* queue_full) {
  if (queue_full) *queue_full = false;
  // Self-references are errors even when both ends are rig cameras.
  if (m.keyframe1.frame_id == m.keyframe2.frame_id && m.keyframe1.stamp_ns == m.keyframe2.stamp_ns) {
    if (error) *error = "a keyframe related to itself";
    return false;
  }
  KeyframeRelativeRotation v;
  if (!m.rotation.allFinite()) return averager_->AddRelativeRotation(m, error, queue_full);  // rejected there
  if (!rig_.ToVariables(m, &v)) {
    std::lock_guard<std::mutex> lock(mutex_);
    ++stats_.absorbed_by_rig;
    return true;
  }
  return averager_->AddRelativeRotation(v, error, queue_full);
}

bool KeyframePipeline::AcceptRelativePose(const RelativePose& msg, std::string* error) {
  KeyframeRelativeRotation m;
  std::string why;
  bool queue_full = false;
  if (FromMsg(msg, &m, &why) && AddMeasurement(m, &why, &queue_full)) return true;
  if (queue_full) {  // valid, dropped under load: counted by the averager (dropped_queue_full)
    if (error) *error = why;
    return false;
  }
  return Reject(&stats_.rejected_messages, why, error);
}

void KeyframePipeline::AcceptStaticTransforms(const tf2_msgs::TFMessage& msg) {
  for (const geometry_msgs::TransformStamped& t : msg.transforms) {
    if (t.header.frame_id == config_.fixed_frame) continue;  // our own keyframe frames
    const auto& q = t.transform.rotation;
    const double norm = std::sqrt(q.w * q.w + q.x * q.x + q.y * q.y + q.z * q.z);
    if (!std::isfinite(norm) || std::abs(norm - 1.0) > 1e-3) continue;
    rig_.AddStaticTransform(t.header.frame_id, t.child_frame_id, QuaternionToRotation(q.w, q.x, q.y, q.z));
  }
}

bool IsRectifiedTopic(const std::string& topic, const std::string& image_type) {
  if (image_type == "raw") return false;
  if (image_type == "rectified") return true;
  const std::size_t slash = topic.find_last_of('/');
  const std::string name = slash == std::string::npos ? topic : topic.substr(slash + 1);
  return name.rfind("image_rect", 0) == 0;
}

namespace {

// The sensor readout of REP 104: which full-resolution pixels the image
// holds (roi, all zero for the whole sensor) and how many of them each of
// its pixels combines (binning, 0 meaning 1). K's convention puts a pixel's
// centre at its integer coordinate, so the binned pixel u' averages the
// full-resolution pixels x_offset + b u' ... x_offset + b u' + b - 1 and
// lies at their centre, u = x_offset + b u' + (b - 1) / 2. image_geometry's
// PinholeCameraModel leaves out the (b - 1) / 2, which puts a 2 x 2 binned
// image's keypoints a quarter of its pixel off K (docs/decisions.md, "A
// binned pixel at the centre of its block": five times the median error on
// the binned demo).
struct Readout {
  unsigned binning_x = 1, binning_y = 1;
  unsigned x_offset = 0, y_offset = 0;
  unsigned width = 0, height = 0;  // of the region, full-resolution pixels; 0: unknown
  bool windowed = false;           // a region of interest or binning other than 1
};

// REP 104: a roi of all zeros is the whole sensor.
bool HasRegionOfInterest(const sensor_msgs::RegionOfInterest& roi) {
  return roi.x_offset != 0 || roi.y_offset != 0 || roi.width != 0 || roi.height != 0;
}

bool ReadoutFromInfo(const sensor_msgs::CameraInfo& info, Readout* readout, std::string* error) {
  // Far beyond any sensor's binning: a value this large is a corrupt message.
  constexpr unsigned kMaxBinning = 64;
  Readout r;
  r.binning_x = std::max(1u, info.binning_x);
  r.binning_y = std::max(1u, info.binning_y);
  if (r.binning_x > kMaxBinning || r.binning_y > kMaxBinning) {
    *error = "binning " + std::to_string(info.binning_x) + " x " + std::to_string(info.binning_y) + " (at most " +
             std::to_string(kMaxBinning) + ")";
    return false;
  }
  const sensor_msgs::RegionOfInterest& roi = info.roi;
  const bool has_roi = HasRegionOfInterest(roi);
  if (has_roi) {
    if (roi.width == 0 || roi.height == 0) {
      *error = "region of interest at (" + std::to_string(roi.x_offset) + ", " + std::to_string(roi.y_offset) +
               ") has no size";
      return false;
    }
    // In 64 bits: offset + width of two 32-bit fields may wrap around.
    const auto beyond = [](std::uint64_t offset, std::uint64_t extent, std::uint64_t limit) {
      return limit > 0 && offset + extent > limit;
    };
    if (beyond(roi.x_offset, roi.width, info.width) || beyond(roi.y_offset, roi.height, info.height)) {
      *error = "region of interest " + std::to_string(roi.width) + " x " + std::to_string(roi.height) + " at (" +
               std::to_string(roi.x_offset) + ", " + std::to_string(roi.y_offset) + ") does not lie on the " +
               std::to_string(info.width) + " x " + std::to_string(info.height) + " sensor";
      return false;
    }
    r.x_offset = roi.x_offset;
    r.y_offset = roi.y_offset;
    r.width = roi.width;
    r.height = roi.height;
  } else {
    r.width = info.width;
    r.height = info.height;
  }
  if (r.width > 0 && (r.width < r.binning_x || r.height < r.binning_y)) {
    *error = "binning " + std::to_string(r.binning_x) + " x " + std::to_string(r.binning_y) + " leaves no pixel of " +
             std::to_string(r.width) + " x " + std::to_string(r.height);
    return false;
  }
  r.windowed = has_roi || r.binning_x > 1 || r.binning_y > 1;
  *readout = r;
  return true;
}

// K (or P's left 3x3) of the full sensor as the camera of the readout's image.
Eigen::Matrix3d ReadoutIntrinsics(const Eigen::Matrix3d& full, const Readout& r) {
  if (!r.windowed) return full;
  Eigen::Matrix3d to_image = Eigen::Matrix3d::Identity();
  to_image(0, 0) = 1.0 / r.binning_x;
  to_image(1, 1) = 1.0 / r.binning_y;
  to_image(0, 2) = -(r.x_offset + 0.5 * (r.binning_x - 1.0)) / r.binning_x;
  to_image(1, 2) = -(r.y_offset + 0.5 * (r.binning_y - 1.0)) / r.binning_y;
  return to_image * full;
}

}  // namespace

bool CameraFromInfo(const sensor_msgs::CameraInfo& info, bool rectified, CameraIntrinsics* camera,
                    std::string* error, cv::Size* image_size) {
  *camera = CameraIntrinsics();
  Readout readout;
  if (!ReadoutFromInfo(info, &readout, error)) return false;
  if (image_size) {
    *image_size = readout.width > 0 ? cv::Size(static_cast<int>(readout.width / readout.binning_x),
                                               static_cast<int>(readout.height / readout.binning_y))
                                    : cv::Size(0, 0);
  }
  if (rectified) {
    // image_proc's rectified image is seen by the camera P describes; a
    // camera_info without P (all zero) falls back to K.
    const bool has_p = info.P[0] != 0.0 || info.P[5] != 0.0;
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) camera->k(r, c) = has_p ? info.P[4 * r + c] : info.K[3 * r + c];
    if (!IsCameraIntrinsics(camera->k)) {
      *error = std::string("no valid ") + (has_p ? "P" : "K") + " for a rectified image (" + kCameraIntrinsicsRule + ")";
      return false;
    }
    camera->k = ReadoutIntrinsics(camera->k, readout);
    return true;
  }
  for (int i = 0; i < 9; ++i) camera->k(i / 3, i % 3) = info.K[i];
  if (!ParseDistortionModel(info.distortion_model, &camera->distortion)) {
    *error = "unknown distortion_model '" + info.distortion_model +
             "' (plumb_bob, rational_polynomial, equidistant; none or empty with D all zero)";
    return false;
  }
  camera->coefficients = info.D;
  std::string why;
  if (!IsCameraIntrinsics(camera->k)) {
    *error = std::string("no valid K (") + kCameraIntrinsicsRule + ")";
    return false;
  }
  camera->k = ReadoutIntrinsics(camera->k, readout);
  if (!camera->Validate(&why)) {
    *error = "D does not fit distortion_model '" + info.distortion_model + "': " + why;
    return false;
  }
  return true;
}

namespace {
std::string DescribeCamera(const std::string& frame, const CameraIntrinsics& camera, bool rectified,
                           const sensor_msgs::CameraInfo& info) {
  std::ostringstream out;
  out << frame << ": f " << camera.k(0, 0) << ", " << camera.k(1, 1) << " px, ";
  const sensor_msgs::RegionOfInterest& roi = info.roi;
  if (HasRegionOfInterest(roi)) {
    out << "region " << roi.width << " x " << roi.height << " at (" << roi.x_offset << ", " << roi.y_offset
        << ") of the sensor, ";
  }
  if (info.binning_x > 1 || info.binning_y > 1) {
    out << "binned " << std::max(1u, info.binning_x) << " x " << std::max(1u, info.binning_y) << ", ";
  }
  if (camera.HasDistortion()) {
    out << "keypoints undistorted by " << DistortionModelName(camera.distortion) << " (";
    for (std::size_t i = 0; i < camera.coefficients.size(); ++i) out << (i ? " " : "") << camera.coefficients[i];
    out << ")";
  } else {
    out << (rectified ? "rectified image (camera_info's P)" : "no distortion in camera_info");
  }
  return out.str();
}
}  // namespace

std::vector<std::string> KeyframePipeline::TakeCameraModelNotices() {
  std::lock_guard<std::mutex> lock(mutex_);
  std::vector<std::string> notices;
  notices.swap(camera_model_notices_);
  return notices;
}

bool KeyframePipeline::Validate(const std::string& frame, const ros::Time& stamp, const cv::Mat& grey,
                                const sensor_msgs::CameraInfo& info, bool rectified, PendingKeyframe* out,
                                std::string* error) {
  if (frame.empty()) return Reject(&stats_.rejected_images, "image with an empty frame_id", error);
  if (grey.empty()) return Reject(&stats_.rejected_images, "empty image from " + frame, error);
  CameraIntrinsics camera;
  std::string why;
  cv::Size size;
  // Refused here, once per image with its camera's name, rather than by the
  // two-view estimation of every pair the keyframe would be tried in.
  if (!CameraFromInfo(info, rectified, &camera, &why, &size)) {
    return Reject(&stats_.rejected_images, "camera_info of " + frame + ": " + why, error);
  }
  if (size.width > 0 && (size.width != grey.cols || size.height != grey.rows)) {
    std::string expected = std::to_string(size.width) + " x " + std::to_string(size.height);
    if (size.width != static_cast<int>(info.width) || size.height != static_cast<int>(info.height)) {
      expected += " (camera_info's " + std::to_string(info.width) + " x " + std::to_string(info.height) +
                  " sensor through its roi and binning)";
    }
    return Reject(&stats_.rejected_images,
                  "image of " + frame + " is " + std::to_string(grey.cols) + " x " + std::to_string(grey.rows) +
                      ", its camera_info says " + expected,
                  error);
  }
  if (!IsNormalizedStamp(stamp)) {
    return Reject(&stats_.rejected_images, "image of " + frame + " has a stamp with nsec >= 1e9 (not normalised)", error);
  }
  const std::int64_t ns = ToNanoseconds(stamp);
  {
    std::lock_guard<std::mutex> lock(mutex_);
    auto last = last_image_stamp_.find(frame);
    if (last != last_image_stamp_.end() && ns <= last->second) {
      ++stats_.rejected_images;
      if (error) *error = "stamp of " + frame + " did not advance (" + std::to_string(stamp.toSec()) + ")";
      return false;
    }
    last_image_stamp_[frame] = ns;
  }
  out->key = KeyframeKey{frame, ns};
  out->image = grey;
  out->camera = camera;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    std::string description = DescribeCamera(frame, camera, rectified, info);
    std::string& known = camera_models_[frame];
    if (known != description) {
      known = description;
      camera_model_notices_.push_back(std::move(description));
    }
  }
  return true;
}

bool KeyframePipeline::DecodeImage(const sensor_msgs::Image& image, const sensor_msgs::CameraInfo& info,
                                   PendingKeyframe* out, std::string* error, bool rectified) {
  // cv_bridge compares height * step with the data's size, and step with
  // width * bytes per pixel, in 32 bits: a product that wraps around passes,
  // and the copy then reads gigabytes past the data. Checked in 64 bits first.
  // (The description is built only for a rejection, not for every image.)
  auto from = [&image] {
    return "image from " + image.header.frame_id + " (" + image.encoding + ", " + std::to_string(image.width) + "x" +
           std::to_string(image.height) + ", step " + std::to_string(image.step) + ", " +
           std::to_string(image.data.size()) + " bytes)";
  };
  std::uint64_t pixel_bytes = 0;
  try {
    pixel_bytes = static_cast<std::uint64_t>(sensor_msgs::image_encodings::bitDepth(image.encoding) / 8) *
                  sensor_msgs::image_encodings::numChannels(image.encoding);
  } catch (const std::exception&) {
    return Reject(&stats_.rejected_images, from() + " has an unknown encoding", error);
  }
  if (image.width == 0 || image.height == 0 || std::uint64_t{image.width} * image.height > kMaxKeyframePixels ||
      std::uint64_t{image.step} < std::uint64_t{image.width} * pixel_bytes ||
      std::uint64_t{image.height} * image.step != image.data.size()) {
    return Reject(&stats_.rejected_images, from() + " is malformed: its size, step and data do not agree", error);
  }
  cv::Mat grey;
  try {
    // toCvCopy: the keyframe outlives the message.
    grey = cv_bridge::toCvCopy(image, sensor_msgs::image_encodings::MONO8)->image;
  } catch (const std::exception& e) {
    return Reject(&stats_.rejected_images,
                  "image from " + image.header.frame_id + " does not decode (" + image.encoding + "): " + e.what(),
                  error);
  }
  return Validate(image.header.frame_id, image.header.stamp, grey, info, rectified, out, error);
}

bool KeyframePipeline::DecodeCompressedImage(const sensor_msgs::CompressedImage& image,
                                             const sensor_msgs::CameraInfo& info, PendingKeyframe* out,
                                             std::string* error, bool rectified) {
  auto from = [&image] { return "compressed image from " + image.header.frame_id + " (" + image.format + ")"; };
  std::uint32_t width = 0, height = 0;
  const std::string format = CompressedImageSize(image.data, &width, &height);
  if (format.empty()) {
    return Reject(&stats_.rejected_images, from() + " is neither PNG nor JPEG, or its header is cut short", error);
  }
  // The size camera_info gives the image (its sensor through roi and
  // binning), or its transpose (an EXIF orientation that the decoder
  // applies; Validate then compares the decoded image).
  CameraIntrinsics camera;
  std::string why;
  cv::Size size;
  if (!CameraFromInfo(info, rectified, &camera, &why, &size)) {
    return Reject(&stats_.rejected_images, "camera_info of " + image.header.frame_id + ": " + why, error);
  }
  const std::uint32_t w = static_cast<std::uint32_t>(size.width), h = static_cast<std::uint32_t>(size.height);
  const bool sized = w > 0 && h > 0;
  const bool as_info = (width == w && height == h) || (width == h && height == w);
  const bool plausible = width > 0 && height > 0 && std::uint64_t{width} * height <= kMaxKeyframePixels;
  if (!plausible || (sized && !as_info)) {
    return Reject(&stats_.rejected_images,
                  from() + ": its " + format + " header declares " + std::to_string(width) + "x" +
                      std::to_string(height) + " pixels, " +
                      (plausible ? "not camera_info's " + std::to_string(w) + "x" + std::to_string(h)
                                 : "an empty or implausibly large image"),
                  error);
  }
  cv::Mat grey;
  try {
    grey = cv::imdecode(image.data, cv::IMREAD_GRAYSCALE);
  } catch (const cv::Exception&) {
    grey.release();
  }
  if (grey.empty()) {
    return Reject(&stats_.rejected_images,
                  from() + " does not decode", error);
  }
  return Validate(image.header.frame_id, image.header.stamp, grey, info, rectified, out, error);
}

std::vector<PendingKeyframe> KeyframePipeline::SelectKeyframes(const PendingKeyframe& image) {
  if (config_.keyframe_selection == "all") {
    std::lock_guard<std::mutex> lock(mutex_);
    ++stats_.frames;
    return {image};
  }
  std::vector<SelectorFrame> selected;
  KeyframeSelectionStats selection;
  {
    std::lock_guard<std::mutex> lock(selector_mutex_);
    selected = selector_.Offer(SelectorFrame{image.key.frame_id, image.key.stamp_ns, image.image, image.camera});
    selection = selector_.Stats();
  }
  std::vector<PendingKeyframe> keyframes;
  for (SelectorFrame& f : selected) {
    PendingKeyframe k;
    k.key = KeyframeKey{f.camera, f.stamp_ns};
    k.image = f.image;
    k.camera = f.intrinsics;
    keyframes.push_back(std::move(k));
  }
  std::lock_guard<std::mutex> lock(mutex_);
  ++stats_.frames;
  stats_.frames_skipped = selection.skipped;
  stats_.selection_s = selection.tracking_s;
  return keyframes;
}

void KeyframePipeline::ResetKeyframeSelection() {
  std::lock_guard<std::mutex> lock(selector_mutex_);
  selector_.Reset();
}

std::size_t KeyframePipeline::ProcessKeyframe(const PendingKeyframe& keyframe, bool* loop_closure,
                                              std::vector<std::string>* warnings) {
  if (loop_closure) *loop_closure = false;
  if (!frontend_) return 0;
  if (rig_.IsRigCamera(keyframe.key.frame_id)) frontend_->SetRigCalibrated(keyframe.key.frame_id);
  ApplyFocalCorrections(warnings);
  RefineFocalByLoops();
  std::size_t added = 0;
  std::vector<KeyframeRelativeRotation> edges;
  KeyframeFrontendStats frontend_stats;
  {
    std::lock_guard<std::mutex> lock(frontend_mutex_);
    edges = frontend_->AddKeyframe(keyframe.key, keyframe.image, keyframe.camera);
    frontend_stats = frontend_->Stats();
    if (focal_checker_) focal_checker_->Submit(frontend_->TakeFocalJobs());
  }
  for (const KeyframeRelativeRotation& e : edges) {
    std::string error;
    if (AddMeasurement(e, &error)) {
      ++added;
      if (loop_closure && e.source == EdgeSource::kLoopClosure) *loop_closure = true;
    } else if (warnings) {
      warnings->push_back("front-end edge dropped: " + error);
    }
  }
  std::lock_guard<std::mutex> lock(mutex_);
  ++stats_.processed_images;
  stats_.edges_from_images += added;
  frontend_stats_ = std::move(frontend_stats);
  return added;
}

std::string KeyframeDatabasePath(const std::string& graph_path) { return graph_path + ".keyframes"; }
std::string RigPath(const std::string& graph_path) { return graph_path + ".rig"; }

bool KeyframePipeline::SaveMap(const std::string& graph_path, std::string* error, std::string* note) {
  using Clock = std::chrono::steady_clock;
  auto seconds_since = [](Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); };
  std::lock_guard<std::mutex> save_lock(save_mutex_);
  MapSaveTiming timing;
  const auto start = Clock::now();
  // Each part is copied while its lock is held and written after: a solve or
  // a keyframe waits for the copy, not for the disk.
  ViewGraph graph;
  std::map<ViewId, Eigen::Matrix3d> orientations;
  averager_->SnapshotGraph(&graph, &orientations);
  timing.graph_lock_s = seconds_since(start);
  // The graph first, the database last: a save cut short between them leaves
  // a database older than the graph.
  if (!WriteRotavgGraph(graph_path, graph, error, &orientations)) return false;
  if (!rig_.Save(RigPath(graph_path), error)) return false;
  std::string saved = "view graph saved to " + graph_path;
  const std::string database_path = KeyframeDatabasePath(graph_path);
  if (frontend_ && frontend_->UsesVocabulary()) {
    KeyframeDatabase database;
    const auto frontend_start = Clock::now();
    {
      std::lock_guard<std::mutex> lock(frontend_mutex_);
      if (!frontend_->SnapshotDatabase(&database, error)) return false;
    }
    timing.frontend_lock_s = seconds_since(frontend_start);
    if (!WriteKeyframeDatabase(database_path, database, error)) return false;
    saved += ", " + std::to_string(database.keyframes.size()) + " keyframes to " + database_path;
  } else {
    // A database left from an earlier save to this path belongs to another
    // graph: loading it with this one would relate new keyframes to views
    // the graph does not have.
    std::error_code ec;
    if (std::filesystem::remove(database_path, ec)) saved += "; the older " + database_path + " removed";
    if (frontend_) saved += "; no keyframe database (retrieval by voting: vocabulary none)";
  }
  timing.total_s = seconds_since(start);
  {
    std::lock_guard<std::mutex> lock(mutex_);
    last_save_timing_ = timing;
  }
  if (note) *note = saved;
  return true;
}

MapSaveTiming KeyframePipeline::LastSaveTiming() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return last_save_timing_;
}

bool KeyframePipeline::CheckMap(const std::string& graph_path, SavedKeyframeGraph* graph, bool* have_rig,
                                RigModel::Saved* rig, std::string* error) const {
  if (!ReadSavedKeyframeGraph(graph_path, graph, error)) return false;
  // The rig's captures: without them a saved capture would stay one
  // orientation of the rig frame, and the cameras' keyframes in it unknown.
  std::error_code ec;
  *have_rig = std::filesystem::exists(RigPath(graph_path), ec);
  return !*have_rig || RigModel::ReadFile(RigPath(graph_path), rig, error);
}

bool KeyframePipeline::LoadMap(const std::string& graph_path, std::string* error, std::string* note,
                               std::map<KeyframeKey, Eigen::Matrix3d>* saved_orientations) {
  // The graph is read and the rig file checked before the database replaces
  // the front end's keyframes: a refused map leaves everything as it was.
  SavedKeyframeGraph graph;
  bool have_rig = false;
  RigModel::Saved saved_rig;
  if (!CheckMap(graph_path, &graph, &have_rig, &saved_rig, error)) return false;
  std::string loaded = "view graph of " + std::to_string(graph.graph.NumViews()) + " views loaded from " + graph_path;
  const std::string rig = RigPath(graph_path);
  std::error_code ec;
  const std::string database = KeyframeDatabasePath(graph_path);
  if (frontend_) {
    if (!std::filesystem::exists(database, ec)) {
      loaded += "; no keyframe database beside it: new keyframes cannot relate to the old ones";
    } else if (!frontend_->UsesVocabulary()) {
      loaded += "; its keyframe database is not loaded (it needs a vocabulary, and vocabulary is none):"
                " new keyframes cannot relate to the old ones";
    } else {
      std::lock_guard<std::mutex> lock(frontend_mutex_);
      if (!frontend_->LoadDatabase(database, error)) return false;
      loaded += ", " + std::to_string(frontend_->NumKeyframes()) + " keyframes from " + database;
      std::lock_guard<std::mutex> stats_lock(mutex_);
      frontend_stats_ = frontend_->Stats();
    }
  }
  std::string graph_note;
  if (!averager_->LoadGraph(graph, &graph_note)) {
    if (error) *error = graph_note;
    return false;
  }
  if (!graph_note.empty()) loaded += " (" + graph_note + ")";
  if (saved_orientations) {
    saved_orientations->clear();
    for (const auto& [id, r] : graph.orientations) saved_orientations->emplace(graph.keys.at(id), r);
  }
  if (have_rig) {
    rig_.Replace(std::move(saved_rig));
    loaded += ", " + std::to_string(rig_.NumCaptures()) + " rig captures from " + rig;
  }
  if (note) *note = loaded;
  return true;
}

bool KeyframePipeline::AddMap(const std::string& graph_path, std::string* error, std::string* note) {
  // The files are checked before anything is added (the database as it is
  // added): a refused map leaves what is held as it was.
  SavedKeyframeGraph graph;
  bool have_rig = false;
  RigModel::Saved saved_rig;
  if (!CheckMap(graph_path, &graph, &have_rig, &saved_rig, error)) return false;
  std::error_code ec;
  std::string added_note = "map " + graph_path + " added:";
  const std::string database = KeyframeDatabasePath(graph_path);
  // Loop closures between its keyframes and those held, found as it is added
  // (a map that shares none of them); they go to the averager after its
  // graph and rig captures, which they refer to.
  std::vector<KeyframeRelativeRotation> links;
  std::size_t already_held = 0;
  const bool with_database = frontend_ && frontend_->UsesVocabulary() && std::filesystem::exists(database, ec);
  if (with_database) {
    std::lock_guard<std::mutex> lock(frontend_mutex_);
    const std::size_t before = frontend_->NumKeyframes();
    if (!frontend_->AddDatabase(database, &already_held, error, &links)) return false;
    added_note += " " + std::to_string(frontend_->NumKeyframes() - before) + " keyframes to retrieve from (" +
                  std::to_string(already_held) + " already held),";
    std::lock_guard<std::mutex> stats_lock(mutex_);
    frontend_stats_ = frontend_->Stats();
  } else if (frontend_) {
    added_note += " no keyframe database (" +
                  std::string(frontend_->UsesVocabulary() ? "none beside it" : "vocabulary none") +
                  "): new keyframes cannot relate to its keyframes,";
  }
  OnlineAverager::AddedGraph added;
  std::string graph_note;
  if (!averager_->AddGraph(graph, &added, &graph_note)) {
    if (error) *error = graph_note;
    return false;
  }
  added_note += " " + std::to_string(added.views) + " views and " + std::to_string(added.edges) + " edges (" +
                std::to_string(added.views_held) + " views and " + std::to_string(added.edges_held) +
                " edges already held)";
  if (!graph_note.empty()) added_note += " (" + graph_note + ")";
  if (have_rig) {
    const std::size_t before = rig_.NumCaptures();
    rig_.Merge(std::move(saved_rig));
    added_note += ", " + std::to_string(rig_.NumCaptures() - before) + " rig captures";
  }
  if (with_database) {
    std::size_t linked = 0;
    for (const KeyframeRelativeRotation& e : links) {
      std::string why;
      if (AddMeasurement(e, &why)) ++linked;
    }
    {
      std::lock_guard<std::mutex> lock(mutex_);
      stats_.edges_from_images += linked;
    }
    added_note += already_held > 0 ? "; joined through the keyframes it shares"
                                   : "; " + std::to_string(linked) + " loop closures to the keyframes held";
    averager_->RequestSolve();
  }
  if (note) *note = added_note;
  return true;
}

KeyframeFrontendStats KeyframePipeline::FrontendStats() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return frontend_stats_;
}

CameraInfoCheckArray KeyframePipeline::CameraInfoCheckMsg(const ros::Time& stamp) const {
  CameraInfoCheckArray msg;
  msg.header.stamp = stamp;
  const std::map<std::string, double> corrections = FocalCorrections();
  for (const auto& [camera, check] : FocalChecks()) {
    CameraInfoCheck m;
    m.frame_id = camera;
    m.pairs_seen = static_cast<std::uint32_t>(check.pairs_seen);
    m.pairs_used = static_cast<std::uint32_t>(check.calibration.pairs);
    m.estimated = check.calibration.estimated;
    m.given_focal_px = check.given_focal_px;
    m.scale = check.calibration.scale;
    m.scale_stddev = check.calibration.standard_deviation;
    m.disagrees = check.disagrees;
    const auto correction = corrections.find(camera);
    m.applied_scale = correction == corrections.end() ? 1.0 : correction->second;
    m.distortion_checked = check.distortion_checked && check.distortion.estimated;
    m.distortion_lambda = check.distortion.lambda;
    m.distortion_lambda_stddev = check.distortion.standard_deviation;
    m.distortion_corner_px = check.distortion.corner_shift_px;
    m.distortion_unmodelled = check.distortion_unmodelled;
    msg.cameras.push_back(m);
  }
  return msg;
}

Orientations KeyframePipeline::OrientationsMsg(const OnlineSolution& solution, const ros::Time& stamp) const {
  Orientations msg;
  msg.header.stamp = stamp;
  msg.header.frame_id = config_.fixed_frame;
  msg.solve_sequence = solution.sequence;
  msg.keyframes.reserve(solution.orientations.size());
  for (const auto& [key, r] : solution.orientations) {
    auto c = solution.component.find(key);
    auto cov = solution.covariance.find(key);
    msg.keyframes.push_back(ToMsg(key, r, c == solution.component.end() ? 0 : c->second,
                                  cov == solution.covariance.end() ? nullptr : &cov->second));
  }
  return msg;
}

geometry_msgs::TransformStamped KeyframePipeline::Transform(const ros::Time& stamp, const std::string& child,
                                                            const geometry_msgs::Quaternion& camera_to_world) const {
  geometry_msgs::TransformStamped t;
  t.header.stamp = stamp;
  t.header.frame_id = config_.fixed_frame;
  t.child_frame_id = child;
  t.transform.rotation = camera_to_world;
  return t;
}

tf2_msgs::TFMessage KeyframePipeline::KeyframeTransforms(const OnlineSolution& solution) const {
  tf2_msgs::TFMessage msg;
  msg.transforms.reserve(solution.orientations.size());
  for (const auto& [key, r] : solution.orientations) {
    msg.transforms.push_back(Transform(FromNanoseconds(key.stamp_ns),
                                       KeyframeFrameName(config_.keyframe_frame_format, key),
                                       ToMsg(key, r, 0).orientation));
  }
  return msg;
}

visualization_msgs::MarkerArray KeyframePipeline::Markers(const OnlineSolution& variables, const OnlineSolution& cameras,
                                                          const ros::Time& stamp) const {
  // Lanes: one per solved frame id (a camera, or a rig frame), keyframes in
  // time order along x.
  std::vector<KeyframeKey> drawn;
  for (const auto& [key, r] : variables.orientations) drawn.push_back(key);
  std::sort(drawn.begin(), drawn.end(),
            [](const KeyframeKey& a, const KeyframeKey& b) { return a.stamp_ns < b.stamp_ns || (a.stamp_ns == b.stamp_ns && a < b); });
  if (drawn.size() > static_cast<std::size_t>(config_.marker_max_keyframes)) {
    drawn.erase(drawn.begin(), drawn.end() - config_.marker_max_keyframes);
  }
  std::map<std::string, int> lane;
  std::map<std::string, int> next_in_lane;
  std::map<KeyframeKey, Eigen::Vector3d> position;
  for (const KeyframeKey& key : drawn) {
    const int l = lane.emplace(key.frame_id, static_cast<int>(lane.size())).first->second;
    const int i = next_in_lane[key.frame_id]++;
    position[key] = Eigen::Vector3d(i * config_.marker_spacing_m, -2.0 * l * config_.marker_spacing_m, 0.0);
  }
  auto point = [](const Eigen::Vector3d& p) {
    geometry_msgs::Point m;
    m.x = p.x();
    m.y = p.y();
    m.z = p.z();
    return m;
  };
  auto base = [&](const std::string& ns, double width) {
    visualization_msgs::Marker m;
    m.header.frame_id = config_.fixed_frame;
    m.header.stamp = stamp;
    m.ns = ns;
    m.id = 0;
    m.type = visualization_msgs::Marker::LINE_LIST;
    m.action = visualization_msgs::Marker::ADD;
    m.pose.orientation.w = 1.0;
    m.scale.x = width;
    m.color.a = 1.0;
    return m;
  };
  // Frusta of every camera keyframe, at the position of the variable it
  // belongs to (the cameras of one rig capture share it).
  visualization_msgs::Marker frusta = base("keyframes", 0.01 * config_.marker_spacing_m);
  frusta.color.r = 0.2;
  frusta.color.g = 0.4;
  frusta.color.b = 1.0;
  const double size = 0.35 * config_.marker_spacing_m;
  const Eigen::Vector3d corners[4] = {{-0.6, -0.45, 1.0}, {0.6, -0.45, 1.0}, {0.6, 0.45, 1.0}, {-0.6, 0.45, 1.0}};
  for (const auto& [key, r] : cameras.orientations) {
    auto at = position.find(rig_.VariableOfKnown(key));
    if (at == position.end()) continue;
    const Eigen::Vector3d apex = at->second;
    Eigen::Vector3d c[4];
    for (int k = 0; k < 4; ++k) c[k] = apex + size * (r.transpose() * corners[k]);  // camera-to-world
    for (int k = 0; k < 4; ++k) {
      frusta.points.push_back(point(apex));
      frusta.points.push_back(point(c[k]));
      frusta.points.push_back(point(c[k]));
      frusta.points.push_back(point(c[(k + 1) % 4]));
    }
  }
  visualization_msgs::Marker edges = base("edges", 0.005 * config_.marker_spacing_m);
  for (const SolvedEdge& e : variables.edges) {
    auto a = position.find(e.keyframe1), b = position.find(e.keyframe2);
    if (a == position.end() || b == position.end()) continue;
    std_msgs::ColorRGBA colour;
    colour.r = static_cast<float>(1.0 - std::clamp(e.robust_weight, 0.0, 1.0));
    colour.g = static_cast<float>(std::clamp(e.robust_weight, 0.0, 1.0));
    colour.b = 0.0f;
    colour.a = 1.0f;
    edges.points.push_back(point(a->second));
    edges.points.push_back(point(b->second));
    edges.colors.push_back(colour);
    edges.colors.push_back(colour);
  }
  visualization_msgs::MarkerArray out;
  out.markers.push_back(frusta);
  out.markers.push_back(edges);
  return out;
}

std::vector<geometry_msgs::TransformStamped> KeyframePipeline::LatestTransforms(const OnlineSolution& solution,
                                                                                 const ros::Time& now) {
  std::map<std::string, std::pair<KeyframeKey, Eigen::Matrix3d>> latest;
  for (const auto& [key, r] : solution.orientations) {
    auto it = latest.find(key.frame_id);
    if (it == latest.end() || it->second.first.stamp_ns < key.stamp_ns) latest[key.frame_id] = {key, r};
  }
  std::vector<geometry_msgs::TransformStamped> tfs;
  std::lock_guard<std::mutex> lock(mutex_);
  for (const auto& [frame_id, kr] : latest) {
    const std::string child = KeyframeFrameName(config_.latest_frame_format, kr.first);
    auto last = last_latest_stamp_.find(child);
    if (last != last_latest_stamp_.end() && now <= last->second) continue;
    last_latest_stamp_[child] = now;
    tfs.push_back(Transform(now, child, ToMsg(kr.first, kr.second, 0).orientation));
  }
  return tfs;
}

void KeyframePipeline::ForgetLatestStamps() {
  std::lock_guard<std::mutex> lock(mutex_);
  last_latest_stamp_.clear();
}

PipelineStats KeyframePipeline::Stats() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return stats_;
}

}  // namespace rotation_averaging
