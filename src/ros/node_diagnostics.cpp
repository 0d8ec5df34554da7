#include "rotation_averaging/ros/node_diagnostics.h"

#include <cstdlib>
#include <fstream>

namespace rotation_averaging {
namespace {

// "a, b": the cameras whose check says `flagged`.
template <typename Flag>
std::string CamerasWhere(const std::map<std::string, CameraFocalCheck>& checks, Flag flagged) {
  std::string cameras;
  for (const auto& [camera, check] : checks) {
    if (flagged(check)) cameras += (cameras.empty() ? "" : ", ") + camera;
  }
  return cameras;
}

void Summarise(const NodeStatus& s, diagnostic_updater::DiagnosticStatusWrapper* status) {
  using diagnostic_msgs::DiagnosticStatus;
  const OnlineAveragerStats& a = s.averager;
  const std::string focal_disagrees =
      CamerasWhere(s.focal_checks, [](const CameraFocalCheck& c) { return c.disagrees; });
  const std::string undescribed_lens =
      CamerasWhere(s.focal_checks, [](const CameraFocalCheck& c) { return c.distortion_unmodelled; });
  if (a.failed_solves > 0 && a.solves == a.failed_solves) {
    status->summary(DiagnosticStatus::ERROR, "every solve failed");
  } else if (s.solve_period_s > 0 && a.last_solve_s > s.solve_period_s) {
    status->summary(DiagnosticStatus::WARN, "solve time exceeds the solve period");
  } else if (a.dropped_queue_full + a.dropped_cap > 0) {
    status->summary(DiagnosticStatus::WARN, "input dropped (queue full or caps reached)");
  } else if (!undescribed_lens.empty()) {
    status->summary(DiagnosticStatus::WARN,
                    "images are distorted but camera_info has no distortion model: " + undescribed_lens);
  } else if (!focal_disagrees.empty()) {
    status->summary(DiagnosticStatus::WARN, "camera_info's focal length disagrees with the images of " + focal_disagrees);
  } else if (s.dropped_images > 0) {
    status->summary(DiagnosticStatus::WARN,
                    "keyframe images dropped: they come faster than the front end processes them");
  } else if (s.pipeline.frames_missing > 0) {
    status->summary(DiagnosticStatus::WARN,
                    "images missing from the camera streams (gaps in their stamps): the driver, the network or "
                    "image_transport_queue lost them, and keyframe selection did not see them");
  } else if (s.refinement && s.refinement_stats.runs > 0 && !s.refinement_stats.last_ok) {
    status->summary(DiagnosticStatus::WARN,
                    "the latest refinement changed nothing (the averaging's orientations are published)");
  } else {
    status->summary(DiagnosticStatus::OK, "ok");
  }
}

void AddFrontend(const NodeStatus& s, diagnostic_updater::DiagnosticStatusWrapper* status) {
  status->add("image queue (keyframes waiting)", s.image_queue);
  status->add("image queue capacity", s.max_image_queue);
  status->add("front-end latency per keyframe, last (ms)", 1e3 * s.latency.last);
  status->add("front-end latency per keyframe, mean of the last 50 (ms)", 1e3 * s.latency.Mean());
  status->add("front-end time per keyframe, mean of the last 50 (ms)", 1e3 * s.frontend_time.Mean());
  const KeyframeFrontendStats& f = s.frontend;
  if (f.pair_times.Count() > 0) {
    status->add("time per two-view pair, median (ms)", 1e3 * f.pair_times.Median());
    status->add("time per two-view pair, p95 (ms)", 1e3 * f.pair_times.P95());
  }
  status->add("loop-closure retrieval", s.retrieval);
  status->add("front-end memory of keyframes (MiB)", f.keyframe_bytes / 1048576.0);
  status->add("loop-closure edges", f.loop_closure_edges);
  status->add("of them, between added maps and the map held", f.map_links);
  status->add("failed two-view pairs", f.failed_pairs);
  if (s.window_pairs) {
    status->add("window-pair edges (to older keyframes of the window)", f.window_edges);
    status->add("window pairs off the chain (dropped)", f.window_rejected_inconsistent);
  }
  if (f.track_pairs + f.track_pairs_matched_instead > 0) {
    status->add("pairs from shared KLT tracks", f.track_pairs);
    status->add("of them, matched by descriptors instead (tracks did not verify)", f.track_pairs_matched_instead);
  }
  // Each camera's focal-length check: its line, and the figures alone.
  for (const auto& [camera, check] : s.focal_checks) {
    status->add("focal length check of " + camera, check.Report());
    if (!check.calibration.estimated) continue;
    status->add("focal length scale of " + camera + " (estimated / camera_info)", check.calibration.scale);
    status->add("focal length scale of " + camera + ", standard deviation", check.calibration.standard_deviation);
  }
  for (const auto& [camera, correction] : s.focal_corrections) {
    status->add("focal length of " + camera + " corrected (x camera_info's)", correction);
  }
  for (const auto& [camera, lens] : s.lens_corrections) {
    status->add("lens given to " + camera + " (division model; camera_info describes none)", lens.lambda);
  }
  if (s.refinement) {
    const KeyframeRefinerStats& r = s.refinement_stats;
    status->add("refinements run", r.runs);
    status->add("refinements applied", r.applied);
    status->add("refinements that changed nothing", r.failed);
    status->add("keyframes corrected by the refinement", r.corrected_keyframes);
    status->add("of them, with the refinement's covariance", r.covariance_keyframes);
    status->add("refinement correction, latest median (deg)", r.median_correction_deg);
    status->add("time per refinement, median (ms)", 1e3 * r.times.Median());
    status->add("time per refinement, p95 (ms)", 1e3 * r.times.P95());
    status->add("refinement correspondences held (MiB)", r.bytes / (1024.0 * 1024.0));
    if (!r.last_report.empty()) status->add("refinement, latest", r.last_report);
    for (const auto& [camera, e] : r.focal) {
      status->add("focal length scale of " + camera + " by the refinement (estimated / in use)", e.scale);
      status->add("focal length scale of " + camera + " by the refinement, standard deviation", e.sigma);
      status->add("focal length of " + camera + " held by the refinement (agreed)",
                  r.focal_agreed.count(camera) ? "true" : "false");
    }
  }
  if (s.focal_check_times.Count() > 0) {
    status->add("focal-length check estimates", s.focal_check_times.Count());
    status->add("time per focal-length check estimate, median (ms)", 1e3 * s.focal_check_times.Median());
    status->add("time per focal-length check estimate, p95 (ms)", 1e3 * s.focal_check_times.P95());
  }
  status->add("front-end memory of the focal-length check (MiB)", f.focal_bytes / 1048576.0);
}

}  // namespace

void RecentTimes::Add(double t) {
  last = t;
  window.push_back(t);
  if (window.size() > 50) window.pop_front();
}

double RecentTimes::Mean() const {
  double sum = 0.0;
  for (double t : window) sum += t;
  return window.empty() ? 0.0 : sum / static_cast<double>(window.size());
}

void FillDiagnostics(const NodeStatus& s, diagnostic_updater::DiagnosticStatusWrapper* status) {
  Summarise(s, status);
  const OnlineAveragerStats& a = s.averager;
  const PipelineStats& p = s.pipeline;
  status->add("keyframes", a.views);
  status->add("edges", a.edges);
  status->add("components", a.components);
  status->add("outlier edges", a.outlier_edges);
  status->add("messages received", a.received);
  if (s.has_rates) {
    status->add("measurements per second (relative poses + front-end edges)", s.measurements_per_s);
    status->add("keyframe images per second", s.keyframe_images_per_s);
  }
  status->add("rejected messages", p.rejected_messages);
  status->add("images seen", p.frames);
  status->add("images that were not keyframes (keyframe_selection)", p.frames_skipped);
  status->add("images missing by their cameras' stamps (lost before the node)", p.frames_missing);
  if (p.frames > 0) status->add("keyframe selection per image (ms)", 1e3 * p.selection_s / p.frames);
  // The time budget, over the most recent images, keyframes and pairs
  // (TimeDistribution's window).
  if (p.image_times.Count() > 0) {
    status->add("time per image (decoding, checks, selection), median (ms)", 1e3 * p.image_times.Median());
    status->add("time per image (decoding, checks, selection), p95 (ms)", 1e3 * p.image_times.P95());
  }
  if (p.keyframe_times.Count() > 0) {
    status->add("time per keyframe (front end), median (ms)", 1e3 * p.keyframe_times.Median());
    status->add("time per keyframe (front end), p95 (ms)", 1e3 * p.keyframe_times.P95());
  }
  status->add("keyframe images processed", p.processed_images);
  status->add("edges from images", p.edges_from_images);
  status->add("rig cameras (extrinsics known)", s.rig_cameras);
  status->add("measurements absorbed by rig extrinsics", p.absorbed_by_rig);
  status->add("rejected images", p.rejected_images + s.images_without_info);
  status->add("dropped images (queue full)", s.dropped_images);
  if (s.has_frontend) AddFrontend(s, status);
  status->add("dropped (queue full)", a.dropped_queue_full);
  status->add("dropped (caps)", a.dropped_cap);
  status->add("queued measurements", a.queued);
  status->add("resident memory (MiB)", s.resident_mib);
  status->add("peak resident memory (MiB)", s.peak_resident_mib);
  status->add("solves", a.solves);
  status->add("local solves (of all solves)", a.local_solves);
  status->add("background full solves taken", a.background_solves);
  status->add("failed solves", a.failed_solves);
  status->add("overruns", a.overruns);
  status->add("last solve time (s)", a.last_solve_s);
  status->add("solve period (s)", s.solve_period_s);
}

void ReadMemoryMiB(double* resident, double* peak) {
  *resident = *peak = 0.0;
  std::ifstream status("/proc/self/status");
  std::string line;
  while (std::getline(status, line)) {
    const bool rss = line.rfind("VmRSS:", 0) == 0, hwm = line.rfind("VmHWM:", 0) == 0;
    if (!rss && !hwm) continue;
    const double kib = std::atof(line.c_str() + 6);
    (rss ? *resident : *peak) = kib / 1024.0;
  }
}

}  // namespace rotation_averaging
