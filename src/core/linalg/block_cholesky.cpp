#include "core/linalg/block_cholesky.h"

#include <algorithm>
#include <cmath>

namespace rotation_averaging {

bool InverseCholeskyFactor(const Eigen::Matrix3d& a, Eigen::Matrix3d* m) {
  const double d0 = a(0, 0);
  if (!(d0 > 0.0) || !std::isfinite(d0)) return false;
  const double l00 = std::sqrt(d0);
  const double l10 = a(1, 0) / l00, l20 = a(2, 0) / l00;
  const double d1 = a(1, 1) - l10 * l10;
  if (!(d1 > 0.0) || !std::isfinite(d1)) return false;
  const double l11 = std::sqrt(d1);
  const double l21 = (a(2, 1) - l20 * l10) / l11;
  const double d2 = a(2, 2) - l20 * l20 - l21 * l21;
  if (!(d2 > 0.0) || !std::isfinite(d2)) return false;
  const double l22 = std::sqrt(d2);
  const double m00 = 1.0 / l00, m11 = 1.0 / l11, m22 = 1.0 / l22;
  const double m10 = -l10 * m00 * m11;
  const double m21 = -l21 * m11 * m22;
  const double m20 = -(l20 * m00 + l21 * m10) * m22;
  *m << m00, 0.0, 0.0, m10, m11, 0.0, m20, m21, m22;
  return m->allFinite();
}

namespace {

// The stored blocks of A as blocks of P A P^T, grouped by row: for each step
// k, emit(k, i, c, p, transposed) for every stored block (r, c) at slot p of
// column c that lands at (k, i), i <= k, in P A P^T (transposed when it lands
// above the diagonal). Rows come out in order; a counting sort, so no
// per-row containers.
template <typename Emit>
void ForEachPermutedBlockByRow(const std::vector<std::vector<int>>& rows_of_column, const std::vector<int>& step,
                               Emit emit) {
  const int n = static_cast<int>(rows_of_column.size());
  std::vector<int> start(n + 2, 0);
  for (int c = 0; c < n; ++c)
    for (int r : rows_of_column[c]) ++start[std::max(step[r], step[c]) + 2];
  for (int k = 0; k < n; ++k) start[k + 2] += start[k + 1];
  struct Entry {
    int i, c, p;
    bool transposed;
  };
  std::vector<Entry> entries(start[n + 1]);
  for (int c = 0; c < n; ++c) {
    const std::vector<int>& rows = rows_of_column[c];
    for (std::size_t p = 0; p < rows.size(); ++p) {
      const int sr = step[rows[p]], sc = step[c];
      entries[start[std::max(sr, sc) + 1]++] = {std::min(sr, sc), c, static_cast<int>(p), sr < sc};
    }
  }
  for (int k = 0; k < n; ++k)
    for (int q = start[k]; q < start[k + 1]; ++q) emit(k, entries[q].i, entries[q].c, entries[q].p, entries[q].transposed);
}

// Walks the elimination tree of the rows of P A P^T given by `row_blocks`
// (for each k, the steps i < k of its blocks, from row_start[k]): calls
// visit(k, i) for each block L(k, i), i < k, of the factor's row k.
template <typename Visit>
void ForEachFactorBlock(int n, const std::vector<int>& row_start, const std::vector<int>& row_blocks, Visit visit) {
  std::vector<int> parent(n, -1), tag(n, -1);
  for (int k = 0; k < n; ++k) {
    tag[k] = k;
    for (int q = row_start[k]; q < row_start[k + 1]; ++q) {
      for (int i = row_blocks[q]; tag[i] != k; i = parent[i]) {
        if (parent[i] == -1) parent[i] = k;
        visit(k, i);
        tag[i] = k;
      }
    }
  }
}

std::size_t StoredBlocks(const std::vector<std::vector<int>>& rows_of_column) {
  std::size_t count = 0;
  for (const std::vector<int>& rows : rows_of_column) count += rows.size();
  return count;
}

std::vector<int> StepOfBlock(const Eigen::VectorXi& order) {
  std::vector<int> step(order.size());
  for (int k = 0; k < static_cast<int>(order.size()); ++k) step[order[k]] = k;
  return step;
}

}  // namespace

std::size_t BlockCholesky::CountFactorBlocks(const std::vector<std::vector<int>>& rows_of_column,
                                             const Eigen::VectorXi& order) {
  const int n = static_cast<int>(rows_of_column.size());
  std::vector<int> row_start(n + 1, 0), row_blocks;
  row_blocks.reserve(StoredBlocks(rows_of_column));
  ForEachPermutedBlockByRow(rows_of_column, StepOfBlock(order), [&](int k, int i, int, int, bool) {
    if (i < k) row_blocks.push_back(i);
    row_start[k + 1] = static_cast<int>(row_blocks.size());
  });
  for (int k = 0; k < n; ++k) row_start[k + 1] = std::max(row_start[k + 1], row_start[k]);
  std::size_t count = n;
  ForEachFactorBlock(n, row_start, row_blocks, [&](int, int) { ++count; });
  return count;
}

void BlockCholesky::Analyze(const std::vector<std::vector<int>>& rows_of_column, const Eigen::VectorXi& order,
                            const Eigen::SparseMatrix<double>& lower) {
  const int n = static_cast<int>(rows_of_column.size());
  n_ = n;
  order_.assign(order.data(), order.data() + n);

  // Each stored block of A, as a block of row max(step) of P A P^T.
  const int* outer = lower.outerIndexPtr();
  source_start_.assign(n + 1, 0);
  sources_.clear();
  const std::size_t stored_blocks = StoredBlocks(rows_of_column);
  sources_.reserve(stored_blocks);
  std::vector<int> row_blocks;
  row_blocks.reserve(stored_blocks);
  ForEachPermutedBlockByRow(rows_of_column, StepOfBlock(order), [&](int k, int i, int c, int p, bool transposed) {
    sources_.push_back({i, outer[3 * c] + 3 * p, outer[3 * c + 1] - outer[3 * c], transposed});
    if (i < k) row_blocks.push_back(i);
    source_start_[k + 1] = static_cast<int>(sources_.size());
  });
  std::vector<int> block_start(n + 1, 0);  // row k's blocks left of the diagonal in row_blocks
  for (int k = 0, b = 0, q = 0; k < n; ++k) {
    source_start_[k + 1] = std::max(source_start_[k + 1], source_start_[k]);
    for (; q < source_start_[k + 1]; ++q) b += sources_[q].column < k;
    block_start[k + 1] = b;
  }

  // The pattern of each row of L: the union of the paths from the row's
  // blocks of P A P^T up the elimination tree to the row.
  row_start_.assign(n + 1, 0);
  row_columns_.clear();
  row_columns_.reserve(2 * row_blocks.size());  // the factor's fill, about right for thin factors
  std::vector<int> column_count(n, 1);  // the diagonal block
  ForEachFactorBlock(n, block_start, row_blocks, [&](int k, int i) {
    row_columns_.push_back(i);
    row_start_[k + 1] = static_cast<int>(row_columns_.size());
    ++column_count[i];
  });
  for (int k = 0; k < n; ++k) {
    row_start_[k + 1] = std::max(row_start_[k + 1], row_start_[k]);
    // Ascending is a topological order: a parent comes after its children.
    std::sort(row_columns_.begin() + row_start_[k], row_columns_.begin() + row_start_[k + 1]);
  }
  column_start_.assign(n + 1, 0);
  for (int i = 0; i < n; ++i) column_start_[i + 1] = column_start_[i] + column_count[i];
  row_of_slot_.assign(column_start_[n], 0);
  std::vector<int> next(n);
  for (int i = 0; i < n; ++i) {
    row_of_slot_[column_start_[i]] = i;
    next[i] = column_start_[i] + 1;
  }
  // Rows are visited in order, so each column's blocks come out by row.
  row_slots_.resize(row_columns_.size());
  for (int k = 0; k < n; ++k) {
    for (int q = row_start_[k]; q < row_start_[k + 1]; ++q) {
      const int slot = next[row_columns_[q]]++;
      row_of_slot_[slot] = k;
      row_slots_[q] = slot;
    }
  }
  // Factorize writes every block before reading it.
  blocks_.resize(row_of_slot_.size());
  work_.resize(n);
}

bool BlockCholesky::Factorize(const Eigen::SparseMatrix<double>& lower) {
  const double* values = lower.valuePtr();
  for (int k = 0; k < n_; ++k) {
    // Row k of P A P^T, on the pattern of row k of L.
    const int row_begin = row_start_[k], row_end = row_start_[k + 1];
    for (int q = row_begin; q < row_end; ++q) work_[row_columns_[q]].setZero();
    Eigen::Matrix3d& diagonal = work_[k];
    diagonal.setZero();
    for (int q = source_start_[k]; q < source_start_[k + 1]; ++q) {
      const Source& s = sources_[q];
      Eigen::Matrix3d& target = work_[s.column];
      for (int b = 0; b < 3; ++b) {
        const double* column = values + s.first + b * s.column_stride;
        for (int a = 0; a < 3; ++a) {
          if (s.transposed) {
            target(b, a) += column[a];
          } else {
            target(a, b) += column[a];
          }
        }
      }
    }
    // L(k, i) = (A(k, i) - sum_{j < i} L(k, j) L(i, j)^T) L(i, i)^-T, the
    // sum pushed forward from each column i as soon as L(k, i) is known.
    for (int q = row_begin; q < row_end; ++q) {
      const int i = row_columns_[q];
      const Eigen::Matrix3d l_ki = work_[i] * blocks_[column_start_[i]].transpose();
      for (int p = column_start_[i] + 1; p < row_slots_[q]; ++p) {
        work_[row_of_slot_[p]].noalias() -= l_ki * blocks_[p].transpose();
      }
      diagonal.noalias() -= l_ki * l_ki.transpose();
      blocks_[row_slots_[q]] = l_ki;
    }
    if (!InverseCholeskyFactor(diagonal, &blocks_[column_start_[k]])) return false;
  }
  return true;
}

Eigen::MatrixXd BlockCholesky::Solve(const Eigen::MatrixXd& b) const {
  Eigen::MatrixXd x(b.rows(), b.cols());
  std::vector<Eigen::Vector3d> y(n_);
  for (Eigen::Index c = 0; c < b.cols(); ++c) {
    for (int k = 0; k < n_; ++k) y[k] = b.col(c).segment<3>(3 * order_[k]);
    // L y' = y, column by column.
    for (int i = 0; i < n_; ++i) {
      y[i] = blocks_[column_start_[i]] * y[i];
      for (int p = column_start_[i] + 1; p < column_start_[i + 1]; ++p) y[row_of_slot_[p]].noalias() -= blocks_[p] * y[i];
    }
    // L^T x = y'.
    for (int i = n_ - 1; i >= 0; --i) {
      Eigen::Vector3d v = y[i];
      for (int p = column_start_[i] + 1; p < column_start_[i + 1]; ++p) v.noalias() -= blocks_[p].transpose() * y[row_of_slot_[p]];
      y[i] = blocks_[column_start_[i]].transpose() * v;
    }
    for (int k = 0; k < n_; ++k) x.col(c).segment<3>(3 * order_[k]) = y[k];
  }
  return x;
}

}  // namespace rotation_averaging
