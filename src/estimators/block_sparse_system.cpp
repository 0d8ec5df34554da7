#include "rotation_averaging/estimators/block_sparse_system.h"

#include <Eigen/SparseCholesky>
#include <algorithm>
#include <cmath>
#include <cstdlib>

#ifdef ROTAVG_HAVE_CHOLMOD
#include <Eigen/CholmodSupport>
#endif

namespace rotation_averaging {

struct BlockSparseSystem::Index {
  // rows_of_column[c]: sorted block rows r >= c stored in block column c.
  std::vector<std::vector<int>> rows_of_column;
};

struct BlockSparseSystem::Factorization {
#ifdef ROTAVG_HAVE_CHOLMOD
  Eigen::CholmodSupernodalLLT<Eigen::SparseMatrix<double>, Eigen::Lower> cholmod;
#endif
  Eigen::SimplicialLLT<Eigen::SparseMatrix<double>, Eigen::Lower, Eigen::AMDOrdering<int>> simplicial;
  bool use_cholmod = false;
  bool analyzed = false;
  bool has_factor = false;      // a numeric factor of an earlier matrix exists
  bool refactor_next = false;   // the last PCG solve struggled: refresh the factor

  Eigen::VectorXd ApplyInverse(const Eigen::VectorXd& b) {
#ifdef ROTAVG_HAVE_CHOLMOD
    if (use_cholmod) return cholmod.solve(b);
#endif
    return simplicial.solve(b);
  }
  bool Factorize(const Eigen::SparseMatrix<double>& m) {
#ifdef ROTAVG_HAVE_CHOLMOD
    if (use_cholmod) {
      if (!analyzed) cholmod.analyzePattern(m);
      analyzed = true;
      cholmod.factorize(m);
      return cholmod.info() == Eigen::Success;
    }
#endif
    if (!analyzed) simplicial.analyzePattern(m);
    analyzed = true;
    simplicial.factorize(m);
    return simplicial.info() == Eigen::Success;
  }
};

BlockSparseSystem::BlockSparseSystem(int num_blocks, const std::vector<std::pair<int, int>>& pairs)
    : num_blocks_(num_blocks), index_(new Index), factorization_(new Factorization) {
  index_->rows_of_column.resize(num_blocks);
  for (int c = 0; c < num_blocks; ++c) index_->rows_of_column[c].push_back(c);
  for (const auto& p : pairs) {
    if (p.first == p.second) continue;
    index_->rows_of_column[std::min(p.first, p.second)].push_back(std::max(p.first, p.second));
  }
  std::size_t nnz = 0;
  for (auto& rows : index_->rows_of_column) {
    std::sort(rows.begin(), rows.end());
    rows.erase(std::unique(rows.begin(), rows.end()), rows.end());
    nnz += 9 * rows.size();
  }
  // Build the compressed column storage directly.
  const int n = 3 * num_blocks;
  matrix_.resize(n, n);
  matrix_.resizeNonZeros(static_cast<Eigen::Index>(nnz));
  int* outer = matrix_.outerIndexPtr();
  int* inner = matrix_.innerIndexPtr();
  int pos = 0;
  for (int c = 0; c < num_blocks; ++c) {
    const std::vector<int>& rows = index_->rows_of_column[c];
    for (int b = 0; b < 3; ++b) {
      outer[3 * c + b] = pos;
      for (int r : rows) {
        for (int a = 0; a < 3; ++a) inner[pos++] = 3 * r + a;
      }
    }
  }
  outer[n] = pos;
  diagonal_positions_.resize(n);
  for (int c = 0; c < num_blocks; ++c) {
    for (int b = 0; b < 3; ++b) diagonal_positions_[3 * c + b] = outer[3 * c + b] + b;  // row c is first
  }
  rhs_ = Eigen::VectorXd::Zero(n);
  SetZero();
#ifdef ROTAVG_HAVE_CHOLMOD
  // Supernodal CHOLMOD pays off once blocks of the factor are large.
  // Supernodal CHOLMOD measured faster than Eigen's simplicial LLT on the
  // shared data overall (much faster on dense 1DSfM graphs).
  factorization_->use_cholmod = true;
#endif
}

BlockSparseSystem::~BlockSparseSystem() = default;

void BlockSparseSystem::SetZero() {
  std::fill(matrix_.valuePtr(), matrix_.valuePtr() + matrix_.nonZeros(), 0.0);
  rhs_.setZero();
}

void BlockSparseSystem::AddBlock(int row, int col, const Eigen::Matrix3d& m) {
  const std::vector<int>& rows = index_->rows_of_column[col];
  const int p = static_cast<int>(std::lower_bound(rows.begin(), rows.end(), row) - rows.begin());
  double* values = matrix_.valuePtr();
  const int* outer = matrix_.outerIndexPtr();
  for (int b = 0; b < 3; ++b) {
    double* column = values + outer[3 * col + b] + 3 * p;
    column[0] += m(0, b);
    column[1] += m(1, b);
    column[2] += m(2, b);
  }
}

bool BlockSparseSystem::Solve(double relative_lambda, int max_retries, Eigen::VectorXd* x, double* lambda_used) {
  const int n = 3 * num_blocks_;
  if (n == 0) {
    x->resize(0);
    return true;
  }
  double* values = matrix_.valuePtr();
  double mean_diagonal = 0.0;
  for (int k = 0; k < n; ++k) mean_diagonal += std::abs(values[diagonal_positions_[k]]);
  mean_diagonal = mean_diagonal > 0.0 ? mean_diagonal / n : 1.0;
  if (!std::isfinite(mean_diagonal) || !rhs_.allFinite()) return false;

  Factorization& f = *factorization_;
  double lambda = relative_lambda * mean_diagonal;
  double applied = 0.0;
  last_pcg_iterations_ = 0;
  for (int k = 0; k < n; ++k) values[diagonal_positions_[k]] += lambda;
  applied = lambda;

  // First try preconditioned conjugate gradients with the factor of an
  // earlier matrix of the same pattern: IRLS weights change little from one
  // iteration to the next, so a few cheap iterations replace a factorisation.
  if (f.has_factor && !f.refactor_next && reuse_factorization_) {
    const auto h = matrix_.selfadjointView<Eigen::Lower>();
    Eigen::VectorXd& xs = *x;
    xs = f.ApplyInverse(rhs_);
    Eigen::VectorXd r = rhs_ - h * xs;
    const double initial_residual2 = r.squaredNorm();
    Eigen::VectorXd z = f.ApplyInverse(r);
    Eigen::VectorXd p = z;
    double rz = r.dot(z);
    const double target = 1e-10 * rhs_.squaredNorm();
    bool converged = r.squaredNorm() <= target;
    for (int it = 0; it < kMaxPcgIterations && !converged && std::isfinite(rz) && rz > 0.0; ++it) {
      const Eigen::VectorXd hp = h * p;
      const double alpha = rz / p.dot(hp);
      if (!std::isfinite(alpha) || alpha <= 0.0) break;
      xs += alpha * p;
      r -= alpha * hp;
      ++last_pcg_iterations_;
      converged = r.squaredNorm() <= target;
      if (converged) break;
      // A stale factor shows at once: if three iterations have not reduced
      // the residual tenfold, refactorising is cheaper than going on.
      if (last_pcg_iterations_ == 3 && r.squaredNorm() > 1e-2 * initial_residual2) break;
      z = f.ApplyInverse(r);
      const double rz_new = r.dot(z);
      p = z + (rz_new / rz) * p;
      rz = rz_new;
    }
    if (converged && xs.allFinite()) {
      ++num_pcg_solves_;
      f.refactor_next = last_pcg_iterations_ > kRefactorAfterPcgIterations;
      for (int k = 0; k < n; ++k) values[diagonal_positions_[k]] -= applied;
      if (lambda_used) *lambda_used = lambda;
      return true;
    }
  }

  for (int attempt = 0; attempt <= max_retries; ++attempt) {
    for (int k = 0; k < n; ++k) values[diagonal_positions_[k]] += lambda - applied;
    applied = lambda;
    bool ok = f.Factorize(matrix_);
    f.has_factor = ok;
    f.refactor_next = false;
    if (ok) {
      *x = f.ApplyInverse(rhs_);
      ok = x->allFinite();
    }
    if (ok) {
      ++num_factorizations_;
      if (lambda_used) *lambda_used = lambda;
      for (int k = 0; k < n; ++k) values[diagonal_positions_[k]] -= applied;
      return true;
    }
    lambda = std::max(lambda * 100.0, 1e-8 * mean_diagonal);
  }
  f.has_factor = false;
  for (int k = 0; k < n; ++k) values[diagonal_positions_[k]] -= applied;
  if (lambda_used) *lambda_used = lambda;
  return false;
}

}  // namespace rotation_averaging
