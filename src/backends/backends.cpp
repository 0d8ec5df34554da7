// The entry point the core looks up after loading this library
// (src/core/util/backends.h).
#include "backends/backends_internal.h"

extern "C" __attribute__((visibility("default"))) const rotation_averaging::Backends* rotation_averaging_backends() {
  static const rotation_averaging::Backends backends = [] {
    rotation_averaging::Backends b;
#ifdef ROTAVG_HAVE_CHOLMOD
    b.make_supernodal_cholesky = &rotation_averaging::MakeCholmodSupernodalCholesky;
#endif
    b.solve_component_ceres = &rotation_averaging::CeresSolveComponent;
    return b;
  }();
  return &backends;
}
