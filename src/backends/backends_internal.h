// Private to the back-end library (librotation_averaging_backends.so): what
// its entry point hands to the core (src/core/util/backends.h).
#ifndef ROTATION_AVERAGING_SRC_BACKENDS_BACKENDS_INTERNAL_H_
#define ROTATION_AVERAGING_SRC_BACKENDS_BACKENDS_INTERNAL_H_

#include <memory>

#include "core/util/backends.h"

namespace rotation_averaging {

// Ceres rotation averaging of one component (ceres_solver.cpp).
void CeresSolveComponent(const RotationAveragingOptions& options, const RobustLoss& loss, ComponentProblem* problem,
                         ComponentSummary* summary);

// CHOLMOD's supernodal factor (supernodal_cholesky.cpp); null when the
// library is built without CHOLMOD.
std::unique_ptr<SupernodalCholesky> MakeCholmodSupernodalCholesky();

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_SRC_BACKENDS_BACKENDS_INTERNAL_H_
