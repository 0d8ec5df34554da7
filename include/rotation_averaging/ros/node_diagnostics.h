// The node's diagnostics (/diagnostics, "rotation averaging"): its health
// in one line and its counters, built from a snapshot of the node's state.
// No node handle or master is needed to build them, so tests check them
// directly.
#ifndef ROTATION_AVERAGING_ROS_NODE_DIAGNOSTICS_H_
#define ROTATION_AVERAGING_ROS_NODE_DIAGNOSTICS_H_

#include <diagnostic_updater/DiagnosticStatusWrapper.h>

#include <cstddef>
#include <cstdint>
#include <deque>
#include <map>
#include <string>

#include "rotation_averaging/ros/keyframe_pipeline.h"

namespace rotation_averaging {

// The last of a series of times and the mean of the last 50 (s).
struct RecentTimes {
  double last = 0.0;
  std::deque<double> window;
  void Add(double t);
  double Mean() const;
};

// What the diagnostics report, copied from the node's parts at one moment.
struct NodeStatus {
  OnlineAveragerStats averager;
  double solve_period_s = 0.0;
  PipelineStats pipeline;
  std::size_t rig_cameras = 0;  // cameras whose rig extrinsics are known
  // The node's own counters of the image path.
  std::uint64_t dropped_images = 0;       // image queue full
  std::uint64_t images_without_info = 0;  // compressed images before any camera_info
  std::size_t image_queue = 0, max_image_queue = 0;
  RecentTimes latency;        // from an image's arrival to its edges entering the graph
  RecentTimes frontend_time;  // the front end's time per keyframe
  // Input rates since the previous diagnostics update (when there was one).
  bool has_rates = false;
  double measurements_per_s = 0.0, keyframe_images_per_s = 0.0;
  // The image front end, when the node has one.
  bool has_frontend = false;
  KeyframeFrontendStats frontend;
  std::string retrieval;  // KeyframeFrontend::RetrievalName
  bool window_pairs = false;
  std::map<std::string, CameraFocalCheck> focal_checks;
  TimeDistribution focal_check_times;  // each focal-length estimate, on the checker's thread
  bool refinement = false;  // the background refinement (refinement: true, with images)
  KeyframeRefinerStats refinement_stats;
  std::map<std::string, double> focal_corrections;
  std::map<std::string, RadialDistortion> lens_corrections;
  double resident_mib = 0.0, peak_resident_mib = 0.0;
};

// The summary (ERROR when every solve failed; WARN when solves overrun the
// period, input is dropped, a lens or focal length disagrees with
// camera_info, or images come faster than the front end; OK otherwise) and
// every counter of `s`, as key-value pairs.
void FillDiagnostics(const NodeStatus& s, diagnostic_updater::DiagnosticStatusWrapper* status);

// Resident and peak resident memory of this process (MiB), from /proc.
void ReadMemoryMiB(double* resident, double* peak);

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_ROS_NODE_DIAGNOSTICS_H_
