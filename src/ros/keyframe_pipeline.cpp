#include "rotation_averaging/ros/keyframe_pipeline.h"

#include <chrono>
#include <cmath>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/ros/msg_conversion.h"
#include "rotation_averaging/util/blas_threads.h"
#include "rotation_averaging/util/time_distribution.h"

namespace rotation_averaging {
namespace {

using Clock = std::chrono::steady_clock;

}  // namespace

KeyframePipeline::KeyframePipeline(const PipelineConfig& config)
    : config_(config),
      averager_(std::make_unique<OnlineAverager>(config.averager)),
      output_(config),
      rig_(config.rig),
      selector_(config.selection) {
  // Before the first image: OpenCV's LAPACK and the refinement's solves.
  HoldOpenBlasToOneThread();
  config_.frontend.focal_monitor.enabled = config_.focal_calibration != FocalCalibrationMode::kOff;
  config_.frontend.focal_monitor.hold_for_correction = config_.focal_calibration == FocalCalibrationMode::kApply;
  config_.frontend.focal_monitor.focal.num_threads = config_.frontend.num_threads;
  auto add_edge = [this](const KeyframeRelativeRotation& m, std::string* error) { return AddMeasurement(m, error); };
  if (!config_.image_topics.empty()) {
    config_.frontend.keep_correspondences = config_.refinement;
    if (config_.refinement) {
      KeyframeRefinerOptions refiner = config_.refiner;
      refiner.focal_min_correction = config_.frontend.focal_monitor.focal.min_correction;  // as the corrector judges
      refiner_ = std::make_unique<KeyframeRefiner>(refiner);
    }
    frontend_ = std::make_unique<KeyframeFrontend>(config_.frontend);
    if (config_.frontend.focal_monitor.enabled) {
      focal_checker_ = std::make_unique<FocalChecker>(config_.frontend.focal_monitor.focal);
    }
    if (focal_checker_ && config_.focal_calibration == FocalCalibrationMode::kApply) {
      FocalCorrectorOptions options;
      options.loop_refinement = config_.focal_loop_refinement;
      options.min_correction = config_.frontend.focal_monitor.focal.min_correction;
      options.averaging = config_.averager.averaging;
      focal_corrector_ = std::make_unique<FocalCorrector>(options, frontend_.get(), &frontend_mutex_,
                                                          focal_checker_.get(), &rig_, averager_.get(), add_edge);
    }
  }
  // Called with frontend_mutex_ held.
  auto frontend_changed = [this] {
    std::lock_guard<std::mutex> lock(mutex_);
    frontend_stats_ = frontend_->Stats();
  };
  map_store_ = std::make_unique<MapStore>(averager_.get(), &rig_, frontend_.get(), &frontend_mutex_, add_edge,
                                          frontend_changed, refiner_.get());
}

KeyframePipeline::~KeyframePipeline() = default;

std::map<std::string, CameraFocalCheck> KeyframePipeline::FocalChecks() const {
  return focal_checker_ ? focal_checker_->Checks() : std::map<std::string, CameraFocalCheck>();
}

TimeDistribution KeyframePipeline::FocalCheckTimes() const {
  return focal_checker_ ? focal_checker_->EstimateTimes() : TimeDistribution();
}

std::vector<std::pair<std::string, bool>> KeyframePipeline::TakeFocalNotices() {
  std::vector<std::pair<std::string, bool>> out;
  if (focal_checker_) out = focal_checker_->TakeNotices();
  if (refiner_ && config_.focal_calibration != FocalCalibrationMode::kOff) {
    const KeyframeRefinerStats r = refiner_->Stats();
    std::lock_guard<std::mutex> lock(mutex_);
    if (r.focal_refinement > refinement_focal_seen_) {
      refinement_focal_seen_ = r.focal_refinement;
      for (const auto& [camera, e] : r.focal) {
        const FocalVerdict verdict = JudgeFocalEstimate(e, config_.frontend.focal_monitor.focal.min_correction);
        const auto said = refinement_focal_verdicts_.find(camera);
        if (said != refinement_focal_verdicts_.end() && said->second == verdict) continue;
        refinement_focal_verdicts_[camera] = verdict;
        std::string line = camera + ": the refinement puts the focal length at " + DescribeFocalEstimate(e) +
                           ", of the one in use: ";
        if (verdict == FocalVerdict::kDisagrees) {
          line += config_.focal_calibration == FocalCalibrationMode::kApply
                      ? "it disagrees (focal_calibration: apply)"
                      : "it disagrees; fix camera_info, or set focal_calibration: apply to correct it";
        } else if (verdict == FocalVerdict::kAgrees) {
          line += "it agrees";
        } else {
          line += "the keyframes cannot tell yet (too few, or motion that does not separate the focal length "
                  "from the depths and the principal point)";
        }
        out.emplace_back(line, verdict == FocalVerdict::kDisagrees);
      }
    }
  }
  if (focal_corrector_) {
    std::vector<std::pair<std::string, bool>> corrections = focal_corrector_->TakeNotices();
    out.insert(out.end(), corrections.begin(), corrections.end());
  }
  return out;
}

std::map<std::string, double> KeyframePipeline::FocalCorrections() const {
  return focal_corrector_ ? focal_corrector_->Corrections() : std::map<std::string, double>();
}

std::map<std::string, RadialDistortion> KeyframePipeline::LensCorrections() const {
  return focal_corrector_ ? focal_corrector_->LensCorrections() : std::map<std::string, RadialDistortion>();
}

std::map<std::string, std::string> KeyframePipeline::FocalLoopRefinements() const {
  return focal_corrector_ ? focal_corrector_->LoopRefinements() : std::map<std::string, std::string>();
}

void KeyframePipeline::WaitForFocalChecks() {
  if (focal_checker_) focal_checker_->Wait();
}

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
  if (m.keyframe1 == m.keyframe2) {
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
  // Refused here, once per image with its camera's name, rather than by the
  // two-view estimation of every pair the keyframe would be tried in.
  if (!CameraOfImage(frame, grey, info, rectified, &camera, &why)) return Reject(&stats_.rejected_images, why, error);
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
  const auto start = Clock::now();
  cv::Mat grey;
  std::string why;
  if (!DecodeImageMsg(image, &grey, &why)) return Reject(&stats_.rejected_images, why, error);
  const bool ok = Validate(image.header.frame_id, image.header.stamp, grey, info, rectified, out, error);
  out->decode_s = SecondsSince(start);
  return ok;
}

bool KeyframePipeline::DecodeCompressedImage(const sensor_msgs::CompressedImage& image,
                                             const sensor_msgs::CameraInfo& info, PendingKeyframe* out,
                                             std::string* error, bool rectified) {
  const auto start = Clock::now();
  cv::Mat grey;
  std::string why;
  if (!DecodeCompressedImageMsg(image, info, rectified, &grey, &why)) return Reject(&stats_.rejected_images, why, error);
  const bool ok = Validate(image.header.frame_id, image.header.stamp, grey, info, rectified, out, error);
  out->decode_s = SecondsSince(start);
  return ok;
}

std::vector<PendingKeyframe> KeyframePipeline::SelectKeyframes(const PendingKeyframe& image) {
  const auto start = Clock::now();
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stream_gaps_.Observe(image.key.frame_id, image.key.stamp_ns);
    stats_.frames_missing = stream_gaps_.Missing();
  }
  if (config_.keyframe_selection == KeyframeSelectionMode::kAll) {
    // Images that are keyframes already (another stack's) are too far
    // apart for tracks: their pairs are matched by descriptors.
    std::lock_guard<std::mutex> lock(mutex_);
    ++stats_.frames;
    stats_.image_times.Add(image.decode_s + SecondsSince(start));
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
    k.tracks = std::move(f.tracks);
    keyframes.push_back(std::move(k));
  }
  std::lock_guard<std::mutex> lock(mutex_);
  ++stats_.frames;
  stats_.frames_skipped = selection.skipped;
  stats_.selection = selection;
  stats_.selection_s = selection.tracking_s;
  stats_.image_times.Add(image.decode_s + SecondsSince(start));
  return keyframes;
}

std::uint64_t KeyframePipeline::FramesMissing() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return stats_.frames_missing;
}

void KeyframePipeline::ResetKeyframeSelection() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stream_gaps_.Reset();
  }
  std::lock_guard<std::mutex> lock(selector_mutex_);
  selector_.Reset();
}

std::size_t KeyframePipeline::ProcessKeyframe(const PendingKeyframe& keyframe, bool* loop_closure,
                                              std::vector<std::string>* warnings) {
  if (loop_closure) *loop_closure = false;
  if (!frontend_) return 0;
  const auto start = Clock::now();
  if (rig_.IsRigCamera(keyframe.key.frame_id)) frontend_->SetRigCalibrated(keyframe.key.frame_id);
  // A lens that keeps the keypoints from scaling with the focal length by
  // more than 5% of what the focal length does: the plumb_bob rig's (0.14)
  // biased the estimate, lund_door's (0.016) did not (docs/decisions.md,
  // "The focal length in the refinement").
  ApplyFocalCorrections(warnings);
  if (refiner_) {
    // camera_info's lens, or the one the check gave it.
    CameraIntrinsics in_use;
    {
      std::lock_guard<std::mutex> lock(frontend_mutex_);
      in_use = frontend_->CameraInUse(keyframe.key.frame_id, keyframe.camera);
    }
    if (in_use.HasDistortion() && FocalScalingError(in_use, in_use.k, keyframe.image.size()) > 0.05) {
      refiner_->HoldFocal(keyframe.key.frame_id);
    }
  }
  std::size_t added = 0;
  std::vector<KeyframeRelativeRotation> edges;
  KeyframeFrontendStats frontend_stats;
  {
    std::lock_guard<std::mutex> lock(frontend_mutex_);
    edges = frontend_->AddKeyframe(keyframe.key, keyframe.image, keyframe.camera, keyframe.tracks);
    frontend_stats = frontend_->Stats();
    if (focal_checker_) focal_checker_->Submit(frontend_->TakeFocalJobs());
    if (refiner_) refiner_->Add(frontend_->TakeCorrespondences());
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
  stats_.keyframe_times.Add(SecondsSince(start));
  frontend_stats_ = std::move(frontend_stats);
  return added;
}

bool KeyframePipeline::ApplyFocalCorrections(std::vector<std::string>* warnings) {
  if (!focal_corrector_) return false;
  const std::map<std::string, double> before = focal_corrector_->Corrections();
  const std::size_t lenses_before = focal_corrector_->LensCorrections().size();
  if (refiner_) {
    const KeyframeRefinerStats r = refiner_->Stats();
    focal_corrector_->ApplyRefinementEstimates(r.focal, r.focal_refinement, warnings);
  }
  focal_corrector_->ApplyCorrections(warnings);
  focal_corrector_->RefineByLoops(FrontendStats().loop_closure_edges);
  bool changed = false;
  for (const auto& [camera, product] : focal_corrector_->Corrections()) {
    const auto b = before.find(camera);
    const double previous = b == before.end() ? 1.0 : b->second;
    if (product == previous) continue;
    changed = true;
    // The refinement's held points were normalised with the former focal length.
    if (refiner_) refiner_->ScaleCamera(camera, product / previous);
  }
  // A lens given: the pairs estimated again with it bring their inliers
  // (KeyframeFrontend::ApplyLensCorrection), in place of the refinement's.
  changed = changed || focal_corrector_->LensCorrections().size() != lenses_before;
  if (changed && refiner_) {
    // The pairs estimated again, with the new focal length's points (after
    // ScaleCamera, which must not scale them).
    std::lock_guard<std::mutex> lock(frontend_mutex_);
    refiner_->Add(frontend_->TakeCorrespondences());
  }
  return changed;
}

OnlineSolution KeyframePipeline::CameraSolution(const OnlineSolution& solution, bool refined) const {
  OnlineSolution cameras = rig_.ToCameraKeyframes(solution);
  if (refined && refiner_) refiner_->Apply(&cameras);
  return cameras;
}

bool KeyframePipeline::MaybeRefine(const OnlineSolution& solution, double now_s, bool force, RefineIn where,
                                   std::function<void(bool)> done) {
  if (!refiner_ || solution.orientations.empty()) return false;
  {
    std::lock_guard<std::mutex> lock(refine_mutex_);
    // The period counts from the first solve: a map of its first few
    // keyframes has nothing to adjust.
    if (std::isnan(last_refine_s_)) last_refine_s_ = now_s;
    if (!force && now_s - last_refine_s_ < config_.refinement_period_s) return false;
    // Staged: the previous one lands now, when the next is due by the
    // caller's clock, however long it took.
    if (where == RefineIn::kStaged) refiner_->Commit();
    if (refiner_->Running()) return false;
    last_refine_s_ = now_s;
  }
  auto cameras = std::make_shared<const OnlineSolution>(CameraSolution(solution, false));
  KeyframeRefiner::RigCaptures rig = RefinerRig(*cameras);
  if (where != RefineIn::kHere) {
    return refiner_->RefineInBackground(std::move(cameras), std::move(rig), std::move(done),
                                        where == RefineIn::kStaged);
  }
  const bool ok = refiner_->Refine(*cameras, rig);
  if (done) done(ok);
  return true;
}

KeyframeRefiner::RigCaptures KeyframePipeline::RefinerRig(const OnlineSolution& cameras) const {
  KeyframeRefiner::RigCaptures rig;
  const auto rig_cameras = rig_.RigCameras();
  for (const auto& [key, r] : cameras.orientations) {
    const auto camera = rig_cameras.find(key.frame_id);
    if (camera != rig_cameras.end()) rig[key] = {rig_.VariableOfKnown(key), camera->second.second};
  }
  return rig;
}

std::size_t KeyframePipeline::RefinementPending(const OnlineSolution& solution) const {
  if (!refiner_ || !config_.refiner.sweep_back || solution.orientations.empty()) return 0;
  const OnlineSolution cameras = CameraSolution(solution, false);
  return refiner_->Pending(cameras, RefinerRig(cameras));
}

void KeyframePipeline::CommitRefinement() {
  if (refiner_) refiner_->Commit();
}

void KeyframePipeline::WaitForRefinement() {
  if (refiner_) refiner_->Wait();
}

void KeyframePipeline::ResetRefinement() {
  if (refiner_) refiner_->Reset();
  std::lock_guard<std::mutex> lock(refine_mutex_);
  last_refine_s_ = std::numeric_limits<double>::quiet_NaN();
}

KeyframeRefinerStats KeyframePipeline::RefinerStats() const {
  return refiner_ ? refiner_->Stats() : KeyframeRefinerStats();
}

bool KeyframePipeline::SaveMap(const std::string& graph_path, std::string* error, std::string* note) {
  return map_store_->Save(graph_path, error, note);
}

MapSaveTiming KeyframePipeline::LastSaveTiming() const { return map_store_->LastSaveTiming(); }

bool KeyframePipeline::LoadMap(const std::string& graph_path, std::string* error, std::string* note,
                               std::map<KeyframeKey, Eigen::Matrix3d>* saved_orientations) {
  return map_store_->Load(graph_path, error, note, saved_orientations);
}

bool KeyframePipeline::AddMap(const std::string& graph_path, std::string* error, std::string* note) {
  std::size_t linked = 0;
  if (!map_store_->Add(graph_path, error, note, &linked)) return false;
  std::lock_guard<std::mutex> lock(mutex_);
  stats_.edges_from_images += linked;
  return true;
}

KeyframeFrontendStats KeyframePipeline::FrontendStats() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return frontend_stats_;
}

CameraInfoCheckArray KeyframePipeline::CameraInfoCheckMsg(const ros::Time& stamp) const {
  return rotation_averaging::CameraInfoCheckMsg(FocalChecks(), FocalCorrections(), stamp);
}

PipelineStats KeyframePipeline::Stats() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return stats_;
}

}  // namespace rotation_averaging
