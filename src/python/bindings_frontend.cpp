// Python bindings of the two-view estimation with its rotation covariance
// and of the bundle adjustment (part of rotation_averaging._core, whose
// module is defined in bindings.cpp).
#include <map>
#include <string>
#include <vector>

#include "python/bindings_common.h"
#include "rotation_averaging/frontend/estimators/bundle_adjustment.h"
#include "rotation_averaging/frontend/estimators/relative_pose.h"
#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/frontend/geometry/camera_model.h"

namespace rotation_averaging_python {
namespace {

// (n, 2) pixel coordinates.
std::vector<Eigen::Vector2d> PointsFromArray(const Array& a, const char* what) {
  if (a.ndim() != 2 || a.shape(1) != 2) throw py::value_error(std::string(what) + " must have shape (n, 2) (pixels)");
  std::vector<Eigen::Vector2d> points(static_cast<std::size_t>(a.shape(0)));
  auto r = a.unchecked<2>();
  for (py::ssize_t k = 0; k < a.shape(0); ++k) points[k] = Eigen::Vector2d(r(k, 0), r(k, 1));
  return points;
}

// Input that cannot be a pair of views is a ValueError, as everywhere in the
// bindings; a pair without a pose (too few inliers, no parallax, ...) is a
// result with success False and the reason.
ra::RelativePoseResult RelativePose(const Array& points1, const Array& points2, const py::handle& k1_object,
                                    const py::handle& k2_object, const ra::RelativePoseOptions& options) {
  const std::vector<Eigen::Vector2d> p1 = PointsFromArray(points1, "points1"), p2 = PointsFromArray(points2, "points2");
  const Eigen::Matrix3d k1 = ToMatrix3(k1_object, "K1");
  const Eigen::Matrix3d k2 = k2_object.is_none() ? k1 : ToMatrix3(k2_object, "K2");
  ra::RelativePoseResult result;
  {
    py::gil_scoped_release release;
    result = ra::EstimateRelativePoseWithCovariance(p1, p2, k1, k2, options);
  }
  if (result.failure == ra::TwoViewFailure::kInvalidInput) throw py::value_error(result.message);
  return result;
}

// {view id: numpy array} of a map from view ids to Eigen values.
template <typename Map>
py::dict IdDict(const Map& values) {
  py::dict d;
  for (const auto& [id, value] : values) d[py::int_(id)] = Array(py::cast(value));
  return d;
}

// The result of a bundle adjustment: orientations and centres per view id.
struct BundleAdjustment {
  ra::ViewOrientations orientations;
  std::unordered_map<ra::ViewId, Eigen::Vector3d> centres;
  ra::BundleAdjustmentSummary summary;
  bool success = false;
};

// The pairs as the adjustment takes them: each pair's inliers in normalised
// coordinates of its views' intrinsics, its translation and pixel noise.
BundleAdjustment BundleAdjust(const py::dict& initial, const py::list& pairs, const py::object& intrinsics,
                              const ra::BundleAdjustmentOptions& options) {
  BundleAdjustment out;
  for (const auto& [key, value] : initial) {
    const ra::ViewId id = py::cast<ra::ViewId>(key);
    out.orientations[id] = ToMatrix3(value, "orientations[" + std::to_string(id) + "]");
    if (!ra::IsRotationMatrix(out.orientations[id], 1e-6)) {
      throw py::value_error("orientations[" + std::to_string(id) + "] is not a rotation matrix");
    }
  }
  // One K for every view, or {view id: K}.
  std::map<ra::ViewId, Eigen::Matrix3d> per_view;
  Eigen::Matrix3d shared = Eigen::Matrix3d::Identity();
  const bool is_dict = py::isinstance<py::dict>(intrinsics);
  if (is_dict) {
    for (const auto& [key, value] : py::cast<py::dict>(intrinsics)) {
      const ra::ViewId id = py::cast<ra::ViewId>(key);
      per_view[id] = ToMatrix3(value, "intrinsics[" + std::to_string(id) + "]");
    }
  } else {
    shared = ToMatrix3(intrinsics, "intrinsics");
  }
  const auto k_of = [&](ra::ViewId id) -> Eigen::Matrix3d {
    if (!is_dict) return shared;
    auto it = per_view.find(id);
    if (it == per_view.end()) throw py::value_error("no intrinsics for view " + std::to_string(id));
    return it->second;
  };
  std::vector<ra::EdgeCorrespondences> edges;
  for (std::size_t k = 0; k < pairs.size(); ++k) {
    const py::tuple pair = py::cast<py::tuple>(pairs[k]);
    const std::string where = "pairs[" + std::to_string(k) + "]";
    if (pair.size() != 5) throw py::value_error(where + " must be (view1, view2, points1, points2, pose)");
    const auto view1 = py::cast<ra::ViewId>(pair[0]);
    const auto view2 = py::cast<ra::ViewId>(pair[1]);
    const std::vector<Eigen::Vector2d> p1 = PointsFromArray(py::cast<Array>(pair[2]), "points1");
    const std::vector<Eigen::Vector2d> p2 = PointsFromArray(py::cast<Array>(pair[3]), "points2");
    const auto& pose = py::cast<const ra::RelativePoseResult&>(pair[4]);
    if (!pose.success) throw py::value_error(where + ": the pair has no pose (" + pose.message + ")");
    if (p1.size() != p2.size()) throw py::value_error(where + ": points1 and points2 differ in length");
    const Eigen::Matrix3d k1 = k_of(view1), k2 = k_of(view2);
    if (!ra::IsCameraIntrinsics(k1) || !ra::IsCameraIntrinsics(k2)) {
      throw py::value_error(where + ": intrinsics that are not a camera (" + ra::kCameraIntrinsicsRule + ")");
    }
    for (int i : pose.inliers) {
      if (i < 0 || static_cast<std::size_t>(i) >= p1.size()) {
        throw py::value_error(where + ": the pose's inlier " + std::to_string(i) + " is beyond the " +
                              std::to_string(p1.size()) + " points given (pass the points the pose was estimated from)");
      }
    }
    // Pixels over the pair's mean focal length.
    const double focal = 0.25 * (k1(0, 0) + k1(1, 1) + k2(0, 0) + k2(1, 1));
    edges.push_back(ra::MakeEdgeCorrespondences(view1, view2, ra::NormalisedPoints(p1, k1, pose.inliers),
                                                ra::NormalisedPoints(p2, k2, pose.inliers), pose.translation,
                                                pose.sigma_px, focal));
  }
  {
    py::gil_scoped_release release;
    out.success = ra::RefineRotationsWithBundleAdjustment(edges, options, &out.orientations, &out.summary, &out.centres);
  }
  return out;
}

// The two-view estimation with its rotation covariance.
void BindRelativePose(py::module_& m) {
  py::class_<ra::RelativePoseOptions> pose_options(
      m, "RelativePoseOptions", "Every option of the two-view estimation (relative_pose.h); enumerations as strings.");
  DefaultConstructibleCopyable(pose_options);
  EnumProperty(pose_options, "covariance_model", &ra::RelativePoseOptions::covariance_model,
               &ra::RotationCovarianceModelName, &ra::ParseRotationCovarianceModel,
               ra::RotationCovarianceModelChoices());
#define ROTAVG_FIELD(name) pose_options.def_readwrite(#name, &ra::RelativePoseOptions::name)
  ROTAVG_FIELD(ransac_threshold_px);
  ROTAVG_FIELD(adaptive_threshold_sigmas);
  ROTAVG_FIELD(min_adaptive_threshold_px);
  ROTAVG_FIELD(ransac_confidence);
  ROTAVG_FIELD(ransac_max_iterations);
  ROTAVG_FIELD(min_inliers);
  ROTAVG_FIELD(min_median_parallax_deg);
  ROTAVG_FIELD(max_homography_inlier_ratio);
  ROTAVG_FIELD(near_planar_report_ratio);
  ROTAVG_FIELD(refine_max_iterations);
  ROTAVG_FIELD(max_condition_number);
  ROTAVG_FIELD(rotation_model);
  ROTAVG_FIELD(jackknife_grid);
#undef ROTAVG_FIELD
  pose_options.def("validate", &ValidateOrThrow<ra::RelativePoseOptions>,
                   "Raises ValueError naming the first field out of its range (relative_pose() checks it too).");

  py::class_<ra::RelativePoseResult>(m, "RelativePose", R"(A two-view relative pose and the covariance of its rotation.

rotation maps camera-1 to camera-2 coordinates (x2 = R x1 + t, R = R_2 R_1^T for
world-to-camera R_i); edge_rotation is the view-graph edge R_12 = rotation^T,
and covariance (rad^2) is that of the edge's right perturbation, as
ViewGraph.add_edge takes it.)")
      .def_readonly("success", &ra::RelativePoseResult::success)
      .def_property_readonly("failure",
                             [](const ra::RelativePoseResult& p) { return std::string(ra::TwoViewFailureName(p.failure)); },
                             "'none', or why the pair has no pose (too_few_matches, too_few_inliers, pure_rotation, ...)")
      .def_readonly("message", &ra::RelativePoseResult::message)
      .def_property_readonly("model", [](const ra::RelativePoseResult& p) { return std::string(ra::TwoViewModelName(p.model)); },
                             "'essential' (general motion) or 'rotation' (the camera turned in place: no translation)")
      .def_readonly("rotation", &ra::RelativePoseResult::rotation, "R_21, 3x3")
      .def_readonly("translation", &ra::RelativePoseResult::translation, "unit t_21; zero for the rotation model")
      .def_property_readonly("edge_rotation", &ra::RelativePoseResult::EdgeRotation, "R_12 = rotation^T")
      .def_readonly("covariance", &ra::RelativePoseResult::covariance,
                    "rad^2, per options.covariance_model (default: marginal over the translation)")
      .def_readonly("covariance_marginal", &ra::RelativePoseResult::covariance_marginal)
      .def_readonly("covariance_conditional", &ra::RelativePoseResult::covariance_conditional)
      .def_readonly("covariance_marginal_pixel", &ra::RelativePoseResult::covariance_marginal_pixel)
      .def_readonly("covariance_paper", &ra::RelativePoseResult::covariance_paper,
                    "(J_w^T J_w)^-1 unscaled (1/px^2), as the paper's code gives it")
      .def_readonly("sigma_px", &ra::RelativePoseResult::sigma_px, "pixel noise measured from the inliers' residuals")
      .def_readonly("median_parallax_deg", &ra::RelativePoseResult::median_parallax_deg)
      .def_readonly("homography_inlier_ratio", &ra::RelativePoseResult::homography_inlier_ratio)
      .def_property_readonly("inliers",
                             [](const ra::RelativePoseResult& p) {
                               return py::array_t<int>(static_cast<py::ssize_t>(p.inliers.size()), p.inliers.data());
                             }, "indices into the points")
      .def_readonly("ransac_threshold_px", &ra::RelativePoseResult::ransac_threshold_px)
      .def_readonly("refine_iterations", &ra::RelativePoseResult::refine_iterations)
      .def_readonly("gric_essential", &ra::RelativePoseResult::gric_essential)
      .def_readonly("gric_rotation", &ra::RelativePoseResult::gric_rotation)
      .def("__repr__", [](const ra::RelativePoseResult& p) {
        std::ostringstream out;
        if (p.success) {
          out << "<RelativePose " << ra::TwoViewModelName(p.model) << ", " << p.inliers.size() << " inliers, "
              << ra::LogSO3(p.rotation).norm() * 180.0 / M_PI << " deg, sigma " << p.sigma_px << " px>";
        } else {
          out << "<RelativePose failed: " << ra::TwoViewFailureName(p.failure) << " (" << p.message << ")>";
        }
        return out.str();
      });

  m.def("relative_pose", &RelativePose, py::arg("points1"), py::arg("points2"), py::arg("K1"), py::arg("K2") = py::none(),
        py::arg("options") = ra::RelativePoseOptions(),
        "Relative pose of two views from corresponding pixels (n, 2) of undistorted images with intrinsics K1, K2 "
        "(K2 defaults to K1), with the covariance of its rotation. Releases the GIL.");
}

void BindBundleAdjustment(py::module_& m) {
  py::class_<ra::BundleAdjustmentOptions> ba_options(m, "BundleAdjustmentOptions",
                                                     "Every option of the bundle adjustment (bundle_adjustment.h).");
  DefaultConstructibleCopyable(ba_options);
#define ROTAVG_FIELD(name) ba_options.def_readwrite(#name, &ra::BundleAdjustmentOptions::name)
  ROTAVG_FIELD(loss_scale_sigmas);
  ROTAVG_FIELD(outlier_sigmas);
  ROTAVG_FIELD(min_track_views);
  ROTAVG_FIELD(min_parallax_deg);
  ROTAVG_FIELD(max_iterations);
  ROTAVG_FIELD(min_correspondences);
#undef ROTAVG_FIELD

  py::class_<BundleAdjustment>(m, "BundleAdjustment", "Adjusted orientations and camera centres, and the summary.")
      .def_readonly("success", &BundleAdjustment::success,
                    "False if nothing could be adjusted or a solve failed (orientations are then the given ones)")
      .def_property_readonly("orientations", [](const BundleAdjustment& b) { return IdDict(b.orientations); },
                             "{id: 3x3} world-to-camera, every view given (adjusted where the tracks reach it)")
      .def_property_readonly("centres", [](const BundleAdjustment& b) { return IdDict(b.centres); },
                             "{id: (3,)} adjusted camera centres, up to one scale per group of connected views")
      .def_property_readonly("summary",
                             [](const BundleAdjustment& b) {
                               const ra::BundleAdjustmentSummary& s = b.summary;
                               py::dict d;
                               d["views"] = s.views;
                               d["edges_used"] = s.edges_used;
                               d["edges_rotation_only"] = s.edges_rotation_only;
                               d["edges_skipped"] = s.edges_skipped;
                               d["tracks"] = s.tracks;
                               d["tracks_inconsistent"] = s.tracks_inconsistent;
                               d["tracks_short"] = s.tracks_short;
                               d["tracks_unconstrained"] = s.tracks_unconstrained;
                               d["observations"] = s.observations;
                               d["observations_dropped"] = s.observations_dropped;
                               d["initial_rms_sigmas"] = s.initial_rms_sigmas;
                               d["final_rms_sigmas"] = s.final_rms_sigmas;
                               d["iterations"] = s.iterations;
                               d["failed_steps"] = s.failed_steps;
                               d["time_s"] = s.time_s;
                               d["converged"] = s.converged;
                               d["status"] = s.status;
                               return d;
                             })
      .def("report", [](const BundleAdjustment& b) { return b.summary.Report(); }, "The summary as rotavg images prints it")
      .def("named",
           [](const BundleAdjustment& b, const py::dict& names) {
             py::dict d;
             for (const auto& [id, r] : b.orientations) {
               const py::int_ key(id);
               d[names.contains(key) ? py::str(names[key]) : py::str(std::to_string(id))] = Array(py::cast(r));
             }
             return d;
           },
           py::arg("names") = py::dict(), "{view name: 3x3} for evaluate(); names: {id: name}, default the id")
      .def("__repr__", [](const BundleAdjustment& b) { return "<BundleAdjustment " + b.summary.Report() + ">"; });

  m.def("bundle_adjust", &BundleAdjust, py::arg("orientations"), py::arg("pairs"), py::arg("intrinsics"),
        py::arg("options") = ra::BundleAdjustmentOptions(),
        "Bundle adjustment from averaged orientations ({id: 3x3}) on the pairs' inlier correspondences: "
        "pairs are (view1, view2, points1, points2, pose), pose = relative_pose(points1, points2, ...); "
        "a keypoint is its pixel coordinates in its view, so give each view's keypoints the same coordinates in "
        "every pair. intrinsics: one 3x3 K, or {id: K}. Releases the GIL.");
}

}  // namespace

void BindFrontend(py::module_& m) {
  BindRelativePose(m);
  BindBundleAdjustment(m);
}

}  // namespace rotation_averaging_python
