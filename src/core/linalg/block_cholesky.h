// Internal to the package: may change between versions.
// Sparse Cholesky factor L L^T = P A P^T of a symmetric positive definite
// matrix of dense 3x3 blocks (the IRLS normal equations of full covariance
// weighting), computed block by block: every entry of the symbolic analysis
// (elimination tree, pattern of each row of L, the slot of each block) is a
// block, and every numeric operation a fixed-size 3x3 product. For factors
// that are thin (a pose graph that is mostly a chain: a few blocks per
// column), this does a ninth of the index work of a scalar simplicial factor
// on the same ordering, and needs no permuted copy of the matrix; denser
// factors go to CHOLMOD's supernodal one (BlockSparseSystem decides).
//
// Up-looking (row k of L from rows 0..k-1, as Eigen's SimplicialLLT and
// CSparse's cs_chol do with scalars): row k's pattern is the union of the
// elimination-tree paths from the blocks of row k of P A P^T, fixed at
// analysis, so a numeric factorisation walks precomputed lists only.
#ifndef ROTATION_AVERAGING_SRC_CORE_LINALG_BLOCK_CHOLESKY_H_
#define ROTATION_AVERAGING_SRC_CORE_LINALG_BLOCK_CHOLESKY_H_

#include <Eigen/Core>
#include <Eigen/SparseCore>
#include <cstddef>
#include <vector>

namespace rotation_averaging {

// M = L^-1 for the lower Cholesky factor L of a symmetric 3x3 matrix A (its
// lower triangle is read), in closed form: M^T M = A^-1. False unless every
// pivot is positive and finite. The factor's pivot blocks and the square
// roots of edge information use it, where a general small-matrix
// factorisation and solve cost more than the rest of the work around them.
bool InverseCholeskyFactor(const Eigen::Matrix3d& a, Eigen::Matrix3d* m);

class BlockCholesky {
 public:
  // Symbolic analysis. `rows_of_column[c]` is the lower block pattern of A
  // (sorted block rows r >= c stored in block column c, c first), laid out
  // in `lower` as BlockSparseSystem stores it: block (r, c) at slot p of
  // column c holds A(3r + a, 3c + b) at value index
  // lower.outerIndexPtr()[3c + b] + 3p + a, and the diagonal block is stored
  // whole. `order[k]` is the block eliminated k-th.
  void Analyze(const std::vector<std::vector<int>>& rows_of_column, const Eigen::VectorXi& order,
               const Eigen::SparseMatrix<double>& lower);
  // Numeric factorisation of `lower` (same pattern as at analysis). False if
  // a pivot block is not positive definite or a number is not finite.
  bool Factorize(const Eigen::SparseMatrix<double>& lower);
  // A^-1 b for every column of b (3 x blocks rows).
  Eigen::MatrixXd Solve(const Eigen::MatrixXd& b) const;
  // Blocks of the factor of the same pattern and order, the diagonal ones
  // included, from the elimination tree alone (nothing is kept): what
  // choosing a factorisation needs before any numbers.
  static std::size_t CountFactorBlocks(const std::vector<std::vector<int>>& rows_of_column,
                                       const Eigen::VectorXi& order);
  // Blocks of L, the diagonal ones included.
  std::size_t NumFactorBlocks() const { return row_of_slot_.size(); }

 private:
  // One block of row k of P A P^T left of or on the diagonal, read from the
  // stored lower triangle: value (a, b) of the block is at
  // first + b * column_stride + a, of its transpose when `transposed`.
  struct Source {
    int column;  // block column of P A P^T (<= the row)
    int first;
    int column_stride;
    bool transposed;
  };
  int n_ = 0;
  std::vector<int> order_;                 // step -> block of A
  std::vector<int> source_start_;          // row k: sources_[source_start_[k] .. source_start_[k + 1])
  std::vector<Source> sources_;
  std::vector<int> row_start_;             // row k of L (left of the diagonal): row_columns_/row_slots_[row_start_[k] ..)
  std::vector<int> row_columns_;           // ascending (a topological order of the elimination tree)
  std::vector<int> row_slots_;             // slot of L(k, column) in blocks_
  std::vector<int> column_start_;          // column i of L: slots column_start_[i] (diagonal) .. column_start_[i + 1]
  std::vector<int> row_of_slot_;           // block row of each slot
  std::vector<Eigen::Matrix3d> blocks_;    // L by slot; diagonal slots hold the inverse of L(i, i)
  std::vector<Eigen::Matrix3d> work_;      // row being factorised, by block column
};

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_SRC_CORE_LINALG_BLOCK_CHOLESKY_H_
