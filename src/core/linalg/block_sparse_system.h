// Internal to the package: may change between versions.
// Symmetric block-sparse normal equations H X = B with 3x3 blocks (or 1x1:
// a scalar, Laplacian-like system with several right-hand sides), one block
// row per free view. The sparsity pattern is fixed at construction, so the
// symbolic factorisation (fill-reducing ordering, elimination tree) is done
// once and reused by every numeric factorisation. Only the lower block
// triangle is stored.
#ifndef ROTATION_AVERAGING_SRC_CORE_LINALG_BLOCK_SPARSE_SYSTEM_H_
#define ROTATION_AVERAGING_SRC_CORE_LINALG_BLOCK_SPARSE_SYSTEM_H_

#include <Eigen/Core>
#include <Eigen/SparseCore>
#include <algorithm>
#include <memory>
#include <utility>
#include <vector>

namespace rotation_averaging {

class AggregationAmg;

class BlockSparseSystem {
 public:
  // `num_blocks` free variables of dimension `block_dim` (3 or 1); `pairs`
  // lists the (unordered) block pairs that are coupled (duplicates and
  // self-pairs are fine); the right-hand side has `num_rhs` columns.
  BlockSparseSystem(int num_blocks, const std::vector<std::pair<int, int>>& pairs, int block_dim = 3,
                    int num_rhs = 1);
  ~BlockSparseSystem();

  int NumBlocks() const { return num_blocks_; }
  void SetZero();
  // H(row block, col block) += m, for row >= col (lower triangle); the
  // diagonal block takes the full 3x3. block_dim 3 only.
  void AddBlock(int row, int col, const Eigen::Matrix3d& m);
  // Slot of block (row, col), row >= col, in its column (the diagonal block
  // is slot 0): the assembly loops of a solver with a fixed edge list look
  // each block up once, not once per iteration, then add with *At.
  int Locate(int row, int col) const;
  // H(row, col) += v at a slot from Locate. block_dim 1 only.
  void AddScalarAt(int col, int slot, double v) { matrix_.valuePtr()[matrix_.outerIndexPtr()[col] + slot] += v; }
  // Position of entry (row, col), row >= col, in the stored values
  // (block_dim 1), and H(entry) += v there: an assembly loop over a fixed
  // edge list keeps one index per edge instead of (column, slot).
  int ScalarIndex(int row, int col) const { return matrix_.outerIndexPtr()[col] + Locate(row, col); }
  void AddScalarAtIndex(int index, double v) { matrix_.valuePtr()[index] += v; }
  void AddBlockAt(int col, int slot, const Eigen::Matrix3d& m);
  // H(a, b) += m and H(b, a) += m^T for any a != b, or H(a, a) += m.
  void AddSymmetric(int a, int b, const Eigen::Matrix3d& m) {
    if (a >= b) AddBlock(a, b, m); else AddBlock(b, a, m.transpose());
  }
  Eigen::MatrixXd& Rhs() { return rhs_; }
  // Solves (H + lambda I) X = rhs. On a failed factorisation, retries with
  // increasing lambda (relative to the mean diagonal) up to max_retries times.
  // Returns false if every attempt failed; `lambda_used` reports the last.
  //
  // When a factor of an earlier matrix exists (same pattern), the system is
  // first solved by conjugate gradients preconditioned with that factor, all
  // right-hand sides together, to the relative residual of
  // SetPcgTolerance; only if that does not converge in kMaxPcgIterations
  // (or the first three iterations show it will not) is the matrix
  // factorised again.
  bool Solve(double relative_lambda, int max_retries, Eigen::MatrixXd* x, double* lambda_used = nullptr);
  // The diagonal blocks (block_dim x block_dim, in the top-left of each 3x3;
  // scalar systems give c I) of the inverse of the current matrix, by a
  // sparse LDL^T factorisation and Takahashi's recurrence on its filled
  // pattern: about the cost of one factorisation, not of n solves. False if
  // the matrix is not positive definite, or if the factor is so dense that
  // the recurrence would take more than `max_work` (~ sum of squared column
  // counts; 3e8 is about a second here).
  bool InverseDiagonalBlocks(std::vector<Eigen::Matrix3d>* blocks, double max_work = 3e8) const;
  // Single right-hand side.
  bool Solve(double relative_lambda, int max_retries, Eigen::VectorXd* x, double* lambda_used = nullptr);
  // Replaces kBlockSimplicialMaxColumnCount; read when the first
  // factorisation chooses its method.
  void SetBlockCholeskyMaxColumnCount(double count) { block_cholesky_max_column_count_ = count; }
  // Solve by conjugate gradients preconditioned with aggregation multigrid
  // (AggregationAmg, set up for each matrix: Setup for scalar systems,
  // SetupBlocks for 3x3 blocks, which must then form a matrix-weighted
  // Laplacian) to the tolerance of SetPcgTolerance, before any
  // factorisation; the factorisation path follows only when that does not
  // converge within kMaxMultigridIterations.
  void SetUseMultigrid(bool use) { use_multigrid_ = use; }
  int NumMultigridSolves() const { return num_multigrid_solves_; }
  // Relative residual |H x - b| / |b| (per column) at which the
  // preconditioned solve stops. A changed tolerance forgets earlier failed
  // preconditioned solves (see Solve).
  void SetPcgTolerance(double tolerance);
  int NumFactorizations() const { return num_factorizations_; }
  // The factorisation this system's pattern chose: "simplicial" (Eigen's
  // simplicial LLT, ordered on the scalar pattern), "block_simplicial"
  // (BlockCholesky, ordered on the graph of the 3x3 blocks) or "supernodal"
  // (CHOLMOD).
  const char* FactorizationMethod() const;
  // 3x3 blocks: entries per scalar column of the Cholesky factor, predicted
  // from the block graph's minimum degree ordering and elimination tree (what
  // the choice of FactorizationMethod compares with the limit). 0 for
  // scalar systems.
  double PredictedFactorEntriesPerColumn() const;
  // H v for the current H (symmetric, from its stored lower triangle).
  Eigen::MatrixXd Multiply(const Eigen::MatrixXd& v) const;
  int NumPreconditionedSolves() const { return num_pcg_solves_; }
  int LastPcgIterations() const { return last_pcg_iterations_; }

  static constexpr int kScalarCholmodMinBlocks = 5000;  // scalar systems larger than this use CHOLMOD
  // 3x3-block systems whose Cholesky factor has at most this many entries
  // per column on average (predicted from the block graph) use BlockCholesky,
  // the others CHOLMOD's supernodal one (see ChooseFactorization and
  // RotationAveragingOptions::block_cholesky_max_column_count).
  static constexpr double kBlockSimplicialMaxColumnCount = 64.0;
  // Scalar systems with more blocks than this are ordered with METIS (less fill
  // on grid-like graphs); 3x3-block systems keep CHOLMOD's default ordering
  // (METIS made the real pose graphs' slower).
  static constexpr int kMetisMinRows = 15000;
  static constexpr int kMaxPcgIterations = 8;
  static constexpr int kRefactorAfterPcgIterations = 4;
  static constexpr int kMaxMultigridIterations = 40;
  // Block systems: an iteration costs far less against their factorisation,
  // so they may take more of them before falling back to it (at 40, large
  // anisotropic systems that were converging were sent to a factorisation
  // that cost more than the rest of their stage).
  static constexpr int kMaxBlockMultigridIterations = 100;

 private:
  // Back-off for a cheaper solve that keeps failing (preconditioned CG with
  // an old factor, multigrid): after k failures in a row the next 2^(k-1)
  // solves go straight to a factorisation.
  struct BackOff {
    int failed_in_a_row = 0;
    int skip = 0;  // solves still sent straight to the factorisation
    // Whether to try now; counts a skipped solve otherwise.
    bool Try() {
      if (skip == 0) return true;
      --skip;
      return false;
    }
    void Succeeded() { failed_in_a_row = 0; }
    void Failed() { skip = 1 << std::min(failed_in_a_row++, 16); }
    void Reset() { failed_in_a_row = skip = 0; }
  };
  struct Index;
  int num_blocks_;
  int block_dim_;
  Eigen::SparseMatrix<double> matrix_;
  std::vector<int> diagonal_positions_;  // value index of each scalar diagonal entry
  std::unique_ptr<Index> index_;
  Eigen::MatrixXd rhs_;
  double block_cholesky_max_column_count_ = kBlockSimplicialMaxColumnCount;
  double pcg_tolerance_ = 1e-5;
  int num_factorizations_ = 0;
  int num_pcg_solves_ = 0;
  int last_pcg_iterations_ = 0;
  bool use_multigrid_ = false;
  bool multigrid_rebuild_ = true;  // next multigrid setup: new aggregates
  int multigrid_baseline_iterations_ = 0;  // iterations of the first solve on the current aggregates
  int num_multigrid_solves_ = 0;
  BackOff multigrid_back_off_;
  std::unique_ptr<AggregationAmg> multigrid_;
  struct Factorization;
  std::unique_ptr<Factorization> factorization_;
  // Solve's cheaper paths, on the matrix with lambda already on its
  // diagonal: each returns whether it solved the system into `x` (false when
  // it does not apply, is backing off, or did not converge).
  bool TryMultigrid(Eigen::MatrixXd* x);
  bool TryOldFactor(Eigen::MatrixXd* x);
  // Picks the factorisation for this pattern (see FactorizationMethod), once.
  void ChooseFactorization() const;
  // PredictedFactorEntriesPerColumn and the block ordering it is for.
  double PredictFactor(Eigen::VectorXi* block_order) const;
};

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_SRC_CORE_LINALG_BLOCK_SPARSE_SYSTEM_H_
