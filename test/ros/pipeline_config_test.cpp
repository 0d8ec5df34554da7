// The node's parameters (ReadPipelineConfig): every one under the name of the
// field it sets, former names with a deprecation warning, values out of range
// refused with the parameter's name, and config/rotation_averaging.yaml
// listing exactly the parameters the node reads, each at its default.
#include "rotation_averaging/ros/keyframe_pipeline.h"

#include <gtest/gtest.h>

#include <cstdlib>
#include <fstream>
#include <map>
#include <regex>
#include <set>
#include <sstream>

namespace rotation_averaging {
namespace {

// Serves the given values (as text, parsed to the type asked for) and
// records every name asked for, with the default the reader held for it.
class TextParameters : public ParameterSource {
 public:
  explicit TextParameters(std::map<std::string, std::string> values = {}) : values_(std::move(values)) {}
  bool Get(const std::string& name, std::string* v) const override { return Serve(name, *v, v); }
  bool Get(const std::string& name, double* v) const override { return Serve(name, Text(*v), v); }
  bool Get(const std::string& name, int* v) const override { return Serve(name, std::to_string(*v), v); }
  bool Get(const std::string& name, bool* v) const override { return Serve(name, *v ? "true" : "false", v); }
  bool Get(const std::string& name, std::vector<std::string>* v) const override {
    defaults_[name] = v->empty() ? "[]" : "[...]";
    if (!values_.count(name)) return false;
    v->clear();
    return true;
  }
  const std::map<std::string, std::string>& Defaults() const { return defaults_; }

 private:
  static std::string Text(double v) {
    std::ostringstream s;
    s << v;
    return s.str();
  }
  template <typename T>
  bool Serve(const std::string& name, const std::string& default_text, T* value) const {
    defaults_[name] = default_text;
    auto it = values_.find(name);
    if (it == values_.end()) return false;
    if constexpr (std::is_same_v<T, std::string>) {
      *value = it->second;
    } else if constexpr (std::is_same_v<T, bool>) {
      *value = it->second == "true";
    } else if constexpr (std::is_same_v<T, double>) {
      *value = std::strtod(it->second.c_str(), nullptr);  // "nan" and "inf" too, as YAML's .nan and .inf
    } else {
      std::istringstream(it->second) >> *value;
    }
    return true;
  }
  std::map<std::string, std::string> values_;
  mutable std::map<std::string, std::string> defaults_;
};

bool Read(const std::map<std::string, std::string>& values, PipelineConfig* config, std::vector<std::string>* warnings,
          std::string* error) {
  return ReadPipelineConfig(TextParameters(values), config, warnings, error);
}

TEST(PipelineConfig, DefaultsValidateAndParametersSetTheFieldsOfTheirName) {
  PipelineConfig defaults;
  std::string error;
  ASSERT_TRUE(defaults.Validate(&error)) << error;
  PipelineConfig c;
  std::vector<std::string> warnings;
  ASSERT_TRUE(Read({{"loss_scale", "2.5"}, {"solve_period_s", "0.25"}, {"local_solve_min_views", "50"},
                    {"posterior_covariance_max_views", "7"}, {"jackknife_grid", "3"}, {"loss", "cauchy"},
                    {"marker_spacing_m", "2"}, {"keyframe_selection", "all"}, {"keyframe_min_motion_deg", "7"},
                    {"keyframe_min_tracked_fraction", "0.3"}, {"keyframe_max_interval_s", "2"},
                    {"rig_stamp_tolerance_s", "0.01"}, {"image_type", "rectified"}, {"focal_calibration", "off"},
                    {"refinement", "false"}, {"refinement_period_s", "3"}, {"refinement_max_keyframes", "50"},
                    {"refinement_max_iterations", "7"}, {"refinement_max_correction_deg", "0.5"},
                    {"refinement_niceness", "5"}, {"image_transport_queue", "12"},
                    {"refinement_covariances", "false"}, {"refinement_jackknife_grid", "2"},
                    {"refinement_jackknife_tracks", "false"}, {"refinement_focal", "false"},
                    {"refinement_rig_joint_covariance", "true"}, {"refinement_hold_agreed_focal", "false"},
                    {"refinement_hold_outside", "false"}, {"refinement_sweep_back", "false"},
                    {"refinement_max_correspondence_mib", "32"}},
                   &c, &warnings, &error))
      << error;
  EXPECT_TRUE(warnings.empty());
  EXPECT_EQ(c.averager.averaging.loss_scale, 2.5);
  EXPECT_EQ(c.averager.solve_period_s, 0.25);
  EXPECT_EQ(c.averager.local_solve_min_views, 50u);
  EXPECT_EQ(c.averager.averaging.posterior_covariance_max_views, 7);
  EXPECT_EQ(c.frontend.relative_pose.jackknife_grid, 3);
  EXPECT_EQ(c.averager.averaging.loss, LossType::kCauchy);
  EXPECT_EQ(c.marker_spacing_m, 2.0);
  EXPECT_EQ(c.keyframe_selection, KeyframeSelectionMode::kAll);
  EXPECT_EQ(c.selection.min_motion_deg, 7.0);
  EXPECT_EQ(c.selection.min_tracked_fraction, 0.3);
  EXPECT_EQ(c.selection.max_interval_s, 2.0);
  // One rig tolerance for the front end, the rig model and keyframe selection.
  EXPECT_EQ(c.selection.rig_stamp_tolerance_s, 0.01);
  EXPECT_EQ(c.frontend.rig_stamp_tolerance_s, 0.01);
  EXPECT_EQ(c.image_type, ImageType::kRectified);
  EXPECT_EQ(c.focal_calibration, FocalCalibrationMode::kOff);
  EXPECT_FALSE(c.refinement);
  EXPECT_EQ(c.refinement_period_s, 3.0);
  EXPECT_EQ(c.refiner.max_keyframes, 50);
  EXPECT_EQ(c.refiner.adjustment.max_iterations, 7);
  EXPECT_EQ(c.refiner.max_correction_deg, 0.5);
  EXPECT_EQ(c.refiner.background_niceness, 5);
  EXPECT_FALSE(c.refiner.covariances);
  EXPECT_FALSE(c.refiner.estimate_focal);
  EXPECT_FALSE(c.refiner.hold_agreed_focal);
  EXPECT_FALSE(c.refiner.hold_outside);
  EXPECT_FALSE(c.refiner.sweep_back);
  EXPECT_EQ(c.refiner.max_correspondence_mib, 32.0);
  EXPECT_EQ(c.refiner.adjustment.covariance_cell_grid, 2);
  EXPECT_FALSE(c.refiner.adjustment.covariance_track_clusters);
  EXPECT_TRUE(c.refiner.rig_joint_covariance);
  EXPECT_EQ(c.image_transport_queue, 12u);
}

TEST(PipelineConfig, FormerNamesAreReadWithADeprecationWarning) {
  PipelineConfig c;
  std::vector<std::string> warnings;
  std::string error;
  ASSERT_TRUE(Read({{"sigma_max", "4"}, {"covariance_max_keyframes", "0"}}, &c, &warnings, &error)) << error;
  EXPECT_EQ(c.averager.averaging.loss_scale, 4.0);
  EXPECT_EQ(c.averager.averaging.posterior_covariance_max_views, 0);
  ASSERT_EQ(warnings.size(), 2u);
  EXPECT_NE(warnings[0].find("'sigma_max' is deprecated: use 'loss_scale'"), std::string::npos) << warnings[0];
  // The new name wins over the old one.
  PipelineConfig both;
  ASSERT_TRUE(Read({{"sigma_max", "4"}, {"loss_scale", "2"}}, &both, nullptr, &error));
  EXPECT_EQ(both.averager.averaging.loss_scale, 2.0);
}

TEST(PipelineConfig, ValuesOutOfRangeAndUnknownChoicesAreRefusedByName) {
  const std::vector<std::pair<std::map<std::string, std::string>, std::string>> cases = {
      {{{"max_iterations", "-1"}}, "max_iterations must be at least 0 (got -1)"},
      {{{"loss_scale", "nan"}}, "loss_scale must be finite"},
      {{{"covisibility_window", "0"}}, "covisibility_window must be at least 1"},
      {{{"jackknife_grid", "17"}}, "jackknife_grid must be in [0, 16]"},
      {{{"downsample", "2"}}, "downsample must be in"},
      {{{"max_queue", "-3"}}, "max_queue must be at least 0 (got -3)"},
      {{{"max_queue", "0"}}, "max_queue must be at least 1"},
      {{{"local_solve_hops", "0"}}, "local_solve_hops must be at least 1"},
      {{{"min_loop_inliers", "2"}}, "min_loop_inliers must be at least 5"},
      {{{"loss", "l3"}}, "loss 'l3' is not one of"},
      {{{"features", "surf"}}, "features 'surf' is not one of sift, orb"},
      {{{"tf_mode", "some"}}, "tf_mode 'some' is not one of"},
      {{{"marker_spacing_m", "0"}}, "marker_spacing_m must be above 0"},
      {{{"keyframe_selection", "every"}}, "keyframe_selection 'every' is not one of motion, all"},
      {{{"focal_calibration", "on"}}, "focal_calibration 'on' is not one of warn, apply, off"},
      {{{"keyframe_min_tracked_fraction", "2"}}, "keyframe_min_tracked_fraction must be in [0, 1]"},
      {{{"keyframe_max_interval_s", "-1"}}, "keyframe_max_interval_s must be at least 0"},
      {{{"image_type", "rect"}}, "image_type 'rect' is not one of auto, raw, rectified"},
      {{{"refinement_period_s", "0"}}, "refinement_period_s must be above 0"},
      {{{"refinement_max_keyframes", "1"}}, "refinement_max_keyframes must be at least 3"},
      {{{"refinement_max_iterations", "0"}}, "refinement_max_iterations must be at least 1"},
      {{{"refinement_max_correction_deg", "nan"}}, "refinement_max_correction_deg must be above 0"},
      {{{"refinement_niceness", "20"}}, "refinement_niceness must be in [0, 19]"},
      {{{"refinement_max_correspondence_mib", "0"}}, "refinement_max_correspondence_mib must be above 0"},
      {{{"refinement_jackknife_grid", "17"}}, "refinement_jackknife_grid must be in [0, 16]"},
      {{{"image_transport_queue", "0"}}, "image_transport_queue must be at least 1"},
  };
  for (const auto& [values, expected] : cases) {
    PipelineConfig c;
    std::string error;
    EXPECT_FALSE(Read(values, &c, nullptr, &error)) << values.begin()->first;
    EXPECT_NE(error.find(expected), std::string::npos) << "'" << error << "' does not say '" << expected << "'";
    EXPECT_EQ(error.rfind("parameter ", 0), 0u) << error;
  }
}

// config/rotation_averaging.yaml is the node's parameter reference: it lists
// every parameter the node reads, under its current name, at its default.
TEST(PipelineConfig, ParameterFileListsEveryParameterAtItsDefault) {
  std::ifstream file(ROTAVG_SOURCE_DIR "/config/rotation_averaging.yaml");
  ASSERT_TRUE(file.good());
  std::map<std::string, std::string> listed;
  const std::regex entry(R"(^([a-z_0-9]+):\s*(\[[^\]]*\]|"[^"]*"|[^\s#]+))");
  std::string line;
  while (std::getline(file, line)) {
    std::smatch m;
    if (std::regex_search(line, m, entry)) listed[m[1]] = m[2];
  }
  TextParameters recorder;
  PipelineConfig c;
  std::string error;
  ASSERT_TRUE(ReadPipelineConfig(recorder, &c, nullptr, &error)) << error;
  // Former names are asked for only when the current one is absent: the
  // current names are the first asked for each field, which are the keys of
  // the defaults the recorder saw minus the deprecated ones.
  std::map<std::string, std::string> read;
  for (const auto& [name, value] : recorder.Defaults()) {
    static const std::set<std::string> former = {
        "marker_spacing", "solve_period", "sigma_max", "local_solve_min_keyframes", "local_solve_max_keyframes",
        "covariance_max_keyframes", "image_downsample", "rig_stamp_tolerance", "covariance_jackknife_grid",
        "loop_covariance_jackknife_grid", "match_by_vocabulary", "autosave_period"};
    if (!former.count(name)) read[name] = value;
  }
  for (const auto& [name, value] : read) {
    ASSERT_TRUE(listed.count(name)) << name << " is read but not in config/rotation_averaging.yaml";
    std::string text = listed[name];
    if (text.size() >= 2 && text.front() == '"') text = text.substr(1, text.size() - 2);
    const bool numeric = !value.empty() && (std::isdigit(value[0]) || value[0] == '-');
    if (numeric) {
      EXPECT_DOUBLE_EQ(std::stod(text), std::stod(value)) << name << ": the file says " << text;
    } else {
      EXPECT_EQ(text, value) << name;
    }
  }
  for (const auto& [name, value] : listed) {
    EXPECT_TRUE(read.count(name)) << name << " is in config/rotation_averaging.yaml but the node does not read it";
  }
}

}  // namespace
}  // namespace rotation_averaging
