// Python bindings of the core library (here), the two-view estimation with its
// rotation covariance and the bundle adjustment (bindings_frontend.cpp) (module
// rotation_averaging._core; the package rotation_averaging re-exports it with a few conveniences, see
// python/rotation_averaging/__init__.py). numpy arrays in, numpy arrays out;
// errors are Python exceptions carrying the C++ message. Solves, two-view
// estimations and adjustments release the GIL.
#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <map>
#include <sstream>
#include <string>
#include <unordered_map>
#include <vector>

#include "rotation_averaging/core/estimators/rotation_averaging.h"
#include "rotation_averaging/core/eval/rotation_evaluation.h"
#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/core/io/graph_io.h"
#include "rotation_averaging/core/io/orientation_io.h"
#include "rotation_averaging/core/scene/synthetic_graph.h"

#include "python/bindings_common.h"
#include "rotation_averaging/frontend/estimators/relative_pose.h"  // ViewGraph.add_relative_pose

namespace {

using namespace rotation_averaging_python;  // NOLINT: the helpers every binding uses
using IdArray = py::array_t<std::uint64_t, py::array::c_style | py::array::forcecast>;

// A view graph plus what reading or building it skipped.
struct PyViewGraph {
  ra::ViewGraph graph;
  std::vector<std::string> warnings;
};

[[noreturn]] void ThrowReadError(const std::string& message) {
  if (message.rfind("cannot open ", 0) == 0) {
    PyErr_SetString(PyExc_FileNotFoundError, message.c_str());
    throw py::error_already_set();
  }
  throw py::value_error(message);
}

// Rotations given as (m, 3, 3) matrices or (m, 4) quaternions (w, x, y, z).
std::vector<Eigen::Matrix3d> RotationsFromArray(const Array& a, py::ssize_t m, const char* what) {
  std::vector<Eigen::Matrix3d> out(m);
  if (a.ndim() == 3 && a.shape(0) == m && a.shape(1) == 3 && a.shape(2) == 3) {
    auto r = a.unchecked<3>();
    for (py::ssize_t k = 0; k < m; ++k)
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) out[k](i, j) = r(k, i, j);
  } else if (a.ndim() == 2 && a.shape(0) == m && a.shape(1) == 4) {
    auto q = a.unchecked<2>();
    for (py::ssize_t k = 0; k < m; ++k) {
      const Eigen::Vector4d v(q(k, 0), q(k, 1), q(k, 2), q(k, 3));
      if (!v.allFinite() || std::abs(v.norm() - 1.0) > 1e-3) {
        // Left to the graph's validation as a non-rotation.
        out[k].setConstant(std::numeric_limits<double>::quiet_NaN());
      } else {
        out[k] = ra::QuaternionToRotation(v[0], v[1], v[2], v[3]);
      }
    }
  } else {
    throw py::value_error(std::string(what) + " must have shape (" + std::to_string(m) + ", 3, 3) or (" +
                          std::to_string(m) + ", 4) (quaternions w, x, y, z)");
  }
  return out;
}

Array MatricesToArray(const std::vector<Eigen::Matrix3d>& matrices) {
  Array out({static_cast<py::ssize_t>(matrices.size()), py::ssize_t{3}, py::ssize_t{3}});
  auto r = out.mutable_unchecked<3>();
  for (std::size_t k = 0; k < matrices.size(); ++k)
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) r(k, i, j) = matrices[k](i, j);
  return out;
}

py::dict NamedToDict(const ra::NamedOrientations& named) {
  py::dict d;
  for (const auto& [name, r] : named) d[py::str(name)] = Array(py::cast(r));
  return d;
}

ra::NamedOrientations DictToNamed(const py::dict& d, const std::string& what) {
  ra::NamedOrientations named;
  for (const auto& [key, value] : d) named[py::str(key)] = ToMatrix3(value, what + "[" + std::string(py::str(key)) + "]");
  return named;
}

ra::EdgeSource SourceFromText(const std::string& text) {
  ra::EdgeSource source;
  if (!ra::ParseEdgeSource(text, &source)) {
    throw py::value_error("unknown edge source '" + text + "' (rig, sequential, loop_closure, other)");
  }
  return source;
}

void AddEdgeOrThrow(PyViewGraph* g, ra::ViewId i, ra::ViewId j, const Eigen::Matrix3d& rotation,
                    const py::object& covariance, int inliers, const std::string& source, std::uint32_t channel) {
  ra::RelativeRotation e;
  e.view1 = i;
  e.view2 = j;
  e.rotation = rotation;
  if (!covariance.is_none()) {
    e.has_covariance = true;
    e.covariance = ToMatrix3(covariance, "covariance");
  }
  e.num_inliers = inliers;
  e.source = SourceFromText(source);
  e.channel = channel;
  std::string why;
  if (g->graph.AddEdge(e, &why, ra::DuplicatePolicy::kKeepBoth) == ra::AddEdgeResult::kRejected) {
    throw py::value_error("edge " + std::to_string(i) + "-" + std::to_string(j) + " rejected: " + why);
  }
}

// Builds a graph from arrays; views are created as edges name them (or from
// `ids`/`names`). Edges the graph rejects are skipped and listed in warnings.
PyViewGraph FromArrays(const IdArray& view1, const IdArray& view2, const Array& rotations, const py::object& covariances,
                       const py::object& inliers, const py::object& ids, const py::object& names) {
  if (view1.ndim() != 1 || view2.ndim() != 1 || view1.shape(0) != view2.shape(0)) {
    throw py::value_error("view1 and view2 must be 1-D arrays of the same length");
  }
  const py::ssize_t m = view1.shape(0);
  const std::vector<Eigen::Matrix3d> r = RotationsFromArray(rotations, m, "rotations");
  std::vector<Eigen::Matrix3d> c;
  if (!covariances.is_none()) {
    const Array a = py::cast<Array>(covariances);
    if (a.ndim() != 3 || a.shape(0) != m || a.shape(1) != 3 || a.shape(2) != 3) {
      throw py::value_error("covariances must have shape (" + std::to_string(m) + ", 3, 3)");
    }
    c = RotationsFromArray(a, m, "covariances");
  }
  std::vector<int> n;
  if (!inliers.is_none()) {
    const auto a = py::cast<py::array_t<int, py::array::c_style | py::array::forcecast>>(inliers);
    if (a.ndim() != 1 || a.shape(0) != m) throw py::value_error("inliers must have shape (" + std::to_string(m) + ",)");
    n.assign(a.data(), a.data() + m);
  }
  PyViewGraph g;
  if (!ids.is_none()) {
    const IdArray a = py::cast<IdArray>(ids);
    std::vector<std::string> view_names;
    if (!names.is_none()) view_names = py::cast<std::vector<std::string>>(names);
    if (a.ndim() != 1 || (!view_names.empty() && view_names.size() != static_cast<std::size_t>(a.shape(0)))) {
      throw py::value_error("ids must be 1-D, and names (if given) as long");
    }
    for (py::ssize_t k = 0; k < a.shape(0); ++k) {
      if (!g.graph.AddView(a.at(k), view_names.empty() ? "" : view_names[k])) {
        throw py::value_error("view id " + std::to_string(a.at(k)) + " given twice");
      }
    }
  } else if (!names.is_none()) {
    throw py::value_error("names need ids");
  }
  auto v1 = view1.unchecked<1>();
  auto v2 = view2.unchecked<1>();
  for (py::ssize_t k = 0; k < m; ++k) {
    if (ids.is_none()) {
      g.graph.AddView(v1(k));
      g.graph.AddView(v2(k));
    }
    ra::RelativeRotation e;
    e.view1 = v1(k);
    e.view2 = v2(k);
    e.rotation = r[k];
    if (!c.empty()) {
      e.has_covariance = true;
      e.covariance = c[k];
    }
    if (!n.empty()) e.num_inliers = n[k];
    std::string why;
    if (g.graph.AddEdge(e, &why, ra::DuplicatePolicy::kKeepBoth) == ra::AddEdgeResult::kRejected) {
      g.warnings.push_back("edge " + std::to_string(k) + " (" + std::to_string(e.view1) + "-" +
                           std::to_string(e.view2) + ") skipped: " + why);
    }
  }
  return g;
}

py::dict ComponentToDict(const ra::ComponentSummary& c) {
  py::dict d;
  d["num_views"] = c.num_views;
  d["num_edges"] = c.num_edges;
  d["gauge_view"] = c.gauge_view;
  d["iterations"] = c.iterations;
  d["factorizations"] = c.factorizations;
  d["preconditioned_solves"] = c.preconditioned_solves;
  d["multigrid_solves"] = c.multigrid_solves;
  d["extrapolations"] = c.extrapolations;
  d["loss_scale"] = c.loss_scale;
  d["noise_scale"] = c.noise_scale;
  d["covariance_floor_rad"] = c.covariance_floor_rad;
  d["initial_cost"] = c.initial_cost;
  d["final_cost"] = c.final_cost;
  d["refined_start"] = c.refined_start;
  d["converged"] = c.converged;
  d["status"] = c.status;
  return d;
}

// The result of a solve, as numpy arrays in the order of the graph's views and edges.
struct Solution {
  std::vector<ra::ViewId> ids;
  std::vector<std::string> names;
  std::vector<Eigen::Matrix3d> rotations;
  ra::RotationAveragingSummary summary;
  bool success = false;
};

Solution Solve(const PyViewGraph& g, const ra::RotationAveragingOptions& options, const py::object& initial) {
  ValidateOrThrow(options);
  ra::ViewOrientations orientations;
  if (!initial.is_none()) {
    for (const auto& [key, value] : py::cast<py::dict>(initial)) {
      const ra::ViewId id = py::cast<ra::ViewId>(key);
      if (!g.graph.HasView(id)) throw py::value_error("initial orientation for unknown view " + std::to_string(id));
      orientations[id] = ToMatrix3(value, "initial[" + std::to_string(id) + "]");
      if (!ra::IsRotationMatrix(orientations[id], 1e-6)) {
        throw py::value_error("initial[" + std::to_string(id) + "] is not a rotation matrix");
      }
    }
  }
  Solution s;
  {
    py::gil_scoped_release release;
    s.success = ra::SolveRotationAveraging(g.graph, options, &orientations, &s.summary);
  }
  for (const ra::View& v : g.graph.Views()) {
    auto it = orientations.find(v.id);
    if (it == orientations.end()) continue;
    s.ids.push_back(v.id);
    s.names.push_back(v.name);
    s.rotations.push_back(it->second);
  }
  return s;
}

template <typename Getter>
py::array_t<double> EdgeField(const Solution& s, Getter get) {
  py::array_t<double> out(static_cast<py::ssize_t>(s.summary.edges.size()));
  auto r = out.mutable_unchecked<1>();
  for (std::size_t k = 0; k < s.summary.edges.size(); ++k) r(k) = get(s.summary.edges[k]);
  return out;
}

py::dict EvaluationToDict(const ra::EvaluationResult& e) {
  py::dict d;
  d["views_in_ground_truth"] = e.views_in_ground_truth;
  d["views_estimated"] = e.views_estimated;
  d["views_common"] = e.views_common;
  d["median_error_deg"] = e.median_error_deg;
  d["mean_error_deg"] = e.mean_error_deg;
  py::dict auc;
  for (const auto& [t, a] : e.auc) auc[py::float_(t)] = a;
  d["auc"] = auc;
  py::dict errors;
  for (const auto& [name, err] : e.errors_deg) errors[py::str(name)] = err;
  d["errors_deg"] = errors;
  d["alignment"] = Array(py::cast(e.alignment));
  return d;
}

// ViewGraph: building one, view by view, edge by edge, or from arrays.
py::class_<PyViewGraph> BindViewGraph(py::module_& m) {
  py::class_<PyViewGraph> graph(m, "ViewGraph", R"(Views (64-bit ids) and relative-rotation edges.

An edge (i, j) holds R_ij = R_i R_j^T for world-to-camera R, and optionally the
3x3 covariance (rad^2) of a right perturbation in camera j's frame.)");
  graph.def(py::init<>())
      .def("add_view", [](PyViewGraph& g, ra::ViewId id, const std::string& name) { return g.graph.AddView(id, name); },
           py::arg("id"), py::arg("name") = "", "Adds a view; False if the id exists. The name defaults to the id.")
      .def(
          "add_edge",
          [](PyViewGraph& g, ra::ViewId i, ra::ViewId j, const Array& rotation, const py::object& covariance, int inliers,
             const std::string& source, std::uint32_t channel) {
            Eigen::Matrix3d r;
            if (rotation.ndim() == 1 && rotation.shape(0) == 4) {
              const Array q = py::cast<Array>(py::cast<py::array>(rotation).attr("reshape")(1, 4));
              r = RotationsFromArray(q, 1, "rotation")[0];
            } else {
              r = ToMatrix3(rotation, "rotation");
            }
            if (!g.graph.HasView(i)) g.graph.AddView(i);
            if (!g.graph.HasView(j)) g.graph.AddView(j);
            AddEdgeOrThrow(&g, i, j, r, covariance, inliers, source, channel);
          },
          py::arg("view1"), py::arg("view2"), py::arg("rotation"), py::arg("covariance") = py::none(),
          py::arg("inliers") = 0, py::arg("source") = "other", py::arg("channel") = 0,
          "Adds an edge (views are created as needed); rotation 3x3 or quaternion (w, x, y, z). "
          "Raises ValueError with the reason if the graph rejects it.")
      .def_static("from_arrays", &FromArrays, py::arg("view1"), py::arg("view2"), py::arg("rotations"),
                  py::arg("covariances") = py::none(), py::arg("inliers") = py::none(), py::arg("ids") = py::none(),
                  py::arg("names") = py::none(),
                  "Graph from arrays: view ids (m,), rotations (m, 3, 3) or quaternions (m, 4), optional covariances "
                  "(m, 3, 3) and inlier counts (m,); optional view ids and names to declare views up front. Edges "
                  "the graph rejects are skipped and listed in `warnings`.")
      .def(
          "add_relative_pose",
          [](PyViewGraph& g, ra::ViewId i, ra::ViewId j, const ra::RelativePoseResult& pose, const std::string& source,
             std::uint32_t channel) {
            if (!pose.success) {
              throw py::value_error("edge " + std::to_string(i) + "-" + std::to_string(j) + ": the pair has no pose (" +
                                    ra::TwoViewFailureName(pose.failure) + ": " + pose.message + ")");
            }
            if (!g.graph.HasView(i)) g.graph.AddView(i);
            if (!g.graph.HasView(j)) g.graph.AddView(j);
            AddEdgeOrThrow(&g, i, j, pose.EdgeRotation(), py::cast(pose.covariance), static_cast<int>(pose.inliers.size()),
                           source, channel);
          },
          py::arg("view1"), py::arg("view2"), py::arg("pose"), py::arg("source") = "other", py::arg("channel") = 0,
          "Adds the edge a relative_pose(points of view1, points of view2, ...) measures: R_12 = pose.rotation^T, "
          "its covariance and inlier count. Raises ValueError if the pair has no pose or the graph rejects it.");
  return graph;
}

// ViewGraph: reading it back as arrays, its components.
void BindViewGraphContents(py::class_<PyViewGraph> graph) {
  graph.def_property_readonly("num_views", [](const PyViewGraph& g) { return g.graph.NumViews(); })
      .def_property_readonly("num_edges", [](const PyViewGraph& g) { return g.graph.NumEdges(); })
      .def_readonly("warnings", &PyViewGraph::warnings, "Edges skipped on input, with the reason.")
      .def_property_readonly("view_ids",
                             [](const PyViewGraph& g) {
                               std::vector<ra::ViewId> ids;
                               for (const ra::View& v : g.graph.Views()) ids.push_back(v.id);
                               return py::array_t<std::uint64_t>(ids.size(), ids.data());
                             })
      .def_property_readonly("view_names",
                             [](const PyViewGraph& g) {
                               std::vector<std::string> names;
                               for (const ra::View& v : g.graph.Views()) names.push_back(v.name);
                               return names;
                             })
      .def_property_readonly("edge_views",
                             [](const PyViewGraph& g) {
                               py::array_t<std::uint64_t> out({static_cast<py::ssize_t>(g.graph.NumEdges()), py::ssize_t{2}});
                               auto r = out.mutable_unchecked<2>();
                               for (std::size_t k = 0; k < g.graph.NumEdges(); ++k) {
                                 r(k, 0) = g.graph.Edges()[k].view1;
                                 r(k, 1) = g.graph.Edges()[k].view2;
                               }
                               return out;
                             }, "(m, 2) view ids of each edge")
      .def_property_readonly("edge_rotations",
                             [](const PyViewGraph& g) {
                               std::vector<Eigen::Matrix3d> r;
                               for (const auto& e : g.graph.Edges()) r.push_back(e.rotation);
                               return MatricesToArray(r);
                             }, "(m, 3, 3) R_ij = R_i R_j^T")
      .def_property_readonly("edge_covariances",
                             [](const PyViewGraph& g) {
                               std::vector<Eigen::Matrix3d> c;
                               for (const auto& e : g.graph.Edges()) {
                                 c.push_back(e.has_covariance ? e.covariance
                                                              : Eigen::Matrix3d::Constant(std::nan("")));
                               }
                               return MatricesToArray(c);
                             }, "(m, 3, 3) covariances (rad^2); NaN for edges without one")
      .def_property_readonly("edge_inliers",
                             [](const PyViewGraph& g) {
                               std::vector<int> n;
                               for (const auto& e : g.graph.Edges()) n.push_back(e.num_inliers);
                               return py::array_t<int>(n.size(), n.data());
                             })
      .def("connected_components",
           [](const PyViewGraph& g) {
             std::vector<py::array_t<std::uint64_t>> out;
             for (const auto& c : g.graph.ConnectedComponents()) out.emplace_back(c.size(), c.data());
             return out;
           }, "Lists of view ids, largest first.")
      .def("__repr__", [](const PyViewGraph& g) {
        return "<ViewGraph " + std::to_string(g.graph.NumViews()) + " views, " + std::to_string(g.graph.NumEdges()) +
               " edges>";
      });
}

void BindSolveOptions(py::module_& m) {
  py::class_<ra::RotationAveragingOptions> options(m, "SolveOptions",
                                                   "Every option of the C++ solver (rotation_averaging.h); "
                                                   "enumerations as strings.");
  DefaultConstructibleCopyable(options);
  EnumProperty(options, "solver", &ra::RotationAveragingOptions::solver, &ra::SolverTypeName, &ra::ParseSolverType,
               ra::SolverTypeChoices());
  EnumProperty(options, "loss", &ra::RotationAveragingOptions::loss, &ra::LossTypeName, &ra::ParseLossType,
               ra::LossTypeChoices());
  EnumProperty(options, "weighting", &ra::RotationAveragingOptions::weighting, &ra::EdgeWeightingName,
               &ra::ParseEdgeWeighting, ra::EdgeWeightingChoices());
  EnumProperty(options, "covariance_normalization", &ra::RotationAveragingOptions::covariance_normalization,
               &ra::CovarianceNormalizationName, &ra::ParseCovarianceNormalization,
               ra::CovarianceNormalizationChoices());
  // The sub-structs' fields (robust_start, linear, l1_irls) are fields of
  // SolveOptions in Python: one flat set of names, as make_options takes them.
  options.def_property(
      "spanning_tree_weight",
      [](const ra::RotationAveragingOptions& o) {
        return std::string(ra::SpanningTreeWeightName(o.robust_start.spanning_tree_weight));
      },
      [](ra::RotationAveragingOptions& o, const std::string& text) {
        if (!ra::ParseSpanningTreeWeight(text, &o.robust_start.spanning_tree_weight)) {
          throw py::value_error("unknown spanning_tree_weight '" + text + "' (" + ra::SpanningTreeWeightChoices() + ")");
        }
      });
  EnumProperty(options, "self_calibration", &ra::RotationAveragingOptions::self_calibration,
               &ra::CovarianceSelfCalibrationName, &ra::ParseCovarianceSelfCalibration,
               ra::CovarianceSelfCalibrationChoices());
#define ROTAVG_FIELD(name) options.def_readwrite(#name, &ra::RotationAveragingOptions::name)
#define ROTAVG_NESTED_FIELD(group, name)                                                                  \
  options.def_property(                                                                                   \
      #name, [](const ra::RotationAveragingOptions& o) { return o.group.name; },                          \
      [](ra::RotationAveragingOptions& o,                                                                 \
         std::remove_reference_t<decltype(std::declval<ra::RotationAveragingOptions&>().group.name)> v) { \
        o.group.name = v;                                                                                 \
      })
  ROTAVG_FIELD(loss_scale);
  ROTAVG_FIELD(paper_covariance_scale);
  ROTAVG_FIELD(warm_start);
  ROTAVG_NESTED_FIELD(robust_start, warm_start_min_fraction);
  ROTAVG_NESTED_FIELD(robust_start, compare_tree_start);
  ROTAVG_NESTED_FIELD(robust_start, l1_initialization);
  ROTAVG_NESTED_FIELD(robust_start, l1_initialization_min_disagreement);
  ROTAVG_NESTED_FIELD(robust_start, l1_init_max_iterations);
  ROTAVG_NESTED_FIELD(robust_start, l1_init_smoothing_rad);
  ROTAVG_NESTED_FIELD(robust_start, l1_init_function_tolerance);
  ROTAVG_NESTED_FIELD(linear, isotropic_presolve_max_anisotropy);
  ROTAVG_NESTED_FIELD(linear, isotropic_presolve_function_tolerance);
  ROTAVG_NESTED_FIELD(robust_start, gnc_initial_scale_factor);
  ROTAVG_NESTED_FIELD(robust_start, gnc_scale_step);
  ROTAVG_NESTED_FIELD(robust_start, gnc_stage_max_iterations);
  ROTAVG_FIELD(auto_scale_threshold);
  ROTAVG_FIELD(max_iterations);
  ROTAVG_FIELD(step_tolerance_rad);
  ROTAVG_FIELD(function_tolerance);
  ROTAVG_NESTED_FIELD(linear, linear_solve_tolerance);
  ROTAVG_NESTED_FIELD(linear, robust_start_linear_solve_tolerance);
  ROTAVG_NESTED_FIELD(linear, multigrid_min_views);
  ROTAVG_NESTED_FIELD(linear, block_cholesky_max_column_count);
  ROTAVG_NESTED_FIELD(linear, block_multigrid_max_anisotropy);
  ROTAVG_NESTED_FIELD(linear, multigrid_linear_solve_tolerance);
  ROTAVG_FIELD(num_threads);
  ROTAVG_FIELD(posterior_covariance_max_views);
  ROTAVG_FIELD(irls_extrapolation);
  ROTAVG_NESTED_FIELD(l1_irls, l1_max_iterations);
  ROTAVG_NESTED_FIELD(l1_irls, l1_admm_max_iterations);
  ROTAVG_NESTED_FIELD(l1_irls, l1_irls_sigma_deg);
  ROTAVG_NESTED_FIELD(l1_irls, l1_irls_max_iterations);
#undef ROTAVG_FIELD
#undef ROTAVG_NESTED_FIELD
  options.def("validate", &ValidateOrThrow<ra::RotationAveragingOptions>,
              "Raises ValueError naming the first field out of its range (solve() checks it too).");
  options.def("default_loss_scale", &ra::DefaultLossScale,
              "The loss scale used when loss_scale <= 0, for this loss, weighting and normalisation.");
}

// The solve and what it returns.
void BindSolve(py::module_& m) {
  py::class_<Solution>(m, "Solution", "Orientations of the solved views and the solve's summary.")
      .def_property_readonly("ids", [](const Solution& s) { return py::array_t<std::uint64_t>(s.ids.size(), s.ids.data()); },
                             "(n,) ids of the oriented views (isolated views are not oriented)")
      .def_readonly("names", &Solution::names)
      .def_property_readonly("rotations", [](const Solution& s) { return MatricesToArray(s.rotations); },
                             "(n, 3, 3) world-to-camera rotations, in the order of ids")
      .def_readonly("success", &Solution::success)
      .def("as_dict",
           [](const Solution& s) {
             py::dict d;
             for (std::size_t k = 0; k < s.ids.size(); ++k) d[py::int_(s.ids[k])] = Array(py::cast(s.rotations[k]));
             return d;
           }, "{id: 3x3 rotation}, usable as the initial orientations of another solve")
      .def("named",
           [](const Solution& s) {
             py::dict d;
             for (std::size_t k = 0; k < s.ids.size(); ++k) d[py::str(s.names[k])] = Array(py::cast(s.rotations[k]));
             return d;
           }, "{view name: 3x3 rotation}, for evaluate() and write_orientations()")
      .def_property_readonly("edge_residuals_rad",
                             [](const Solution& s) { return EdgeField(s, [](const ra::EdgeResult& e) { return e.residual_rad; }); },
                             "(m,) |Log(M^T R_i R_j^T)| per edge, in the graph's edge order")
      .def_property_readonly("edge_whitened_squared",
                             [](const Solution& s) { return EdgeField(s, [](const ra::EdgeResult& e) { return e.whitened_squared; }); },
                             "(m,) |D^T r|^2 per edge")
      .def_property_readonly("edge_weights",
                             [](const Solution& s) { return EdgeField(s, [](const ra::EdgeResult& e) { return e.robust_weight; }); },
                             "(m,) final robust weight rho'(s) in [0, 1]; 0 is a rejected outlier")
      .def_property_readonly("edge_solved",
                             [](const Solution& s) {
                               py::array_t<bool> out(static_cast<py::ssize_t>(s.summary.edges.size()));
                               auto r = out.mutable_unchecked<1>();
                               for (std::size_t k = 0; k < s.summary.edges.size(); ++k) r(k) = s.summary.edges[k].solved;
                               return out;
                             })
      .def_property_readonly("view_covariances",
                             [](const Solution& s) {
                               py::dict d;
                               for (const auto& [id, c] : s.summary.view_covariances) d[py::int_(id)] = Array(py::cast(c));
                               return d;
                             },
                             "{id: 3x3} posterior covariances (rad^2, left perturbation, relative to the component's "
                             "gauge view); filled when options.posterior_covariance_max_views > 0")
      .def_property_readonly("components",
                             [](const Solution& s) {
                               py::list l;
                               for (const auto& c : s.summary.components) l.append(ComponentToDict(c));
                               return l;
                             })
      .def_property_readonly("num_outlier_edges", [](const Solution& s) { return s.summary.num_outlier_edges; })
      .def_property_readonly("num_isolated_views", [](const Solution& s) { return s.summary.num_isolated_views; })
      .def_property_readonly("loss_scale", [](const Solution& s) { return s.summary.loss_scale; })
      .def_property_readonly("solve_time_s", [](const Solution& s) { return s.summary.solve_time_s; })
      .def_property_readonly("warnings", [](const Solution& s) { return s.summary.warnings; })
      .def("report", [](const Solution& s) { return s.summary.Report(); }, "The summary as text (as rotavg prints it)")
      .def("__repr__", [](const Solution& s) {
        return "<Solution " + std::to_string(s.ids.size()) + " views, " + std::to_string(s.summary.components.size()) +
               " components, " + (s.success ? "success" : "failed") + ">";
      });

  m.def("solve", &Solve, py::arg("graph"), py::arg("options") = ra::RotationAveragingOptions(),
        py::arg("initial") = py::none(),
        "Solves every connected component. `initial`: {id: 3x3} warm-start orientations (options.warm_start).");
}

// Graphs, orientations and ground truth on disk, and the scoring.
void BindFilesAndEvaluation(py::module_& m) {
  m.def(
      "read_graph",
      [](const std::string& path, const std::string& format_text) {
        ra::GraphFormat format;
        if (!ra::ParseGraphFormat(format_text, &format)) {
          throw py::value_error("unknown format '" + format_text + "' (auto, 1dsfm, g2o, toro, irotavg, rotavg)");
        }
        PyViewGraph g;
        ra::ReadReport report;
        {
          py::gil_scoped_release release;
          report = ra::ReadViewGraph(path, format, &g.graph);
        }
        if (!report.ok()) ThrowReadError(report.error);
        g.warnings = report.warnings;
        return g;
      },
      py::arg("path"), py::arg("format") = "auto",
      "Reads a 1DSfM EGs.txt (or its folder), g2o, TORO, iRotAvg or rotavg graph file.");
  m.def(
      "write_graph",
      [](const std::string& path, const PyViewGraph& g) {
        std::string error;
        if (!ra::WriteRotavgGraph(path, g.graph, &error)) throw py::value_error(error);
      },
      py::arg("path"), py::arg("graph"), "Writes the package's own graph format (read back exactly).");
  m.def(
      "read_orientations",
      [](const std::string& path) {
        ra::NamedOrientations o;
        const ra::ReadReport report = ra::ReadOrientationsCsv(path, &o);
        if (!report.ok()) ThrowReadError(report.error);
        return NamedToDict(o);
      },
      py::arg("path"), "Orientations CSV (name,qw,qx,qy,qz) as {name: 3x3}.");
  m.def(
      "write_orientations",
      [](const std::string& path, const py::dict& orientations) {
        std::string error;
        if (!ra::WriteOrientationsCsv(path, DictToNamed(orientations, "orientations"), &error)) {
          throw py::value_error(error);
        }
      },
      py::arg("path"), py::arg("orientations"));
  m.def(
      "read_ground_truth",
      [](const std::string& path, const std::string& format_text) {
        ra::GroundTruthFormat format;
        if (!ra::ParseGroundTruthFormat(format_text, &format)) {
          throw py::value_error("unknown format '" + format_text + "' (auto, csv, strecha, colmap, chain)");
        }
        ra::NamedOrientations o;
        const ra::ReadReport report = ra::ReadGroundTruth(path, format, &o);
        if (!report.ok()) ThrowReadError(report.error);
        return NamedToDict(o);
      },
      py::arg("path"), py::arg("format") = "auto",
      "Ground truth (Strecha folder, COLMAP images.txt, CSV, or a noise-free graph to chain) as {name: 3x3}.");
  m.def(
      "evaluate",
      [](const py::dict& estimate, const py::dict& ground_truth, const std::vector<double>& thresholds) {
        return EvaluationToDict(ra::EvaluateOrientations(DictToNamed(estimate, "estimate"),
                                                         DictToNamed(ground_truth, "ground_truth"), thresholds));
      },
      py::arg("estimate"), py::arg("ground_truth"), py::arg("auc_thresholds_deg") = std::vector<double>{2, 5, 10, 20},
      "Aligns the estimate by one robustly fitted rotation and scores it: median and mean error, AUC per threshold, "
      "per-view errors. Both are {name: 3x3 world-to-camera}.");
}

// A synthetic graph with its truth, SO(3) maps and the names of the choices.
void BindUtilities(py::module_& m) {
  m.def(
      "synthetic_graph",
      [](int num_views, double mean_degree, double noise_deg, double noise_spread, bool anisotropic, double outlier_ratio,
         bool with_covariance, int locality, std::uint64_t seed) {
        ra::SyntheticGraphOptions o;
        o.num_views = num_views;
        o.mean_degree = mean_degree;
        o.noise_deg = noise_deg;
        o.noise_spread = noise_spread;
        o.anisotropic = anisotropic;
        o.outlier_ratio = outlier_ratio;
        o.with_covariance = with_covariance;
        o.locality = locality;
        o.seed = seed;
        if (num_views < 2 || !(mean_degree >= 2.0) || !(noise_deg >= 0.0) || !(noise_spread >= 1.0) ||
            !(outlier_ratio >= 0.0 && outlier_ratio < 1.0) || locality < 0) {
          throw py::value_error("need num_views >= 2, mean_degree >= 2, noise_deg >= 0, noise_spread >= 1, "
                                "0 <= outlier_ratio < 1, locality >= 0");
        }
        ra::SyntheticGraph sg = ra::MakeSyntheticGraph(o);
        PyViewGraph g;
        g.graph = std::move(sg.graph);
        py::dict truth;
        for (const ra::View& v : g.graph.Views()) truth[py::str(v.name)] = Array(py::cast(sg.ground_truth.at(v.id)));
        std::vector<char> outlier(sg.edge_is_outlier.begin(), sg.edge_is_outlier.end());
        py::array_t<bool> is_outlier(static_cast<py::ssize_t>(outlier.size()));
        for (std::size_t k = 0; k < outlier.size(); ++k) is_outlier.mutable_at(k) = outlier[k] != 0;
        return py::make_tuple(std::move(g), truth, is_outlier);
      },
      py::arg("num_views") = 100, py::arg("mean_degree") = 10.0, py::arg("noise_deg") = 3.0,
      py::arg("noise_spread") = 1.0, py::arg("anisotropic") = false, py::arg("outlier_ratio") = 0.0,
      py::arg("with_covariance") = true, py::arg("locality") = 0, py::arg("seed") = 1,
      "A random view graph with known ground truth: (graph, {name: 3x3}, is_outlier per edge).");
  m.def("exp_so3", [](const Eigen::Vector3d& w) { return ra::ExpSO3(w); }, py::arg("rotation_vector"));
  m.def("log_so3", [](const Eigen::Matrix3d& r) { return ra::LogSO3(r); }, py::arg("rotation"));
  m.def("loss_names", [] {
    std::vector<std::string> names;
    for (ra::LossType t : ra::AllLossTypes()) names.push_back(ra::LossTypeName(t));
    return names;
  });
  m.def("weighting_names", [] {
    std::vector<std::string> names;
    for (ra::EdgeWeighting w : ra::AllEdgeWeightings()) names.push_back(ra::EdgeWeightingName(w));
    return names;
  });
}

}  // namespace

PYBIND11_MODULE(_core, m) {
  m.doc() = "Uncertainty-aware robust rotation averaging (C++ core bindings)";
  // Options classes come before the functions whose defaults are built from them.
  BindViewGraphContents(BindViewGraph(m));
  BindSolveOptions(m);
  BindSolve(m);
  rotation_averaging_python::BindFrontend(m);
  BindFilesAndEvaluation(m);
  BindUtilities(m);
}
