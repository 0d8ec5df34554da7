#include "core/linalg/block_sparse_system.h"

#include "core/linalg/aggregation_amg.h"
#include "core/linalg/block_cholesky.h"
#include "core/util/backends.h"

#include <Eigen/SparseCholesky>
#include <algorithm>
#include <cmath>
#include <cstdlib>

namespace rotation_averaging {
namespace {

// Approximate minimum degree ordering of a block graph given by the lower
// block pattern `rows_of_column` (column c: block rows r >= c, c included):
// order[k] is the block eliminated k-th (Eigen's convention for orderings).
Eigen::VectorXi BlockGraphOrdering(const std::vector<std::vector<int>>& rows_of_column) {
  const int n = static_cast<int>(rows_of_column.size());
  std::vector<Eigen::Triplet<double>> entries;
  std::size_t stored = 0;
  for (const std::vector<int>& rows : rows_of_column) stored += rows.size();
  entries.reserve(2 * stored);
  for (int c = 0; c < n; ++c) {
    for (int r : rows_of_column[c]) {
      entries.emplace_back(r, c, 1.0);
      if (r != c) entries.emplace_back(c, r, 1.0);
    }
  }
  Eigen::SparseMatrix<double> pattern(n, n);
  pattern.setFromTriplets(entries.begin(), entries.end());
  Eigen::PermutationMatrix<Eigen::Dynamic, Eigen::Dynamic, int> perm;
  Eigen::internal::minimum_degree_ordering(pattern, perm);
  return perm.indices();
}

}  // namespace

struct BlockSparseSystem::Index {
  // rows_of_column[c]: sorted block rows r >= c stored in block column c.
  std::vector<std::vector<int>> rows_of_column;
};

struct BlockSparseSystem::Factorization {
  std::unique_ptr<SupernodalCholesky> supernodal;  // from the back-end library, when chosen
  Eigen::SimplicialLLT<Eigen::SparseMatrix<double>, Eigen::Lower, Eigen::AMDOrdering<int>> simplicial;
  BlockCholesky block_simplicial;  // analysed in ChooseFactorization
  bool chosen = false;                // supernodal and the two below (BlockSparseSystem::ChooseFactorization)
  bool use_block_simplicial = false;  // 3x3 blocks whose factor is thin
  bool use_metis = false;       // nested-dissection ordering (large systems)
  bool analyzed = false;
  bool has_factor = false;      // a numeric factor of an earlier matrix exists
  bool refactor_next = false;   // the last PCG solve struggled: refresh the factor
  BackOff pcg_back_off;  // preconditioned solves through this factor (see Solve)

  Eigen::MatrixXd ApplyInverse(const Eigen::MatrixXd& b) {
    if (supernodal) return supernodal->Solve(b);
    if (use_block_simplicial) return block_simplicial.Solve(b);
    return simplicial.solve(b);
  }
  bool Factorize(const Eigen::SparseMatrix<double>& m) {
    if (supernodal) return supernodal->Factorize(m, use_metis);
    if (use_block_simplicial) return block_simplicial.Factorize(m);
    if (!analyzed) simplicial.analyzePattern(m);
    analyzed = true;
    simplicial.factorize(m);
    return simplicial.info() == Eigen::Success;
  }
};

BlockSparseSystem::BlockSparseSystem(int num_blocks, const std::vector<std::pair<int, int>>& pairs, int block_dim,
                                     int num_rhs)
    : num_blocks_(num_blocks), block_dim_(block_dim == 1 ? 1 : 3), index_(new Index), factorization_(new Factorization) {
  const int d = block_dim_;
  index_->rows_of_column.resize(num_blocks);
  {
    std::vector<int> count(num_blocks, 1);  // the diagonal
    for (const auto& p : pairs)
      if (p.first != p.second) ++count[std::min(p.first, p.second)];
    for (int c = 0; c < num_blocks; ++c) index_->rows_of_column[c].reserve(count[c]);
  }
  for (int c = 0; c < num_blocks; ++c) index_->rows_of_column[c].push_back(c);
  for (const auto& p : pairs) {
    if (p.first == p.second) continue;
    index_->rows_of_column[std::min(p.first, p.second)].push_back(std::max(p.first, p.second));
  }
  std::size_t nnz = 0;
  for (auto& rows : index_->rows_of_column) {
    std::sort(rows.begin(), rows.end());
    rows.erase(std::unique(rows.begin(), rows.end()), rows.end());
    nnz += static_cast<std::size_t>(d * d) * rows.size();
  }
  // Build the compressed column storage directly.
  const int n = d * num_blocks;
  matrix_.resize(n, n);
  matrix_.resizeNonZeros(static_cast<Eigen::Index>(nnz));
  int* outer = matrix_.outerIndexPtr();
  int* inner = matrix_.innerIndexPtr();
  int pos = 0;
  for (int c = 0; c < num_blocks; ++c) {
    const std::vector<int>& rows = index_->rows_of_column[c];
    for (int b = 0; b < d; ++b) {
      outer[d * c + b] = pos;
      for (int r : rows) {
        for (int a = 0; a < d; ++a) inner[pos++] = d * r + a;
      }
    }
  }
  outer[n] = pos;
  diagonal_positions_.resize(n);
  for (int c = 0; c < num_blocks; ++c) {
    for (int b = 0; b < d; ++b) diagonal_positions_[d * c + b] = outer[d * c + b] + b;  // row c is first
  }
  rhs_ = Eigen::MatrixXd::Zero(n, std::max(1, num_rhs));
  SetZero();
}

// Chosen when a factorisation is first needed: systems that multigrid
// solves never pay for the prediction (a noticeable part of a solve on the
// largest anisotropic graphs of results/scale.md).
void BlockSparseSystem::ChooseFactorization() const {
  Factorization& f = *factorization_;
  if (f.chosen) return;
  f.chosen = true;
  // 3x3 blocks whose factor is thin (a few dozen entries per column: a pose
  // graph that is mostly a chain) are factorised block by block
  // (BlockCholesky), ordered on the graph of the blocks; denser ones
  // (grid-like graphs) by CHOLMOD's supernodal factor, whose dense
  // kernels pay there and only there. The factor's size is predicted from
  // the block graph's ordering and elimination tree, before any numbers.
  // Scalar Laplacians: simplicial is as fast or faster on the real graphs:
  // their factors are too thin for
  // dense supernodes to pay for CHOLMOD's BLAS and thread overhead. Large
  // scalar systems are another matter: on grid-like graphs of 10,000 views
  // and more (rotavg_scale_benchmark, results/scale.md) CHOLMOD's supernodal
  // factor with a METIS ordering is several times faster than the
  // simplicial LLT.
  Eigen::VectorXi block_order;
  if (block_dim_ == 3 && num_blocks_ > 0) {
    f.use_block_simplicial = PredictFactor(&block_order) <= block_cholesky_max_column_count_;
  }
  const bool supernodal = block_dim_ == 3 ? !f.use_block_simplicial : num_blocks_ > kScalarCholmodMinBlocks;
  if (supernodal) {
    // CHOLMOD lives in the back-end library, loaded here the first time a
    // system needs it. Without it, 3x3 blocks keep BlockCholesky and scalar
    // systems Eigen's simplicial factor.
    const Backends* backends = LoadBackends();
    if (backends && backends->make_supernodal_cholesky) f.supernodal = backends->make_supernodal_cholesky();
    if (!f.supernodal && block_dim_ == 3) f.use_block_simplicial = true;
  }
  f.use_metis = block_dim_ == 1 && num_blocks_ > kMetisMinRows;
  if (f.use_block_simplicial) f.block_simplicial.Analyze(index_->rows_of_column, block_order, matrix_);
}

double BlockSparseSystem::PredictFactor(Eigen::VectorXi* block_order) const {
  if (block_dim_ != 3 || num_blocks_ == 0) return 0.0;
  *block_order = BlockGraphOrdering(index_->rows_of_column);
  const std::size_t block_entries = BlockCholesky::CountFactorBlocks(index_->rows_of_column, *block_order);
  // Each off-diagonal block of the factor holds 9 entries, each diagonal block 6.
  const double entries = 9.0 * static_cast<double>(block_entries - num_blocks_) + 6.0 * num_blocks_;
  return entries / (3.0 * num_blocks_);
}

double BlockSparseSystem::PredictedFactorEntriesPerColumn() const {
  Eigen::VectorXi block_order;
  return PredictFactor(&block_order);
}

// 3x3 blocks: block by block from the stored lower triangle (each
// off-diagonal block serves both triangles), a fixed-size product per block
// where the generic symmetric sparse product does index work per entry.
Eigen::MatrixXd BlockSparseSystem::Multiply(const Eigen::MatrixXd& v) const {
  if (block_dim_ != 3) return matrix_.selfadjointView<Eigen::Lower>() * v;
  Eigen::MatrixXd product = Eigen::MatrixXd::Zero(v.rows(), v.cols());
  const double* values = matrix_.valuePtr();
  const int* outer = matrix_.outerIndexPtr();
  using Block = Eigen::Map<const Eigen::Matrix3d, 0, Eigen::OuterStride<>>;
  for (Eigen::Index k = 0; k < v.cols(); ++k) {
    const double* x = v.col(k).data();
    double* y = product.col(k).data();
    for (int c = 0; c < num_blocks_; ++c) {
      const std::vector<int>& rows = index_->rows_of_column[c];
      const Eigen::OuterStride<> stride(outer[3 * c + 1] - outer[3 * c]);
      const Eigen::Map<const Eigen::Vector3d> x_c(x + 3 * c);
      Eigen::Map<Eigen::Vector3d> y_c(y + 3 * c);
      y_c.noalias() += Block(values + outer[3 * c], stride) * x_c;
      for (std::size_t p = 1; p < rows.size(); ++p) {
        const Block b(values + outer[3 * c] + 3 * p, stride);
        const int r = rows[p];
        Eigen::Map<Eigen::Vector3d>(y + 3 * r).noalias() += b * x_c;
        y_c.noalias() += b.transpose() * Eigen::Map<const Eigen::Vector3d>(x + 3 * r);
      }
    }
  }
  return product;
}

BlockSparseSystem::~BlockSparseSystem() = default;

const char* BlockSparseSystem::FactorizationMethod() const {
  ChooseFactorization();
  return factorization_->supernodal             ? "supernodal"
         : factorization_->use_block_simplicial ? "block_simplicial"
                                                : "simplicial";
}

void BlockSparseSystem::SetPcgTolerance(double tolerance) {
  // A new accuracy (the next stage of a robust solve) gets a fresh chance.
  if (tolerance != pcg_tolerance_) {
    factorization_->pcg_back_off.Reset();
    multigrid_back_off_.Reset();
    multigrid_rebuild_ = true;
  }
  pcg_tolerance_ = tolerance;
}

void BlockSparseSystem::SetZero() {
  std::fill(matrix_.valuePtr(), matrix_.valuePtr() + matrix_.nonZeros(), 0.0);
  rhs_.setZero();
}

int BlockSparseSystem::Locate(int row, int col) const {
  const std::vector<int>& rows = index_->rows_of_column[col];
  return static_cast<int>(std::lower_bound(rows.begin(), rows.end(), row) - rows.begin());
}

void BlockSparseSystem::AddBlock(int row, int col, const Eigen::Matrix3d& m) { AddBlockAt(col, Locate(row, col), m); }

void BlockSparseSystem::AddBlockAt(int col, int p, const Eigen::Matrix3d& m) {
  double* values = matrix_.valuePtr();
  const int* outer = matrix_.outerIndexPtr();
  for (int b = 0; b < 3; ++b) {
    double* column = values + outer[3 * col + b] + 3 * p;
    column[0] += m(0, b);
    column[1] += m(1, b);
    column[2] += m(2, b);
  }
}

bool BlockSparseSystem::TryMultigrid(Eigen::MatrixXd* x) {
  // Large systems (SetUseMultigrid): conjugate gradients preconditioned
  // with aggregation multigrid, set up for this matrix. The
  // aggregates of the last full setup are kept while the solves they serve
  // take at most two iterations more than the first one did; a solve that
  // takes more, or a new tolerance (the next stage), rebuilds them.
  // A system multigrid did not solve goes to the factorisation, and so do
  // the next 2^(k-1) solves after k such failures in a row: where the
  // hierarchy does not suit the matrix (nearly degenerate information, as in
  // some real pose graphs), each attempt would cost the iterations it takes
  // to give up.
  if (!use_multigrid_ || !multigrid_back_off_.Try()) return false;
  if (!multigrid_) multigrid_ = std::make_unique<AggregationAmg>();
  for (int pass = 0; pass < 2; ++pass) {
    const bool reuse = pass == 0 && !multigrid_rebuild_;
    bool converged = false;
    if (block_dim_ == 1 ? multigrid_->Setup(matrix_, reuse) : multigrid_->SetupBlocks(matrix_, reuse)) {
      last_pcg_iterations_ = multigrid_->Solve(
          rhs_, pcg_tolerance_, block_dim_ == 1 ? kMaxMultigridIterations : kMaxBlockMultigridIterations, x, &converged);
    }
    converged = converged && x->allFinite();
    if (!reuse) {
      multigrid_baseline_iterations_ = last_pcg_iterations_;
      multigrid_rebuild_ = false;
    } else if (!converged || last_pcg_iterations_ > multigrid_baseline_iterations_ + 2) {
      multigrid_rebuild_ = true;
    }
    if (converged) {
      ++num_multigrid_solves_;
      multigrid_back_off_.Succeeded();
      return true;
    }
    if (!reuse) break;  // a fresh hierarchy did not converge: factorise
  }
  multigrid_back_off_.Failed();
  return false;
}

bool BlockSparseSystem::TryOldFactor(Eigen::MatrixXd* x) {
  // Conjugate gradients preconditioned with the factor of an earlier
  // matrix of the same pattern: IRLS weights change little
  // from one iteration to the next, so a few cheap iterations replace a
  // factorisation. Where the weights change too much between solves (the
  // robust start's early iterations), every attempt fails and costs about
  // half a factorisation (three or more iterations through the old factor):
  // after k failures in a row, the next 2^(k-1) solves factorise directly
  // (on the large graphs of results/scale.md solved by factorisation alone,
  // the failed attempts otherwise take a large part of the solve).
  Factorization& f = *factorization_;
  if (!f.has_factor || f.refactor_next || !f.pcg_back_off.Try()) return false;
  // All right-hand sides iterate together, each with its own step
  // lengths: one triangular solve with k columns streams the factor once,
  // so the Laplacian's three coordinates cost little more than one (the
  // solve is bound by reading the factor, not by the arithmetic).
  const Eigen::Index k = rhs_.cols();
  Eigen::MatrixXd& xs = *x;
  xs = f.ApplyInverse(rhs_);
  Eigen::MatrixXd r = rhs_ - Multiply(xs);
  const Eigen::ArrayXd initial = r.colwise().squaredNorm().transpose().array();
  const Eigen::ArrayXd target = pcg_tolerance_ * pcg_tolerance_ * rhs_.colwise().squaredNorm().transpose().array();
  Eigen::ArrayXd residual2 = initial;
  auto all_converged = [&]() { return (residual2 <= target).all(); };
  Eigen::MatrixXd z = f.ApplyInverse(r);
  Eigen::MatrixXd p = z;
  Eigen::ArrayXd rz = (r.array() * z.array()).colwise().sum().transpose();
  int iterations = 0;
  bool failed = false;
  while (!all_converged() && !failed && iterations < kMaxPcgIterations) {
    const Eigen::MatrixXd hp = Multiply(p);
    ++iterations;
    for (Eigen::Index c = 0; c < k; ++c) {
      if (residual2(c) <= target(c)) continue;  // this column is done
      const double alpha = rz(c) / p.col(c).dot(hp.col(c));
      if (!std::isfinite(alpha) || !(alpha > 0.0)) {
        failed = true;
        break;
      }
      xs.col(c) += alpha * p.col(c);
      r.col(c) -= alpha * hp.col(c);
      residual2(c) = r.col(c).squaredNorm();
    }
    if (failed || all_converged()) break;
    // A stale factor shows at once: when the rate of the first three
    // iterations would not reach the tolerance within kMaxPcgIterations,
    // refactorising is cheaper than going on.
    if (iterations == 3) {
      bool hopeless = false;
      for (Eigen::Index c = 0; c < k; ++c) {
        if (residual2(c) <= target(c)) continue;
        // Squared residual reduction per iteration so far.
        const double rate2 = std::pow(residual2(c) / std::max(initial(c), 1e-300), 1.0 / iterations);
        hopeless = hopeless || !(rate2 < 1.0) ||
                   std::log(target(c) / residual2(c)) / std::log(rate2) > kMaxPcgIterations - iterations;
      }
      if (hopeless) break;
    }
    z = f.ApplyInverse(r);
    for (Eigen::Index c = 0; c < k; ++c) {
      if (residual2(c) <= target(c)) continue;
      const double rz_new = r.col(c).dot(z.col(c));
      p.col(c) = z.col(c) + (rz_new / rz(c)) * p.col(c);
      rz(c) = rz_new;
    }
  }
  last_pcg_iterations_ = iterations;
  if (!failed && all_converged() && xs.allFinite()) {
    f.pcg_back_off.Succeeded();
    ++num_pcg_solves_;
    f.refactor_next = last_pcg_iterations_ > kRefactorAfterPcgIterations;
    return true;
  }
  f.pcg_back_off.Failed();
  return false;
}

bool BlockSparseSystem::Solve(double relative_lambda, int max_retries, Eigen::VectorXd* x, double* lambda_used) {
  Eigen::MatrixXd solution;
  const bool ok = Solve(relative_lambda, max_retries, &solution, lambda_used);
  *x = ok && solution.cols() > 0 ? Eigen::VectorXd(solution.col(0)) : Eigen::VectorXd(solution.rows());
  return ok;
}

bool BlockSparseSystem::InverseDiagonalBlocks(std::vector<Eigen::Matrix3d>* blocks, double max_work) const {
  const int d = block_dim_;
  const int n = d * num_blocks_;
  blocks->assign(num_blocks_, Eigen::Matrix3d::Zero());
  if (n == 0) return true;
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>, Eigen::Lower, Eigen::AMDOrdering<int>> ldlt(matrix_);
  if (ldlt.info() != Eigen::Success) return false;
  const Eigen::VectorXd diagonal = ldlt.vectorD();
  if (!(diagonal.minCoeff() > 0.0) || !diagonal.allFinite()) return false;
  // The strictly lower part of the unit triangular factor, column by column
  // (rows ascending).
  const Eigen::SparseMatrix<double>& l = ldlt.matrixL().nestedExpression();
  std::vector<int> start(n + 1, 0), rows;
  std::vector<double> values;
  for (int j = 0; j < n; ++j) {
    start[j] = static_cast<int>(rows.size());
    for (Eigen::SparseMatrix<double>::InnerIterator it(l, j); it; ++it) {
      if (it.row() > j) {
        rows.push_back(static_cast<int>(it.row()));
        values.push_back(it.value());
      }
    }
  }
  start[n] = static_cast<int>(rows.size());
  double work = 0.0;  // ~ sum over columns of |P(j)|^2: the recurrence's cost
  for (int j = 0; j < n; ++j) work += static_cast<double>(start[j + 1] - start[j]) * (start[j + 1] - start[j]);
  if (work > max_work) return false;
  // Z = (L D L^T)^-1 on the pattern of L (Takahashi, Fagan & Chin 1973):
  //   Z_ij = -sum_{k in P(j)} L_kj Z_ik  (i in P(j)),
  //   Z_jj = 1 / D_j - sum_{k in P(j)} L_kj Z_kj,
  // from the last column to the first. For k in P(j), every i in P(j) above
  // k is in P(k) (fill paths), so Z_ik (= Z_ki) is found by walking column k
  // and P(j) together: each pair (i, k) is visited once and feeds both Z_ij
  // and Z_kj.
  std::vector<double> z(rows.size(), 0.0), z_diagonal(n, 0.0), accumulated;
  for (int j = n - 1; j >= 0; --j) {
    const int b = start[j], e = start[j + 1];
    accumulated.assign(e - b, 0.0);
    for (int pk = b; pk < e; ++pk) {
      const int k = rows[pk];
      const double l_kj = values[pk];
      accumulated[pk - b] += l_kj * z_diagonal[k];
      int q = pk + 1, c = start[k];
      const int column_end = start[k + 1];
      while (q < e && c < column_end) {
        if (rows[c] < rows[q]) {
          ++c;
        } else if (rows[c] > rows[q]) {
          ++q;  // not reached for a filled pattern
        } else {
          const double z_ik = z[c];
          accumulated[q - b] += l_kj * z_ik;
          accumulated[pk - b] += values[q] * z_ik;
          ++q;
          ++c;
        }
      }
    }
    double sum = 0.0;
    for (int p = b; p < e; ++p) {
      z[p] = -accumulated[p - b];
      sum += values[p] * z[p];
    }
    z_diagonal[j] = 1.0 / diagonal[j] - sum;
  }
  auto at = [&](int r, int c) {
    if (r == c) return z_diagonal[r];
    if (r < c) std::swap(r, c);
    const auto first = rows.begin() + start[c], last = rows.begin() + start[c + 1];
    const auto it = std::lower_bound(first, last, r);
    return it != last && *it == r ? z[it - rows.begin()] : 0.0;
  };
  // P A P^-1 = L D L^T, so (A^-1)_ab = Z_{P(a) P(b)}.
  const Eigen::VectorXi& perm = ldlt.permutationP().indices();
  for (int blk = 0; blk < num_blocks_; ++blk) {
    Eigen::Matrix3d& out = (*blocks)[blk];
    if (d == 1) {
      out = at(perm[blk], perm[blk]) * Eigen::Matrix3d::Identity();
      continue;
    }
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c <= r; ++c) out(r, c) = out(c, r) = at(perm[3 * blk + r], perm[3 * blk + c]);
    }
  }
  return true;
}

bool BlockSparseSystem::Solve(double relative_lambda, int max_retries, Eigen::MatrixXd* x, double* lambda_used) {
  const int n = block_dim_ * num_blocks_;
  if (n == 0) {
    x->resize(0, rhs_.cols());
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

  // The cheaper solves first; a factorisation where neither applies or
  // converges.
  if (TryMultigrid(x) || TryOldFactor(x)) {
    for (int i = 0; i < n; ++i) values[diagonal_positions_[i]] -= applied;
    if (lambda_used) *lambda_used = lambda;
    return true;
  }

  ChooseFactorization();
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
