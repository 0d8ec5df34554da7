#include "rotation_averaging/ros/replay_report.h"

#include "rotation_averaging/frontend/controllers/focal_corrector.h"

#include <algorithm>
#include <cstdio>
#include <fstream>
#include <iomanip>
#include <limits>
#include <sstream>
#include <utility>

#include "rotation_averaging/frontend/controllers/focal_corrector.h"
#include "rotation_averaging/frontend/eval/error_plot.h"
#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/core/io/orientation_io.h"

namespace rotation_averaging {

void CollectStatistics(const KeyframePipeline& pipeline, OnlineAverager& averager, const OnlineSolution& solution,
                       ReplayResult* result) {
  const OnlineAveragerStats stats = averager.Stats();
  const PipelineStats pipeline_stats = pipeline.Stats();
  result->variables = stats.views;
  result->keyframes = solution.orientations.size();
  result->edges = stats.edges;
  result->components = solution.summary.components.size();
  result->outlier_edges = solution.summary.num_outlier_edges;
  for (const ComponentSummary& c : solution.summary.components) result->final_cost += c.final_cost;
  for (const auto& [source, n] : averager.EdgesBySource()) result->edges_by_source[EdgeSourceName(source)] = n;
  result->keyframe_images = pipeline_stats.processed_images;
  result->images_seen = pipeline_stats.frames;
  result->images_skipped = pipeline_stats.frames_skipped;
  result->images_missing = pipeline_stats.frames_missing;
  result->selection = pipeline_stats.selection;
  result->selection_s = pipeline_stats.selection_s;
  result->image_times = pipeline_stats.image_times;
  result->keyframe_times = pipeline_stats.keyframe_times;
  result->keyframe_selection = OptionName(pipeline.Config().keyframe_selection);
  result->rejected_images = pipeline_stats.rejected_images;
  result->rejected_messages = pipeline_stats.rejected_messages;
  if (const KeyframeFrontend* f = pipeline.Frontend()) {
    result->frontend_features_s = f->Stats().features_s;
    result->frontend_retrieval_s = f->Stats().retrieval_s;
    result->frontend_pairs_s = f->Stats().pairs_s;
    result->pair_times = f->Stats().pair_times;
    result->frontend_failed_pairs = f->Stats().failed_pairs;
    result->frontend_rotation_model_edges = f->Stats().rotation_model_edges;
    result->frontend_chain_bridged = f->Stats().chain_bridged;
    result->loop_candidates = f->Stats().loop_candidates_tried;
    result->loop_closure_edges = f->Stats().loop_closure_edges;
    result->loops_same_place = f->Stats().loops_same_place;
    result->window_edges = f->Stats().window_edges;
    result->window_rejected_inconsistent = f->Stats().window_rejected_inconsistent;
    result->track_pairs = f->Stats().track_pairs;
    result->track_pairs_matched_instead = f->Stats().track_pairs_matched_instead;
    result->map_links = f->Stats().map_links;
    result->map_link_s = f->Stats().map_link_s;
    result->frontend_bytes = f->Stats().keyframe_bytes;
    result->compacted_keyframes = f->Stats().compacted_keyframes;
    result->compact_bytes = f->Stats().compact_bytes;
    result->frontend_failures = f->Stats().failures;
    result->retrieval = f->RetrievalName();
  }
  result->absorbed_by_rig = pipeline_stats.absorbed_by_rig;
  for (const auto& [camera, rig] : pipeline.Rig().RigCameras()) result->rig_cameras.push_back(camera + " in " + rig.first);
  for (const auto& [camera, check] : pipeline.FocalChecks()) result->focal_checks.push_back(check.Report());
  result->focal_check_times = pipeline.FocalCheckTimes();
  for (const auto& [camera, correction] : pipeline.FocalCorrections()) {
    std::ostringstream line;
    line << camera << ": camera_info's focal length x" << std::setprecision(6) << correction;
    result->focal_corrections.push_back(line.str());
  }
  for (const auto& [camera, lens] : pipeline.LensCorrections()) {
    std::ostringstream line;
    line << std::fixed << std::setprecision(3) << camera << ": division model " << lens.lambda << " +- "
         << lens.standard_deviation << ", " << std::setprecision(1) << lens.corner_shift_px << " px at the corners";
    result->lens_corrections.push_back(line.str());
  }
  for (const auto& [camera, line] : pipeline.FocalLoopRefinements()) result->focal_loop_refinements.push_back(line);
  result->refinement = pipeline.HasRefiner();
  result->refinement_stats = pipeline.RefinerStats();
}

bool WriteFrontendCost(const std::string& output_dir, ReplayResult* result, std::string* error) {
  if (result->frontend_cost.empty()) return true;
  result->frontend_cost_csv = output_dir + "/frontend_cost.csv";
  std::ofstream csv(result->frontend_cost_csv);
  csv << "keyframe,features_ms,retrieval_ms,pairs_ms,total_ms\n";
  LineSeries total{"front end, all (mean of 20)", {}, {}}, retrieval{"retrieval (mean of 20)", {}, {}};
  double sum_total = 0.0, sum_retrieval = 0.0;
  for (std::size_t k = 0; k < result->frontend_cost.size(); ++k) {
    const ReplayResult::KeyframeCost& c = result->frontend_cost[k];
    csv << k + 1 << "," << c.features_ms << "," << c.retrieval_ms << "," << c.pairs_ms << "," << c.total_ms << "\n";
    // Means over 20 keyframes: single keyframes with a loop closure to
    // verify are several times the others.
    sum_total += c.total_ms;
    sum_retrieval += c.retrieval_ms;
    if ((k + 1) % 20 == 0) {
      total.x.push_back(static_cast<double>(k + 1));
      total.y.push_back(sum_total / 20);
      retrieval.x.push_back(static_cast<double>(k + 1));
      retrieval.y.push_back(sum_retrieval / 20);
      sum_total = sum_retrieval = 0.0;
    }
  }
  if (!csv) {
    *error = "cannot write " + result->frontend_cost_csv;
    return false;
  }
  result->frontend_cost_png = output_dir + "/frontend_cost.png";
  std::string plot_error;
  if (!WriteLinePlot(result->frontend_cost_png, "front-end wall time per keyframe against the keyframe count",
                     "keyframes", "ms per keyframe", {total, retrieval}, &plot_error)) {
    result->frontend_cost_png.clear();  // fewer than 20 keyframes: nothing to draw
  }
  return true;
}

bool ScoreAgainstGroundTruth(const NamedOrientations& named, const NamedOrientations& ground_truth,
                             const OnlineSolution& solution, const std::string& output_dir, ReplayResult* result,
                             std::string* error) {
  result->scores = EvaluateOrientations(named, ground_truth);
  result->have_scores = true;
  {
    std::map<std::string, Eigen::Matrix3d> covariances;
    std::map<std::string, int> component;
    for (const auto& [key, c] : solution.covariance) covariances[OnlineAverager::KeyframeName(key)] = c;
    for (const auto& [key, index] : solution.component) component[OnlineAverager::KeyframeName(key)] = index;
    result->posterior = EvaluatePosteriorCovariances(named, covariances, component, ground_truth);
  }
  result->scores_file = output_dir + "/scores.txt";
  std::ofstream scores(result->scores_file);
  scores << result->scores.ToText() << "\n";
  if (!scores) {
    *error = "cannot write " + result->scores_file;
    return false;
  }
  result->ground_truth_csv = output_dir + "/ground_truth.csv";
  if (!WriteOrientationsCsv(result->ground_truth_csv, ground_truth, error)) return false;
  if (!result->posterior.views.empty()) {
    // Which keyframes' covariances tell the truth and which do not, for a
    // user fusing them (and for the covariances' own benchmarks).
    result->posterior_csv = output_dir + "/posterior.csv";
    std::ofstream csv(result->posterior_csv);
    csv << "name,gauge,error_deg,sigma_deg,nees\n" << std::setprecision(6);
    for (const auto& [name, v] : result->posterior.views) {
      csv << name << ',' << v.gauge << ',' << RadToDeg(v.error.norm()) << ',' << RadToDeg(v.sigma) << ',' << v.nees
          << '\n';
    }
    if (!csv) {
      *error = "cannot write " + result->posterior_csv;
      return false;
    }
  }
  std::map<std::string, ErrorSeries> series;
  std::int64_t first_stamp = std::numeric_limits<std::int64_t>::max();
  for (const auto& [key, r] : solution.orientations) first_stamp = std::min(first_stamp, key.stamp_ns);
  for (const auto& [name, e] : result->scores.errors_deg) {
    KeyframeKey key;
    if (!OnlineAverager::ParseKeyframeName(name, &key)) continue;
    ErrorSeries& s = series[key.frame_id];
    s.label = key.frame_id;
    s.time_s.push_back(1e-9 * static_cast<double>(key.stamp_ns - first_stamp));
    s.error_deg.push_back(e);
  }
  std::vector<ErrorSeries> list;
  for (auto& [frame, s] : series) list.push_back(std::move(s));
  char title[160];
  std::snprintf(title, sizeof(title), "%zu keyframes: median %.3f deg, AUC@2/5/10 %.1f / %.1f / %.1f",
                result->scores.views_common, result->scores.median_error_deg, 100 * result->scores.auc[0].second,
                100 * result->scores.auc[1].second, 100 * result->scores.auc[2].second);
  result->plot_png = output_dir + "/errors.png";
  std::string plot_error;
  if (!WriteErrorPlot(result->plot_png, title, list, &plot_error)) {
    result->warnings.push_back("no plot: " + plot_error);
    result->plot_png.clear();
  }
  return true;
}

void ReplayResult::SummariseFrontend(std::ostream& out) const {
  out << "front end per keyframe: features " << 1e3 * frontend_features_s / keyframe_images << " ms, retrieval "
      << 1e3 * frontend_retrieval_s / keyframe_images << " ms, pair verification "
      << 1e3 * frontend_pairs_s / keyframe_images << " ms\n";
  out << "two-view pairs: " << frontend_failed_pairs << " failed";
  if (!frontend_failures.empty()) {
    out << " (";
    bool first = true;
    for (const auto& [why, n] : frontend_failures) {
      out << (first ? "" : ", ") << why << " " << n;
      first = false;
    }
    out << ")";
  }
  out << ", " << frontend_chain_bridged
      << " failed previous pairs bridged by an older keyframe, " << frontend_rotation_model_edges
      << " edges from the rotation-only model\n";
  if (window_edges + window_rejected_inconsistent > 0) {
    out << "window pairs: " << window_edges << " edges to older keyframes of the window, "
        << window_rejected_inconsistent << " verified but off the chain's prediction (window_pairs)\n";
  }
  if (track_pairs + track_pairs_matched_instead > 0) {
    out << "tracks: " << track_pairs << " pairs estimated from shared KLT tracks, " << track_pairs_matched_instead
        << " matched by descriptors when their tracks did not verify\n";
  }
  out << "loop closures: " << loop_closure_edges << " edges from " << loop_candidates
      << " verified candidates; retrieval: " << retrieval << "\n";
  if (loops_same_place > 0) {
    out << "  and " << loops_same_place << " dropped for a loop with more inliers to the same place (one_loop_per_place)\n";
  }
  if (map_links > 0) {
    out << "  of them between added maps and the map held: " << map_links << " (matched in " << map_link_s
        << " s)\n";
  }
  out << "front-end memory: " << frontend_bytes / 1048576.0 << " MiB of features and retrieval data for "
      << keyframe_images << " keyframes";
  if (compacted_keyframes > 0) {
    out << " (" << compacted_keyframes << " compact, " << compact_bytes / 1024.0 / compacted_keyframes
        << " KB each)";
  }
  out << "\n";
  const std::size_t n = frontend_cost.size();
  if (n >= 300) {
    auto mean = [this](std::size_t from, std::size_t to) {
      double sum = 0.0;
      for (std::size_t k = from; k < to; ++k) sum += frontend_cost[k].total_ms;
      return sum / static_cast<double>(to - from);
    };
    const double early = mean(100, 200), late = mean(n - 100, n);
    out << "front-end cost per keyframe: keyframes 100-200 " << early << " ms, last 100 " << late << " ms ("
        << late / early << "x)\n";
  }
}

void ReplayResult::SummariseMaps(std::ostream& out) const {
  if (!map_loaded.empty()) {
    out << "map loaded in " << std::setprecision(1) << 1e3 * map_load_s << " ms: " << map_loaded << "\n";
    if (map_load_shift_deg >= 0.0) {
      out << "loaded keyframes at the first solve: moved at most " << std::setprecision(4) << map_load_shift_deg
          << " deg from where the map had them\n";
    }
    if (map_merged) {
      out << "loaded keyframes when new keyframes joined them (solve " << map_merged_at_solve << "): moved at most "
          << std::setprecision(4) << map_merge_move_deg << " deg, " << std::setprecision(3) << map_merge_move_sigma
          << " posterior standard deviations; their frame as a whole rotated by " << std::setprecision(4)
          << map_merge_frame_deg << " deg\n";
    } else {
      out << "loaded keyframes: no new keyframe joined them\n";
    }
  }
  for (const std::string& added : maps_added) out << added << "\n";
  for (const std::string& saved : maps_saved_after_bags) out << "after a bag: " << saved << "\n";
  if (!map_saved.empty()) {
    out << "map saved in " << std::setprecision(1) << 1e3 * map_save_s << " ms (the graph held "
        << 1e3 * map_save_graph_lock_s << " ms, the front end " << 1e3 * map_save_frontend_lock_s
        << " ms): " << map_saved << "\n";
  }
}

std::string ReplayResult::Summary() const {
  std::ostringstream out;
  out.setf(std::ios::fixed);
  out.precision(2);
  out << "messages: " << messages_read << " of " << messages_total << (truncated ? " (stopped at damage)" : "") << "\n";
  out << "bag time: " << bag_duration_s << " s; wall time: " << wall_s << " s ("
      << (wall_s > 0.0 ? bag_duration_s / wall_s : 0.0) << "x real time); CPU time: " << cpu_s
      << " s; peak memory: " << peak_rss_mib << " MiB\n";
  out << "keyframes: " << keyframes << " (" << keyframe_images << " images through the front end, " << rejected_images
      << " rejected); relative-pose messages rejected: " << rejected_messages << "\n";
  if (images_seen > 0) {
    out << "keyframe selection (" << keyframe_selection << "): " << images_seen << " images, " << keyframe_images
        << " keyframes, " << images_skipped << " not keyframes; " << 1e3 * selection_s / images_seen
        << " ms per image\n";
    if (images_missing > 0) {
      out << "  images missing from the bag by their cameras' stamps (lost before recording): " << images_missing
          << "\n";
    }
    if (selection.keyframes > 0) {
      out << "  keyframes made: " << selection.first << " first of their camera, " << selection.by_motion
          << " by motion, " << selection.by_rotation << " by rotation, " << selection.by_tracking
          << " by tracks lost, " << selection.by_interval << " by interval, " << selection.by_rig << " with the rig's other cameras\n";
    }
    if (selection.rotation_checks > 0) {
      out << "  rotation checks (keyframe_min_rotation_deg): " << selection.rotation_checks << ", "
          << 1e3 * selection.rotation_s / selection.rotation_checks << " ms each\n";
    }
  }
  if (image_times.Count() > 0) {
    out << "time per image (decoding, checks, keyframe selection): " << image_times.DescribeMs() << "\n";
  }
  if (keyframe_times.Count() > 0) {
    out << "time per keyframe (front end): " << keyframe_times.DescribeMs() << "; per two-view pair: "
        << pair_times.DescribeMs() << "\n";
  }
  if (keyframe_images > 0) SummariseFrontend(out);
  if (damaged_messages > 0) out << "damaged messages dropped: " << damaged_messages << "\n";
  for (const std::string& camera : camera_models) out << "camera " << camera << "\n";
  for (const std::string& check : focal_checks) out << "camera_info check, last estimate: " << check << "\n";
  if (focal_check_times.Count() > 0) {
    out << "time per camera_info check estimate (one camera's pairs; the node runs it beside the front end): "
        << focal_check_times.DescribeMs() << "\n";
  }
  for (const std::string& c : focal_corrections) out << "focal length corrected (focal_calibration: apply): " << c << "\n";
  for (const std::string& c : lens_corrections) {
    out << "lens given where camera_info describes none (focal_calibration: apply): " << c << "\n";
  }
  for (const std::string& r : focal_loop_refinements) out << "focal length by the loops, last estimate: " << r << "\n";
  if (refinement) {
    const KeyframeRefinerStats& r = refinement_stats;
    out << "refinement (bundle adjustment of the newest keyframes): " << r.runs << " runs, " << r.applied
        << " applied, " << r.failed << " changed nothing; " << r.corrected_keyframes << " keyframes corrected ("
        << r.covariance_keyframes << " with the adjustment's covariance)";
    if (r.applied > 0) {
      out << ", the latest by median " << r.median_correction_deg << " deg, at most " << r.max_correction_deg
          << " deg (" << r.held_back << " held back)";
    }
    out << "; time per refinement: " << r.times.DescribeMs() << "; correspondences held: " << r.edges_held
        << " edges, " << r.bytes / (1024.0 * 1024.0) << " MiB\n";
    if (!r.last_report.empty()) out << "refinement, latest: " << r.last_report << "\n";
    for (const auto& [camera, e] : r.focal) {
      out << "focal length by the refinement, " << camera << ": " << DescribeFocalEstimate(e) << " of the one in use"
          << (r.focal_agreed.count(camera) ? " (agrees: held in the later refinements)" : "") << "\n";
    }
  }
  if (!rig_cameras.empty()) {
    out << "rig cameras (one orientation per capture): ";
    for (std::size_t k = 0; k < rig_cameras.size(); ++k) out << (k ? ", " : "") << rig_cameras[k];
    out << "; measurements within a capture absorbed by the extrinsics: " << absorbed_by_rig << "\n";
  }
  out << "solved variables: " << variables << " (keyframes, or rig captures); edges: " << edges;
  if (!edges_by_source.empty()) {
    out << " (";
    bool first = true;
    for (const auto& [source, n] : edges_by_source) {
      out << (first ? "" : ", ") << source << " " << n;
      first = false;
    }
    out << ")";
  }
  out << "\ncomponents: " << components << "; outlier edges: " << outlier_edges << "; solves: " << solves
      << "; final cost: " << std::setprecision(6) << final_cost << "\n";
  if (have_scores) {
    out << "scores against ground truth:\n" << scores.ToText() << "\n";
    out << posterior.Describe() << "\n";
  }
  SummariseMaps(out);
  out << "outputs:\n  " << orientations_csv << "\n  " << graph_file << "\n  " << output_bag;
  if (!scores_file.empty()) out << "\n  " << scores_file;
  if (!ground_truth_csv.empty()) out << "\n  " << ground_truth_csv;
  if (!posterior_csv.empty()) out << "\n  " << posterior_csv;
  if (!plot_png.empty()) out << "\n  " << plot_png;
  if (!frontend_cost_csv.empty()) out << "\n  " << frontend_cost_csv;
  if (!frontend_cost_png.empty()) out << "\n  " << frontend_cost_png;
  for (const std::string& w : warnings) out << "\nwarning: " << w;
  return out.str();
}

}  // namespace rotation_averaging
