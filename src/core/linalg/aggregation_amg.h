// Internal to the package: may change between versions.
// Aggregation-based algebraic multigrid (AMG) as a preconditioner of
// conjugate gradients, for the large systems of the IRLS solver: weighted
// graph Laplacians with the gauge view's row and column removed (symmetric
// positive definite, non-positive off-diagonal entries), and their 3x3-block
// counterparts, matrix-weighted Laplacians (SetupBlocks).
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
#ifndef ROTATION_AVERAGING_SRC_CORE_LINALG_AGGREGATION_AMG_H_
#define ROTATION_AVERAGING_SRC_CORE_LINALG_AGGREGATION_AMG_H_

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
    // correction. Two halve the iterations of a large MAGSAC-weighted
    // system against one, for less than they save.
    int smoothing_sweeps = 2;
    // Block Gauss-Seidel sweeps on the 3x3-block level of SetupBlocks. A
    // block costs nine times a scalar entry to stream, so one sweep each
    // way takes less time per solve than two, although it needs more
    // iterations.
    int block_smoothing_sweeps = 1;
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
  // The same for a matrix of 3x3 blocks (3n x 3n, lower triangle of block
  // columns as BlockSparseSystem stores them: each block column's three
  // columns hold the same block rows, diagonal block first, in full) that is
  // a matrix-weighted graph Laplacian: off-diagonal blocks -G_ij, diagonal
  // blocks the sums of the G_ij of their edges (and of edges to held views),
  // G_ij symmetric positive semi-definite, so that the three constant vectors
  // are its near null space. The off-diagonal blocks are kept by their six
  // distinct entries (their symmetric part: the rounding of the assembly's
  // asymmetry is dropped), which is all the passes over them stream. The
  // hierarchy is built on the scalar Laplacian of weights tr(G_ij) / 3 (each
  // block replaced by its trace / 3), which bounds the block matrix within the
  // edges' anisotropy; the finest level is smoothed by block Gauss-Seidel on
  // the blocks themselves, so the anisotropy of each view's own couplings is
  // resolved there and only the smooth error goes to the scalar levels. False also when the matrix is not
  // of that block form, a diagonal block is not positive definite, or it is
  // too small to coarsen (at most max_coarsest_size views: factorise it).
  bool SetupBlocks(const Eigen::SparseMatrix<double>& lower, bool reuse_aggregates = false);
  // Solves A X = B by flexible CG preconditioned with the K-cycle, from
  // X = 0, until every column's relative residual |A x - b| / |b| is at most
  // `tolerance` or `max_iterations` pass. Returns the iterations taken;
  // `converged` reports whether every column reached the tolerance. After
  // SetupBlocks each column of B is one coupled system of 3n unknowns.
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

#endif  // ROTATION_AVERAGING_SRC_CORE_LINALG_AGGREGATION_AMG_H_
