// Aggregation-based algebraic multigrid (AMG) as a preconditioner of
// conjugate gradients, for the large scalar systems of the IRLS solver:
// weighted graph Laplacians with the gauge view's row and column removed
// (symmetric positive definite, non-positive off-diagonal entries).
//
// Hierarchy: each level groups the unknowns into aggregates of at most four
// by two passes of pairwise matching along the strongest couplings (a node
// pairs with the unmatched neighbour j of largest -a_ij, among those with
// -a_ij >= strong_coupling * max_k -a_ik), and the coarse matrix is the
// Galerkin product P^T A P with the piecewise-constant prolongation P (for a
// Laplacian: the aggregates' graph with summed weights). Strongly diagonally
// dominant rows are left out of the aggregates and handled by the smoother
// alone. The coarsest level is factorised (sparse LDL^T).
//
// Cycle: the K-cycle of Notay and Vassilevski (Numer. Linear Algebra Appl.
// 2008): forward Gauss-Seidel, coarse correction by two steps of flexible CG
// on the next level (each preconditioned by that level's cycle; one step when
// it already reduces the residual fourfold), backward Gauss-Seidel. The cycle
// is not a fixed linear operator, so the outer iteration is flexible CG.
//
// Unlike a sparse Cholesky factor, the hierarchy costs O(nonzeros) to build
// and is rebuilt for every matrix: it suits IRLS iterations whose weights
// change too much for an earlier factor to precondition the next matrix.
// Several right-hand sides iterate together (one pass over each matrix
// serves all columns), each with its own step lengths.
#ifndef ROTATION_AVERAGING_ESTIMATORS_AGGREGATION_AMG_H_
#define ROTATION_AVERAGING_ESTIMATORS_AGGREGATION_AMG_H_

#include <Eigen/Core>
#include <Eigen/SparseCore>
#include <memory>
#include <vector>

namespace rotation_averaging {

class AggregationAmg {
 public:
  struct Options {
    double strong_coupling = 0.25;  // pairing threshold relative to a row's strongest coupling
    double dominance = 5.0;         // rows with a_ii >= dominance * sum_j |a_ij| are not aggregated
    int max_coarsest_size = 400;    // coarsen until at most this many nodes (sparse LDL^T there)
    int max_levels = 30;
    double kcycle_reduction = 0.25;  // one coarse Krylov step suffices below this residual ratio
    // Gauss-Seidel sweeps before (forward) and after (backward) the coarse
    // correction. Two took a MAGSAC-weighted 100,000-view system from 6 to 3
    // iterations to a relative residual of 1e-2 (27 to 21 to 1e-5).
    int smoothing_sweeps = 2;
    // A level above this size whose coarsening stalls (see PairwiseMatch)
    // is coarsened with weak nodes merged after all, rather than factorised.
    int relaxed_coarsening_size = 20000;
  };
  AggregationAmg();
  explicit AggregationAmg(const Options& options);
  ~AggregationAmg();

  // Builds the hierarchy for the symmetric matrix whose lower triangle
  // (diagonal included) `lower` holds in compressed columns. The sparsity
  // pattern's index is kept and reused while it stays the same. With
  // `reuse_aggregates`, the aggregates and coarse patterns of the previous
  // setup (same pattern) are kept and only the values are carried down:
  // O(nonzeros) without matching, a third to a quarter of a full setup. The
  // aggregates then follow the earlier matrix's strong couplings, which
  // weakens the preconditioner as the weights drift (see
  // BlockSparseSystem::Solve for when it rebuilds). False if the matrix is
  // empty, has a non-positive or non-finite diagonal entry, coarsening
  // stalls above 20,000 nodes, or the coarsest level is not positive definite.
  bool Setup(const Eigen::SparseMatrix<double>& lower, bool reuse_aggregates = false);
  // Solves A X = B by flexible CG preconditioned with the K-cycle, from
  // X = 0, until every column's relative residual |A x - b| / |b| is at most
  // `tolerance` or `max_iterations` pass. Returns the iterations taken;
  // `converged` reports whether every column reached the tolerance.
  int Solve(const Eigen::MatrixXd& b, double tolerance, int max_iterations, Eigen::MatrixXd* x,
            bool* converged);

  int NumLevels() const;
  int LevelSize(int level) const;
  // Sum over levels of the matrices' nonzeros, relative to the finest's.
  double OperatorComplexity() const;

 private:
  struct Impl;
  Options options_;
  std::unique_ptr<Impl> impl_;
};

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_ESTIMATORS_AGGREGATION_AMG_H_
