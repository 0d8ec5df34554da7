// CHOLMOD's supernodal Cholesky factor behind the core's SupernodalCholesky.
#include "backends/backends_internal.h"

#ifdef ROTAVG_HAVE_CHOLMOD
#include <Eigen/CholmodSupport>
#ifdef _OPENMP
#include <omp.h>
#endif

namespace rotation_averaging {
namespace {

// CHOLMOD is built with OpenMP and opens parallel regions inside its
// supernodal factorisation. For systems of the size of the shared pose graphs,
// waking those threads costs more than they save; our solver is
// single-threaded by design, so the calling thread's OpenMP settings are
// changed around CHOLMOD calls and restored afterwards (they are per thread:
// nothing else changes).
class SingleThreadedOpenMp {
 public:
#ifdef _OPENMP
  // CHOLMOD asks for its teams with an explicit num_threads clause, which
  // only dynamic adjustment may shrink.
  SingleThreadedOpenMp() : previous_threads_(omp_get_max_threads()), previous_dynamic_(omp_get_dynamic()) {
    omp_set_num_threads(1);
    omp_set_dynamic(1);
  }
  ~SingleThreadedOpenMp() {
    omp_set_num_threads(previous_threads_);
    omp_set_dynamic(previous_dynamic_);
  }

 private:
  int previous_threads_;
  int previous_dynamic_;
#endif
};

class CholmodSupernodalCholesky : public SupernodalCholesky {
 public:
  bool Factorize(const Eigen::SparseMatrix<double>& lower, bool nested_dissection) override {
    SingleThreadedOpenMp single;
    // A factorisation that fails is retried with regularisation by the
    // caller and counted there; CHOLMOD's own warning on stderr is noise.
    factor_.cholmod().print = 0;
    if (!analyzed_) {
      if (nested_dissection) {
        factor_.cholmod().nmethods = 1;
        factor_.cholmod().method[0].ordering = CHOLMOD_METIS;
      }
      factor_.analyzePattern(lower);
      analyzed_ = true;
    }
    factor_.factorize(lower);
    return factor_.info() == Eigen::Success;
  }
  Eigen::MatrixXd Solve(const Eigen::MatrixXd& b) override {
    SingleThreadedOpenMp single;
    return factor_.solve(b);
  }

 private:
  Eigen::CholmodSupernodalLLT<Eigen::SparseMatrix<double>, Eigen::Lower> factor_;
  bool analyzed_ = false;
};

}  // namespace

std::unique_ptr<SupernodalCholesky> MakeCholmodSupernodalCholesky() {
  return std::make_unique<CholmodSupernodalCholesky>();
}

}  // namespace rotation_averaging
#endif  // ROTAVG_HAVE_CHOLMOD
