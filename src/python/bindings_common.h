// Internal to the Python module: what its binding files share (the numpy
// array types, conversions, and the options classes' conventions).
#ifndef ROTATION_AVERAGING_SRC_PYTHON_BINDINGS_COMMON_H_
#define ROTATION_AVERAGING_SRC_PYTHON_BINDINGS_COMMON_H_

#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <Eigen/Core>
#include <string>

namespace py = pybind11;
namespace rotation_averaging {}
namespace ra = rotation_averaging;

namespace rotation_averaging_python {

using Array = py::array_t<double, py::array::c_style | py::array::forcecast>;

inline Eigen::Matrix3d ToMatrix3(const py::handle& h, const std::string& what) {
  const Array a = py::cast<Array>(h);
  if (a.ndim() != 2 || a.shape(0) != 3 || a.shape(1) != 3) throw py::value_error(what + " must be a 3x3 matrix");
  Eigen::Matrix3d m;
  auto r = a.unchecked<2>();
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) m(i, j) = r(i, j);
  return m;
}

// An options class: constructible with the defaults, and copied (never
// shared) by copy(), copy.copy and copy.deepcopy.
template <typename Options>
void DefaultConstructibleCopyable(py::class_<Options>& c) {
  c.def(py::init<>());
  c.def("copy", [](const Options& o) { return o; });
  c.def("__copy__", [](const Options& o) { return o; });
  c.def("__deepcopy__", [](const Options& o, py::dict) { return o; });
}

template <typename Options, typename Enum>
void EnumProperty(py::class_<Options>& c, const char* name, Enum Options::*field, const char* (*to_name)(Enum),
                  bool (*parse)(const std::string&, Enum*), const std::string& choices) {
  c.def_property(
      name, [field, to_name](const Options& o) { return std::string(to_name(o.*field)); },
      [field, parse, name, choices](Options& o, const std::string& text) {
        if (!parse(text, &(o.*field))) {
          throw py::value_error("unknown " + std::string(name) + " '" + text + "' (" + choices + ")");
        }
      });
}

// Options that do not validate are a ValueError naming the field.
template <typename Options>
void ValidateOrThrow(const Options& options) {
  std::string error;
  if (!options.Validate(&error)) throw py::value_error("options: " + error);
}

// The two-view estimation and the bundle adjustment (bindings_frontend.cpp).
void BindFrontend(py::module_& m);

}  // namespace rotation_averaging_python

#endif  // ROTATION_AVERAGING_SRC_PYTHON_BINDINGS_COMMON_H_
