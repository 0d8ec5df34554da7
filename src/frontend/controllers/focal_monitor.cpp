#include "rotation_averaging/frontend/controllers/focal_monitor.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <iomanip>
#include <sstream>
#include <utility>

#include "rotation_averaging/util/option_check.h"

namespace rotation_averaging {

bool FocalMonitorOptions::Validate(std::string* error) const {
  return OptionCheck()
      .AtLeast("focal_first_estimate_pairs", first_estimate_pairs, std::max(1, focal.min_pairs))
      .Above("focal_estimate_growth", growth, 1.0)
      .AtLeast("focal_max_pairs", max_pairs, first_estimate_pairs)
      .AtLeast("focal_max_matches_per_pair", max_matches_per_pair, focal.min_inliers)
      .AtLeast("focal_max_correction_pairs", max_correction_pairs, 1)
      .Within("focal_principal_point_sigma", focal.principal_point_sigma, 0.0, 0.2)
      .Within("focal_min_correction", focal.min_correction, 0.0, 0.5)
      .Ok(error);
}

std::string CameraFocalCheck::Report() const {
  std::ostringstream out;
  out << camera << ": ";
  if (!calibration.estimated) {
    out << "focal length not determined yet (" << pairs_seen << " verified pairs"
        << (calibration.unobservable ? "; the motion so far does not determine it" : "") << ")";
  } else {
    out << std::fixed << std::setprecision(4) << "focal length x" << calibration.scale << " +- "
        << calibration.standard_deviation << " (matches " << calibration.matches_deviation << ", principal point "
        << calibration.principal_point_deviation << ")" << std::setprecision(1) << " of the given "
        << given_focal_px << " px (" << calibration.pairs << " of " << pairs_seen << " verified pairs): "
        << (disagrees ? "disagrees with the given intrinsics, check the calibration" : "agrees");
  }
  if (distortion_checked && distortion.estimated) {
    out << std::fixed << std::setprecision(3) << "; radial distortion seen (division model) " << distortion.lambda
        << " +- " << distortion.standard_deviation << ", " << std::setprecision(1) << distortion.corner_shift_px
        << " px at the corners";
    if (std::isfinite(distortion.advantage_deviation)) {
      out << " (the pairs' cost " << distortion.focal_only_cost - distortion.cost << " +- "
          << distortion.advantage_deviation << " below the focal length's alone)";
    }
    out << ": "
        << (distortion_unmodelled ? "the images are distorted but camera_info has no distortion model: give its "
                                    "distortion_model and D, or rectified images"
            : distortion_explained_by_focal
                ? "the focal length's scale alone explains the pairs as well: no distortion beyond the focal error"
                : "none beyond the noise");
  }
  return out.str();
}

std::shared_ptr<const FocalSample> MakeFocalSample(const std::vector<Eigen::Vector2d>& points1,
                                                   const std::vector<Eigen::Vector2d>& points2,
                                                   const RelativePoseResult& pose, int max_matches) {
  auto sample = std::make_shared<FocalSample>();
  sample->pose = pose;
  const std::size_t n = std::min(points1.size(), points2.size());
  const std::size_t keep = std::min(n, static_cast<std::size_t>(std::max(1, max_matches)));
  if (keep == n) {
    sample->points1.assign(points1.begin(), points1.begin() + n);
    sample->points2.assign(points2.begin(), points2.begin() + n);
    return sample;
  }
  std::vector<int> new_index(n, -1);
  sample->points1.reserve(keep);
  sample->points2.reserve(keep);
  for (std::size_t i = 0; i < keep; ++i) {
    const std::size_t m = i * n / keep;
    new_index[m] = static_cast<int>(i);
    sample->points1.push_back(points1[m]);
    sample->points2.push_back(points2[m]);
  }
  sample->pose.inliers.clear();
  for (int m : pose.inliers) {
    if (m >= 0 && static_cast<std::size_t>(m) < n && new_index[m] >= 0) sample->pose.inliers.push_back(new_index[m]);
  }
  return sample;
}

CameraFocalCheck RunFocalJob(const FocalJob& job, const FocalCalibrationOptions& options) {
  std::vector<FocalPair> pairs;
  pairs.reserve(job.samples.size());
  for (const auto& s : job.samples) pairs.push_back({&s->points1, &s->points2, &s->pose});
  CameraFocalCheck check;
  check.camera = job.camera;
  check.given_focal_px = job.given_focal_px;
  check.pairs_seen = job.pairs_seen;
  check.calibration = EstimateFocalScale(pairs, job.k, options, &job.lens);
  check.disagrees = ShouldApplyFocalScale(check.calibration, options);
  if (job.check_distortion) {
    RadialDistortionOptions distortion;
    distortion.min_inliers = options.min_inliers;
    distortion.min_pairs = options.min_pairs;
    distortion.num_threads = options.num_threads;
    check.distortion_checked = true;
    check.distortion = EstimateRadialDistortion(pairs, job.k, distortion, &check.calibration);
    check.distortion_unmodelled = DistortionIsUnmodelled(check.distortion, distortion);
    check.distortion_explained_by_focal =
        DistortionBeyondNoise(check.distortion, distortion) && check.distortion.FocalExplainsAsWell();
  }
  return check;
}

void FocalMonitor::Add(const std::string& camera, const Eigen::Matrix3d& k, double given_focal_px,
                       CameraIntrinsics lens, std::shared_ptr<const FocalSample> sample) {
  if (!options_.enabled || !sample) return;
  Camera& c = cameras_[camera];
  const bool same_lens = c.lens.HasDistortion() == lens.HasDistortion() &&
                         (!lens.HasDistortion() ||
                          (c.lens.distortion == lens.distortion && c.lens.coefficients == lens.coefficients));
  if (c.seen == 0 || !(c.k == k) || !same_lens) {
    c = Camera();
    c.k = k;
    c.given_focal_px = given_focal_px;
    c.lens = std::move(lens);
    c.next_estimate = static_cast<std::uint64_t>(std::max(1, options_.first_estimate_pairs));
  }
  ++c.seen;
  c.held.push_back(std::move(sample));
  if (static_cast<int>(c.held.size()) > std::max(1, options_.max_pairs)) {
    std::vector<std::shared_ptr<const FocalSample>> kept;
    for (std::size_t i = 0; i < c.held.size(); i += 2) kept.push_back(std::move(c.held[i]));
    c.held.swap(kept);
  }
  if (c.seen < c.next_estimate) return;
  c.next_estimate = std::max(c.seen + 1, static_cast<std::uint64_t>(std::ceil(c.seen * options_.growth)));
  due_.push_back({camera, !c.lens.HasDistortion(), c.lens, c.k, c.given_focal_px, c.seen, c.held});
}

std::size_t FocalMonitor::HeldBytes() const {
  std::size_t bytes = 0;
  for (const auto& [name, camera] : cameras_) {
    for (const auto& s : camera.held) {
      bytes += sizeof(FocalSample) + (s->points1.size() + s->points2.size()) * sizeof(Eigen::Vector2d) +
               s->pose.inliers.size() * sizeof(int);
    }
  }
  return bytes;
}

double FocalMonitor::GivenFocal(const std::string& camera) const {
  const auto it = cameras_.find(camera);
  return it == cameras_.end() ? 0.0 : it->second.given_focal_px;
}

CameraIntrinsics FocalMonitor::Lens(const std::string& camera) const {
  const auto it = cameras_.find(camera);
  return it == cameras_.end() ? CameraIntrinsics() : it->second.lens;
}

std::vector<FocalJob> FocalMonitor::TakeDue() {
  std::vector<FocalJob> out;
  out.swap(due_);
  return out;
}

std::size_t FocalMonitor::HeldPairs(const std::string& camera) const {
  const auto it = cameras_.find(camera);
  return it == cameras_.end() ? 0 : it->second.held.size();
}

FocalChecker::FocalChecker(const FocalCalibrationOptions& options) : options_(options) {
  worker_ = std::thread(&FocalChecker::Run, this);
}

FocalChecker::~FocalChecker() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stopping_ = true;
  }
  wake_.notify_all();
  worker_.join();
}

void FocalChecker::Submit(std::vector<FocalJob> jobs) {
  if (jobs.empty()) return;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    for (FocalJob& job : jobs) {
      bool replaced = false;
      for (FocalJob& waiting : queue_) {
        if (waiting.camera != job.camera) continue;
        waiting = std::move(job);
        replaced = true;
        break;
      }
      if (!replaced) queue_.push_back(std::move(job));
    }
  }
  wake_.notify_one();
}

std::map<std::string, CameraFocalCheck> FocalChecker::Checks() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return checks_;
}

std::vector<std::pair<std::string, bool>> FocalChecker::TakeNotices() {
  std::lock_guard<std::mutex> lock(mutex_);
  std::vector<std::pair<std::string, bool>> out;
  out.swap(notices_);
  return out;
}

void FocalChecker::Wait() {
  std::unique_lock<std::mutex> lock(mutex_);
  idle_.wait(lock, [this] { return queue_.empty() && !running_job_; });
}

void FocalChecker::ExpectFocal(const std::string& camera, double given_focal_px) {
  std::lock_guard<std::mutex> lock(mutex_);
  expected_focal_px_[camera] = given_focal_px;
  const auto it = checks_.find(camera);
  if (it != checks_.end() && it->second.given_focal_px != given_focal_px) checks_.erase(it);
}

TimeDistribution FocalChecker::EstimateTimes() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return estimate_times_;
}

void FocalChecker::Run() {
  while (true) {
    FocalJob job;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      wake_.wait(lock, [this] { return stopping_ || !queue_.empty(); });
      if (stopping_) return;
      job = std::move(queue_.front());
      queue_.pop_front();
      running_job_ = true;
    }
    const auto start = std::chrono::steady_clock::now();
    CameraFocalCheck check = RunFocalJob(job, options_);
    const double seconds = SecondsSince(start);
    {
      std::lock_guard<std::mutex> lock(mutex_);
      estimate_times_.Add(seconds);
      const auto expected = expected_focal_px_.find(check.camera);
      if (expected != expected_focal_px_.end() && expected->second != check.given_focal_px) {
        running_job_ = false;  // estimated on a focal length no longer used
        idle_.notify_all();
        continue;
      }
      const auto it = checks_.find(check.camera);
      const bool was_estimated = it != checks_.end() && it->second.calibration.estimated;
      const bool was_disagreeing = it != checks_.end() && it->second.disagrees;
      const bool was_unmodelled = it != checks_.end() && it->second.distortion_unmodelled;
      if ((check.calibration.estimated && !was_estimated) || check.disagrees != was_disagreeing ||
          check.distortion_unmodelled != was_unmodelled) {
        notices_.emplace_back(check.Report(), check.Flagged());
      }
      checks_[check.camera] = check;
      running_job_ = false;
    }
    idle_.notify_all();
  }
}

}  // namespace rotation_averaging
