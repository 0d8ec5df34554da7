// Internal to the package: may change between versions.
// The heavy back ends, in a library of their own that is loaded when one of
// them is first needed: CHOLMOD's supernodal Cholesky (with SuiteSparse,
// OpenBLAS and OpenMP) and the Ceres solver (with Ceres, glog and gflags).
//
// Most solves need neither: thin pose graphs, scalar Laplacians up to a few
// thousand views and every multigrid solve use Eigen's factors, and Ceres is
// a baseline. Linked into the core, their libraries cost every process that
// uses it their loading and relocation at start-up, more than the whole
// solve of a small graph (results/core_benchmark.md, start-up of `rotavg`).
#ifndef ROTATION_AVERAGING_SRC_CORE_UTIL_BACKENDS_H_
#define ROTATION_AVERAGING_SRC_CORE_UTIL_BACKENDS_H_

#include <Eigen/Core>
#include <Eigen/SparseCore>
#include <memory>

namespace rotation_averaging {

struct RotationAveragingOptions;
class RobustLoss;
struct ComponentProblem;
struct ComponentSummary;

// A sparse Cholesky factor by CHOLMOD's supernodal method.
class SupernodalCholesky {
 public:
  virtual ~SupernodalCholesky() = default;
  // Analyses the pattern of `lower` on the first call (by nested dissection
  // with `nested_dissection`, else CHOLMOD's default orderings), then
  // factorises it numerically. False when the matrix is not positive
  // definite.
  virtual bool Factorize(const Eigen::SparseMatrix<double>& lower, bool nested_dissection) = 0;
  virtual Eigen::MatrixXd Solve(const Eigen::MatrixXd& b) = 0;
};

// What the back-end library provides. Entries are null where it was built
// without them (no CHOLMOD).
struct Backends {
  std::unique_ptr<SupernodalCholesky> (*make_supernodal_cholesky)() = nullptr;
  void (*solve_component_ceres)(const RotationAveragingOptions& options, const RobustLoss& loss,
                                ComponentProblem* problem, ComponentSummary* summary) = nullptr;
};

// Loads librotation_averaging_backends.so once per process, from the
// directory of the core library or else the dynamic linker's search path.
// Null (and one warning on stderr) when it cannot be loaded: callers fall
// back to what the core has. Thread-safe. OpenBLAS, if loading it started
// the library, is held to one thread (see backends.cpp).
const Backends* LoadBackends();

// Whether the back-end library is loaded in this process (tests).
bool BackendsLoaded();

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_SRC_CORE_UTIL_BACKENDS_H_
