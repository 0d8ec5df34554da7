#include "rotation_averaging/ros/pipeline_config.h"

#include <algorithm>
#include <filesystem>
#include <initializer_list>
#include <limits>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "rotation_averaging/util/option_check.h"

namespace rotation_averaging {
namespace {

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
  // One of the parameters of pipeline_config.h's enumerations.
  template <typename E>
  void ReadOption(const std::string& name, E* field) {
    ReadChoice(name, field, &OptionName<E>, &ParseOption<E>, OptionChoices<E>());
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

// Each choice's value and parameter text, in the order OptionChoices lists them.
template <typename E>
struct OptionTable;
#define ROTAVG_OPTION_TABLE(E, ...)                                         \
  template <>                                                              \
  struct OptionTable<E> {                                                  \
    static constexpr std::pair<E, const char*> kEntries[] = {__VA_ARGS__}; \
  };
ROTAVG_OPTION_TABLE(TfMode, {TfMode::kAllKeyframes, "all_keyframes"}, {TfMode::kLatestPerCamera, "latest_per_camera"},
                    {TfMode::kNone, "none"})
ROTAVG_OPTION_TABLE(ImageTransportMode, {ImageTransportMode::kRaw, "raw"}, {ImageTransportMode::kCompressed, "compressed"})
ROTAVG_OPTION_TABLE(ImageType, {ImageType::kAuto, "auto"}, {ImageType::kRaw, "raw"}, {ImageType::kRectified, "rectified"})
ROTAVG_OPTION_TABLE(KeyframeSelectionMode, {KeyframeSelectionMode::kMotion, "motion"}, {KeyframeSelectionMode::kAll, "all"})
ROTAVG_OPTION_TABLE(FocalCalibrationMode, {FocalCalibrationMode::kWarn, "warn"}, {FocalCalibrationMode::kApply, "apply"},
                    {FocalCalibrationMode::kOff, "off"})
#undef ROTAVG_OPTION_TABLE

}  // namespace

template <typename E>
const char* OptionName(E value) {
  for (const auto& [v, name] : OptionTable<E>::kEntries) {
    if (v == value) return name;
  }
  return "?";
}

template <typename E>
bool ParseOption(const std::string& text, E* value) {
  for (const auto& [v, name] : OptionTable<E>::kEntries) {
    if (text == name) {
      *value = v;
      return true;
    }
  }
  return false;
}

template <typename E>
std::string OptionChoices() {
  std::string choices;
  for (const auto& entry : OptionTable<E>::kEntries) choices += (choices.empty() ? "" : ", ") + std::string(entry.second);
  return choices;
}

#define ROTAVG_OPTION_INSTANCES(E)                               \
  template const char* OptionName<E>(E);                         \
  template bool ParseOption<E>(const std::string&, E*);          \
  template std::string OptionChoices<E>();
ROTAVG_OPTION_INSTANCES(TfMode)
ROTAVG_OPTION_INSTANCES(ImageTransportMode)
ROTAVG_OPTION_INSTANCES(ImageType)
ROTAVG_OPTION_INSTANCES(KeyframeSelectionMode)
ROTAVG_OPTION_INSTANCES(FocalCalibrationMode)
#undef ROTAVG_OPTION_INSTANCES

std::string DefaultVocabularyPath() {
  // The devel space's, where the build trains it; else the install space's,
  // where `make install` copies it. Both paths are set by src/ros/CMakeLists.txt.
  std::error_code ec;
  if (!std::filesystem::exists(ROTAVG_DEFAULT_VOCABULARY, ec) && std::filesystem::exists(ROTAVG_INSTALLED_VOCABULARY, ec)) {
    return ROTAVG_INSTALLED_VOCABULARY;
  }
  return ROTAVG_DEFAULT_VOCABULARY;
}

PipelineConfig::PipelineConfig() {
  // The node's defaults where they differ from the libraries': posterior
  // covariances in ~orientations (an extra output the library leaves off).
  averager.averaging.posterior_covariance_max_views = 20000;
}

bool PipelineConfig::Validate(std::string* error) const {
  std::string averager_error, frontend_error, selection_error, refiner_error;
  return OptionCheck()
      .Require(selection.Validate(&selection_error), selection_error)
      .Above("refinement_period_s", refinement_period_s, 0.0)
      .Require(refiner.Validate(&refiner_error), refiner_error)
      .AtLeast("max_image_queue", static_cast<double>(max_image_queue), 1)
      .AtLeast("image_transport_queue", static_cast<double>(image_transport_queue), 1)
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
  r.ReadOption("tf_mode", &c.tf_mode);
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
  r.Read("posterior_covariance_floor", &o.posterior_covariance_floor);

  r.Read("image_topics", &c.image_topics);
  r.ReadOption("image_transport", &c.image_transport);
  r.ReadOption("image_type", &c.image_type);
  KeyframeFrontendOptions& f = c.frontend;
  r.Read("downsample", &f.features.downsample, {"image_downsample"});
  r.ReadChoice("features", &f.features.type, &FeatureTypeName, &ParseFeatureType, FeatureTypeChoices());
  r.Read("max_features", &f.features.max_features);
  r.Read("rig_stamp_tolerance_s", &f.rig_stamp_tolerance_s, {"rig_stamp_tolerance"});
  c.rig.stamp_tolerance_s = f.rig_stamp_tolerance_s;
  c.selection.rig_stamp_tolerance_s = f.rig_stamp_tolerance_s;
  r.ReadOption("keyframe_selection", &c.keyframe_selection);
  r.Read("keyframe_min_motion_deg", &c.selection.min_motion_deg);
  r.Read("keyframe_min_rotation_deg", &c.selection.min_rotation_deg);
  r.Read("keyframe_min_tracked_fraction", &c.selection.min_tracked_fraction);
  r.Read("keyframe_max_interval_s", &c.selection.max_interval_s);
  r.Read("tracks", &c.selection.tracks);
  r.Read("max_tracks", &c.selection.tracker.max_tracks);
  r.Read("track_min_spacing_px", &c.selection.tracker.min_spacing_px);
  r.Read("track_window_px", &c.selection.tracker.window_px);
  r.Read("track_forward_backward_px", &c.selection.tracker.forward_backward_px);
  r.Read("min_track_matches", &f.min_track_matches);
  f.tracker = c.selection.tracker;
  r.ReadOption("focal_calibration", &c.focal_calibration);
  r.Read("focal_loop_refinement", &c.focal_loop_refinement);
  r.Read("refinement", &c.refinement);
  r.Read("refinement_period_s", &c.refinement_period_s);
  r.Read("refinement_max_keyframes", &c.refiner.max_keyframes);
  r.Read("refinement_max_correction_deg", &c.refiner.max_correction_deg);
  r.Read("refinement_max_iterations", &c.refiner.adjustment.max_iterations);
  r.Read("refinement_niceness", &c.refiner.background_niceness);
  r.Read("refinement_covariances", &c.refiner.covariances);
  r.Read("refinement_jackknife_grid", &c.refiner.adjustment.covariance_cell_grid);
  r.Read("refinement_jackknife_tracks", &c.refiner.adjustment.covariance_track_clusters);
  r.Read("refinement_rig_joint_covariance", &c.refiner.rig_joint_covariance);
  r.Read("refinement_focal", &c.refiner.estimate_focal);
  r.Read("refinement_hold_agreed_focal", &c.refiner.hold_agreed_focal);
  r.Read("refinement_hold_outside", &c.refiner.hold_outside);
  r.Read("refinement_sweep_back", &c.refiner.sweep_back);
  r.Read("refinement_max_correspondence_mib", &c.refiner.max_correspondence_mib);
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
  r.Read("image_transport_queue", &c.image_transport_queue);

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

}  // namespace rotation_averaging
