// What a bag replay (bag_replay.h) reports: every figure of the run in
// ReplayResult, gathered from the pipeline at the end, and the files and the
// summary written from it (scores against ground truth, the front end's cost
// per keyframe, the plots).
#ifndef ROTATION_AVERAGING_ROS_REPLAY_REPORT_H_
#define ROTATION_AVERAGING_ROS_REPLAY_REPORT_H_

#include <cstdint>
#include <ostream>
#include <map>
#include <string>
#include <vector>

#include "rotation_averaging/ros/keyframe_pipeline.h"
#include "rotation_averaging/core/eval/rotation_evaluation.h"
#include "rotation_averaging/frontend/controllers/keyframe_refiner.h"
#include "rotation_averaging/util/time_distribution.h"

namespace rotation_averaging {

struct ReplayResult {
  bool ok = false;
  std::string error;                // why the replay failed (ok == false)
  std::vector<std::string> warnings;
  bool truncated = false;           // stopped at damage in a bag; results cover what came before
  std::size_t messages_total = 0, messages_read = 0;
  std::size_t damaged_messages = 0;  // did not deserialise: dropped
  double bag_start_s = 0.0, bag_duration_s = 0.0;
  double wall_s = 0.0, cpu_s = 0.0, peak_rss_mib = 0.0;
  std::size_t keyframes = 0;   // camera keyframes oriented
  std::size_t variables = 0;   // solved views: keyframes, or captures of a rig with known extrinsics
  std::size_t edges = 0, components = 0, outlier_edges = 0;
  std::vector<std::string> rig_cameras;  // "camera in rig_frame"
  // How each camera's keypoints were undistorted (or that they were not),
  // once per camera and whenever its camera_info changed.
  std::vector<std::string> camera_models;
  // The focal-length check (focal_calibration: warn): its log lines as the
  // estimates came (a camera's first, and each change of verdict), and each
  // camera's last estimate (CameraFocalCheck::Report).
  std::vector<std::string> focal_notices, focal_checks;
  std::vector<std::string> focal_corrections;  // focal_calibration: apply: "cam: camera_info's focal length x1.03"
  // focal_calibration: apply: "cam: division model -0.118 +- 0.001, 47.9 px at the corners".
  std::vector<std::string> lens_corrections;
  // focal_loop_refinement: each camera's latest estimate from the loops and
  // what became of it (KeyframePipeline::FocalLoopRefinements).
  std::vector<std::string> focal_loop_refinements;
  std::size_t absorbed_by_rig = 0;
  std::map<std::string, std::size_t> edges_by_source;
  std::size_t keyframe_images = 0, rejected_images = 0, rejected_messages = 0;
  KeyframeSelectionStats selection;  // keyframe_selection: motion
  std::size_t images_seen = 0, images_skipped = 0;  // valid images offered to keyframe selection, not keyframes
  std::size_t images_missing = 0;  // by the gaps in each camera's stamps (PipelineStats::frames_missing)
  std::string keyframe_selection;
  double selection_s = 0.0;  // wall time of keyframe selection
  // The time budget (PipelineStats, KeyframeFrontendStats): per valid image
  // (decoding, checks, selection), per keyframe (the front end), per two-view
  // pair (matching and estimation, on its thread).
  TimeDistribution image_times, keyframe_times, pair_times;
  TimeDistribution focal_check_times;  // each focal-length estimate (the replay waits for it)
  double frontend_features_s = 0.0, frontend_retrieval_s = 0.0, frontend_pairs_s = 0.0;
  // Two-view pairs of the front end: failed, edges from the rotation-only
  // model, and failed previous pairs bridged by an older keyframe.
  std::uint64_t frontend_failed_pairs = 0, frontend_rotation_model_edges = 0, frontend_chain_bridged = 0;
  std::map<std::string, std::uint64_t> frontend_failures;  // two-view failure reason -> count
  std::string retrieval;  // how loop-closure candidates were found
  std::uint64_t loop_candidates = 0, loop_closure_edges = 0;
  std::uint64_t loops_same_place = 0;  // dropped by one_loop_per_place
  // window_pairs: edges to older keyframes of the window, and the verified
  // ones dropped for disagreeing with the chain.
  std::uint64_t window_edges = 0, window_rejected_inconsistent = 0;
  std::uint64_t track_pairs = 0, track_pairs_matched_instead = 0;  // tracks: true
  // Of those, between added maps and the map held (add_maps), and the time
  // matching them took.
  std::uint64_t map_links = 0;
  double map_link_s = 0.0;
  // Front-end wall time per keyframe (ms) in arrival order: features,
  // retrieval, pair verification, and all of ProcessKeyframe.
  struct KeyframeCost {
    double features_ms = 0.0, retrieval_ms = 0.0, pairs_ms = 0.0, total_ms = 0.0;
  };
  std::vector<KeyframeCost> frontend_cost;
  std::size_t frontend_bytes = 0;             // features and retrieval data held at the end
  std::size_t compact_bytes = 0;              // of that, by the compact keyframes
  std::uint64_t compacted_keyframes = 0;      // keyframes holding only their compact features
  std::string frontend_cost_csv, frontend_cost_png;
  std::size_t solves = 0;
  // The background refinement (refinement: true): its counts, times and
  // latest outcome (KeyframeRefinerStats); refinement_runs 0 without it.
  bool refinement = false;
  KeyframeRefinerStats refinement_stats;
  double final_cost = 0.0;
  bool have_scores = false;
  EvaluationResult scores;
  // The published posterior covariances (~orientations) of the last
  // solution against the ground truth (EvaluatePosteriorCovariances).
  PosteriorCalibration posterior;
  std::string orientations_csv, graph_file, output_bag, scores_file, plot_png;
  // The ground truth of the keyframes scored, under their keyframe names
  // (those of orientations.csv and graph.txt): what `rotavg solve graph.txt
  // --gt` and `rotavg eval --gt` score a re-solve of the graph against.
  std::string ground_truth_csv;
  // Each scored keyframe's posterior: its error against the truth relative
  // to its gauge, its covariance's standard deviation and its NEES
  // (PosteriorCalibration); empty when none is scored.
  std::string posterior_csv;
  // The map the replay started from (load_graph) and the one it saved at
  // the end (save_on_shutdown), as KeyframePipeline::LoadMap and SaveMap
  // described them; empty when not asked for.
  std::string map_loaded, map_saved;
  std::vector<std::string> maps_added;  // what AddMap said of each of add_maps
  std::vector<std::string> maps_saved_after_bags;  // save_after_each_bag: what SaveMap said, bag by bag
  double map_load_s = 0.0, map_save_s = 0.0;  // wall time of LoadMap and SaveMap
  double map_save_graph_lock_s = 0.0, map_save_frontend_lock_s = 0.0;  // of SaveMap: MapSaveTiming
  // The keyframes of the loaded map: the largest angle between where the map
  // had them and the first solve after loading (< 0: the map holds no
  // orientations); at the first solve that joined a new keyframe to them,
  // their largest move since that first solve, in degrees and in posterior
  // standard deviations along the move, and the rotation of their frame as
  // a whole (AlignRotations).
  double map_load_shift_deg = -1.0;
  bool map_merged = false;
  std::size_t map_merged_at_solve = 0;
  double map_merge_move_deg = 0.0, map_merge_move_sigma = 0.0;
  double map_merge_frame_deg = 0.0;  // the one rotation that best maps them from before to after
  std::string Summary() const;  // the multi-line report printed at the end

 private:
  // Parts of the summary, written to its stream (and in its number format).
  void SummariseFrontend(std::ostream& out) const;  // with keyframe images
  void SummariseMaps(std::ostream& out) const;      // loaded, added, saved
};

// What the pipeline did, for the summary: its counters, the averager's,
// the front end's, the rig's and the focal checks' last word.
void CollectStatistics(const KeyframePipeline& pipeline, OnlineAverager& averager, const OnlineSolution& solution,
                       ReplayResult* result);

// The front end's cost per keyframe (result->frontend_cost): a CSV in
// `output_dir`, and a plot of its means over 20 keyframes against the
// keyframe count; their paths into `result`.
bool WriteFrontendCost(const std::string& output_dir, ReplayResult* result, std::string* error);

// Scores the camera orientations `named` (of `solution`) against the
// ground truth: scores.txt, ground_truth.csv (the keyframes' ground truth
// under their names), and errors.png with each camera's error per keyframe
// over capture time, in `output_dir`; the scores and paths into `result`.
bool ScoreAgainstGroundTruth(const NamedOrientations& named, const NamedOrientations& ground_truth,
                             const OnlineSolution& solution, const std::string& output_dir, ReplayResult* result,
                             std::string* error);

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_ROS_REPLAY_REPORT_H_
