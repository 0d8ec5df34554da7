#include "core/linalg/aggregation_amg.h"
#include "core/linalg/aggregation_amg_level.h"

#include <Eigen/Cholesky>
#include <Eigen/SparseCholesky>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <limits>
#include <tuple>
#include <type_traits>

namespace rotation_averaging {
namespace {

using amg::AggregateMembers;
using amg::Galerkin;
using amg::IndexLower;
using amg::kSkip;
using amg::Level;
using amg::PairwiseMatch;
using amg::UpdateLower;

// Coarsening that stalls above this size leaves a coarsest level too large
// to factorise cheaply: the hierarchy is refused.
constexpr int kMaxCoarsestSize = 20000;
// A level that keeps more than this fraction of the nodes of the one above
// has stalled.
constexpr double kStall = 0.7;

template <int K>
using Block = std::array<double, K>;

// y = A x: each entry for its row (gathered) and for its column (scattered
// to a row already written, which only rows below add to).
template <int K>
void Multiply(const Level& level, const double* x, double* y) {
  for (int i = 0; i < level.n; ++i) {
    const double* xi = x + K * i;
    Block<K> s;
    for (int c = 0; c < K; ++c) s[c] = level.diag[i] * xi[c];
    for (int m = level.lower_ptr[i]; m < level.lower_ptr[i + 1]; ++m) {
      const double a = level.lower_val[m];
      const int j = level.lower_col[m];
      for (int c = 0; c < K; ++c) {
        s[c] += a * x[K * j + c];
        y[K * j + c] += a * xi[c];
      }
    }
    for (int c = 0; c < K; ++c) y[K * i + c] = s[c];
  }
}

template <int K>
Block<K> Dot(const std::vector<double>& a, const std::vector<double>& b, int n) {
  Block<K> s{};
  for (int i = 0; i < n; ++i)
    for (int c = 0; c < K; ++c) s[c] += a[K * i + c] * b[K * i + c];
  return s;
}

// A symmetric 3x3 block by its six distinct entries. The off-diagonal blocks
// of a matrix-weighted Laplacian (-G_ij) are symmetric, so the product
// streams two thirds of the bytes of a full block; the passes over the
// blocks are bound by that streaming, not by arithmetic.
template <typename T>
struct SymmetricBlock {
  T xx, xy, xz, yy, yz, zz;
  // The symmetric part of m (the input's blocks are symmetric up to rounding).
  static SymmetricBlock Of(const Eigen::Matrix3d& m) {
    return {static_cast<T>(m(0, 0)), static_cast<T>(0.5 * (m(0, 1) + m(1, 0))),
            static_cast<T>(0.5 * (m(0, 2) + m(2, 0))), static_cast<T>(m(1, 1)),
            static_cast<T>(0.5 * (m(1, 2) + m(2, 1))), static_cast<T>(m(2, 2))};
  }
  // s += B v.
  template <typename S>
  void AddProduct(const double* v, S* s) const {
    const T v0 = static_cast<T>(v[0]), v1 = static_cast<T>(v[1]), v2 = static_cast<T>(v[2]);
    s[0] += xx * v0 + xy * v1 + xz * v2;
    s[1] += xy * v0 + yy * v1 + yz * v2;
    s[2] += xz * v0 + yz * v1 + zz * v2;
  }
};

// The finest level of a 3x3-block system (SetupBlocks): its diagonal
// blocks, and each off-diagonal block once, in block row i's part left of
// the diagonal (from lower_ptr[i]; the block is symmetric and is its own
// transpose in row lower_col[m]). Every pass applies each block to both of
// its views, gathering for one and scattering to the other, so it streams
// half the blocks of the full symmetric pattern.
struct BlockLevel {
  int n = 0;
  std::vector<Eigen::Matrix3d> diag, inv_diag;
  std::vector<int> lower_ptr, lower_col;
  // Double precision for the outer iteration's product; single precision for
  // the smoother, which the cycle streams twice per iteration: it halves that
  // traffic and only perturbs the preconditioner, which flexible CG absorbs.
  std::vector<SymmetricBlock<double>> val;
  std::vector<SymmetricBlock<float>> val_single;
  // Entry (a, b) of block m is input value base[m] + b * stride[m] + a (or
  // its transpose: the same symmetric block); likewise the diagonal blocks
  // (diagonal_base, diagonal_stride).
  std::vector<int> base, stride, diagonal_base, diagonal_stride;
  std::vector<double> residual, sum;
};

// y = H x (3 values per node), in double precision: each block for its row
// (gathered) and for its column (scattered to a row already written, which
// only rows below add to).
void BlockMultiply(const BlockLevel& level, const double* x, double* y) {
  using Vector = Eigen::Map<const Eigen::Vector3d>;
  for (int i = 0; i < level.n; ++i) {
    const double* xi = x + 3 * i;
    Eigen::Vector3d s = level.diag[i] * Vector(xi);
    for (int m = level.lower_ptr[i]; m < level.lower_ptr[i + 1]; ++m) {
      const int j = level.lower_col[m];
      level.val[m].AddProduct(x + 3 * j, s.data());
      level.val[m].AddProduct(xi, y + 3 * j);
    }
    Eigen::Map<Eigen::Vector3d>(y + 3 * i) = s;
  }
}

// Gauss-Seidel on A z = r over a level whose entries left of the diagonal
// are stored row by row (Level, BlockLevel). Row i gathers its entries left
// of the diagonal from the nodes before it and takes sum_i, the sum over its
// entries right of the diagonal, which the rows after it scattered as they
// were solved; it then scatters its new value to the rows before it. Each
// entry streams once per sweep, in the direction of the sweep, and stays in
// cache between its gather and its scatter. `Entries` applies the level's
// entries: ScalarEntries (K columns apart) or BlockEntries (3x3 blocks, so
// each view's three unknowns are solved together with its diagonal block,
// where an anisotropic information matrix couples them; a scalar smoother
// would leave the error along its weak axes).
//
// Forward sweeps, the first from z = 0, leaving the residual r - A z in
// level.residual. In a forward sweep sum_i is (U z)_i at the values before
// the sweep, scattered in the sweep before (zero in the first), and the
// sweep's own scatters rebuild it for the next; so the last sweep's residual
// needs no product of its own: row i's equation holds but for the change in
// its sum, residual_i = sum_i before - sum_i after.
template <typename Entries>
void ForwardGaussSeidel(const Entries& entries, const double* r, double* z, int sweeps) {
  constexpr int V = Entries::kValues;
  auto& level = entries.level;
  double* sum = level.sum.data();
  double* residual = level.residual.data();
  std::fill(level.sum.begin(), level.sum.end(), 0.0);
  for (int sweep = 0; sweep < sweeps; ++sweep) {
    const bool last = sweep + 1 == sweeps;
    for (int i = 0; i < level.n; ++i) {
      const int first = level.lower_ptr[i], end = level.lower_ptr[i + 1];
      double* sum_i = sum + V * i;
      auto s = entries.Begin(r + V * i, sum_i);
      for (int m = first; m < end; ++m) entries.Gather(m, z + V * level.lower_col[m], &s);
      double* zi = z + V * i;
      entries.Finish(i, r + V * i, sum_i, s, zi);
      for (int c = 0; c < V; ++c) {
        if (last) residual[V * i + c] = sum_i[c];
        sum_i[c] = 0.0;
      }
      for (int m = first; m < end; ++m) entries.Scatter(m, zi, sum + V * level.lower_col[m]);
    }
  }
  for (std::size_t k = 0; k < level.residual.size(); ++k) residual[k] -= sum[k];
}

// One backward sweep in place: sum_i holds the rows after i at their new
// values. Each row's entries are walked backward too, so that the whole
// sweep streams in one direction, which the hardware prefetcher follows
// (rows backward with each row's blocks forward took more than twice the
// time of a forward sweep).
template <typename Entries>
void BackwardGaussSeidel(const Entries& entries, const double* r, double* z) {
  constexpr int V = Entries::kValues;
  auto& level = entries.level;
  double* sum = level.sum.data();
  std::fill(level.sum.begin(), level.sum.end(), 0.0);
  for (int i = level.n - 1; i >= 0; --i) {
    const int first = level.lower_ptr[i], end = level.lower_ptr[i + 1];
    auto s = entries.Begin(r + V * i, sum + V * i);
    for (int m = end - 1; m >= first; --m) entries.Gather(m, z + V * level.lower_col[m], &s);
    double* zi = z + V * i;
    entries.Finish(i, r + V * i, sum + V * i, s, zi);
    for (int m = end - 1; m >= first; --m) entries.Scatter(m, zi, sum + V * level.lower_col[m]);
  }
}

// A scalar level's entries, applied to K columns apart: s = r_i - sum_i
// minus the gathered products, z_i = s / a_ii.
template <int K>
struct ScalarEntries {
  static constexpr int kValues = K;
  Level& level;
  Block<K> Begin(const double* ri, const double* sum_i) const {
    Block<K> s;
    for (int c = 0; c < K; ++c) s[c] = ri[c] - sum_i[c];
    return s;
  }
  void Gather(int m, const double* zj, Block<K>* s) const {
    const double a = level.lower_val[m];
    for (int c = 0; c < K; ++c) (*s)[c] -= a * zj[c];
  }
  void Finish(int i, const double*, const double*, const Block<K>& s, double* zi) const {
    for (int c = 0; c < K; ++c) zi[c] = s[c] * level.inv_diag[i];
  }
  void Scatter(int m, const double* zi, double* sj) const {
    const double a = level.lower_val[m];
    for (int c = 0; c < K; ++c) sj[c] += a * zi[c];
  }
};

// A block level's entries in single precision (the smoother's blocks): the
// gathered products summed in single precision, z_i = D_i^-1 (r_i - sum_i -
// that sum).
struct BlockEntries {
  static constexpr int kValues = 3;
  struct Sum {
    float s[3] = {0.0f, 0.0f, 0.0f};
  };
  BlockLevel& level;
  Sum Begin(const double*, const double*) const { return Sum(); }
  void Gather(int m, const double* zj, Sum* s) const { level.val_single[m].AddProduct(zj, s->s); }
  void Finish(int i, const double* ri, const double* sum_i, const Sum& s, double* zi) const {
    Eigen::Map<Eigen::Vector3d> new_zi(zi);
    new_zi = level.inv_diag[i] * (Eigen::Map<const Eigen::Vector3d>(ri) - Eigen::Map<const Eigen::Vector3d>(sum_i) -
                                  Eigen::Vector3d(s.s[0], s.s[1], s.s[2]));
  }
  void Scatter(int m, const double* zi, double* sj) const {
    float t[3] = {0.0f, 0.0f, 0.0f};
    level.val_single[m].AddProduct(zi, t);
    sj[0] += t[0], sj[1] += t[1], sj[2] += t[2];
  }
};

}  // namespace

struct AggregationAmg::Impl {
  std::vector<Level> levels;
  double kcycle_reduction = 0.25;
  int sweeps = 2;
  int block_sweeps = 1;
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>, Eigen::Lower, Eigen::AMDOrdering<int>> coarsest;
  // The coarsest matrix (lower triangle) and, per entry of the last level,
  // its slot there (diagonal apart): a numeric update refactorises it without
  // a new symbolic analysis.
  Eigen::SparseMatrix<double> coarsest_matrix;
  std::vector<int> coarsest_diagonal_slot, coarsest_entry_slot;
  bool structure_valid = false;  // aggregates and patterns of the last full setup
  // Index of the finest level's pattern: for each of its off-diagonal
  // entries and diagonal entries, the position in the lower-triangular input.
  int pattern_n = -1;
  std::vector<int> pattern_outer, pattern_inner;
  std::vector<int> offdiagonal_source, diagonal_source;
  // Outer iteration's vectors (K values per node).
  std::vector<double> x, r, z, p, q;
  // 3x3-block systems (SetupBlocks): the block level, smoothed on the
  // blocks, above the scalar hierarchy of its surrogate (levels[0]), and the
  // surrogate's lower triangle with, per entry, where its block is.
  bool block_mode = false;
  BlockLevel block;
  int block_pattern_n = -1;
  std::vector<int> block_pattern_outer, block_pattern_inner;
  Eigen::SparseMatrix<double> surrogate;
  std::vector<int> surrogate_base, surrogate_stride;

  bool BuildFinest(const Eigen::SparseMatrix<double>& lower, bool* pattern_changed);
  bool BuildBlocks(const Eigen::SparseMatrix<double>& lower);
  // BuildBlocks' parts: the block index and the surrogate's pattern of a
  // matrix with the 3x3 block pattern (HasBlockPattern), then its values.
  void IndexBlocks(const Eigen::SparseMatrix<double>& lower);
  bool ReadBlockValues(const double* values);
  bool BuildHierarchy(const AggregationAmg::Options& options, const Eigen::SparseMatrix<double>& lower, bool reuse);
  void IndexEntries(int l);
  bool FactorCoarsest(bool analyse);
  bool UpdateNumeric();
  template <int K>
  void Cycle(int l, const double* r, double* z);
  // Restriction of `residual` to level l + 1, its cycle there (with two
  // steps of flexible CG, the K-cycle, below the next-coarsest level) and
  // the prolongated correction added to z.
  template <int K>
  void CoarseCorrection(int l, const double* residual, double* z);
  void BlockCycle(const double* r, double* z);
  template <int K, typename Apply, typename Precondition>
  int Solve(int n, const Eigen::MatrixXd& b, int first_column, double tolerance, int max_iterations,
            bool give_up_early, Eigen::MatrixXd* x, bool* converged, Apply apply, Precondition precondition);
};

bool AggregationAmg::Impl::BuildFinest(const Eigen::SparseMatrix<double>& lower, bool* pattern_changed) {
  const int n = static_cast<int>(lower.rows());
  const int* outer = lower.outerIndexPtr();
  const int* inner = lower.innerIndexPtr();
  const double* values = lower.valuePtr();
  const int nnz = outer[n];
  const bool same = pattern_n == n && static_cast<int>(pattern_inner.size()) == nnz &&
                    std::memcmp(pattern_outer.data(), outer, sizeof(int) * (n + 1)) == 0 &&
                    std::memcmp(pattern_inner.data(), inner, sizeof(int) * nnz) == 0;
  Level& level = levels.front();
  *pattern_changed = !same;
  if (!same) {
    pattern_n = n;
    pattern_outer.assign(outer, outer + n + 1);
    pattern_inner.assign(inner, inner + nnz);
    level = Level();
    level.n = n;
    level.ptr.assign(n + 1, 0);
    diagonal_source.assign(n, -1);
    for (int c = 0; c < n; ++c) {
      for (int k = outer[c]; k < outer[c + 1]; ++k) {
        const int row = inner[k];
        if (row == c) continue;
        ++level.ptr[row + 1];
        ++level.ptr[c + 1];
      }
    }
    for (int i = 0; i < n; ++i) level.ptr[i + 1] += level.ptr[i];
    level.col.resize(level.ptr[n]);
    offdiagonal_source.resize(level.ptr[n]);
    // Columns in order: row r receives (r, c < r) in ascending c, then its
    // own column's rows, ascending too.
    std::vector<int> fill(level.ptr.begin(), level.ptr.end() - 1);
    for (int c = 0; c < n; ++c) {
      for (int k = outer[c]; k < outer[c + 1]; ++k) {
        const int row = inner[k];
        if (row == c) {
          diagonal_source[c] = k;
          continue;
        }
        level.col[fill[row]] = c;
        offdiagonal_source[fill[row]++] = k;
        level.col[fill[c]] = row;
        offdiagonal_source[fill[c]++] = k;
      }
    }
  }
  level.val.resize(level.col.size());
  for (std::size_t k = 0; k < level.col.size(); ++k) level.val[k] = values[offdiagonal_source[k]];
  level.diag.resize(n);
  for (int i = 0; i < n; ++i) {
    level.diag[i] = diagonal_source[i] >= 0 ? values[diagonal_source[i]] : 0.0;
    if (!(level.diag[i] > 0.0) || !std::isfinite(level.diag[i])) return false;
  }
  for (double v : level.val)
    if (!std::isfinite(v)) return false;
  return true;
}

template <int K>
void AggregationAmg::Impl::Cycle(int l, const double* r, double* z) {
  Level& level = levels[l];
  const int n = level.n;
  if (l + 1 == static_cast<int>(levels.size())) {
    using Vectors = Eigen::Matrix<double, Eigen::Dynamic, K, K == 1 ? Eigen::ColMajor : Eigen::RowMajor>;
    Eigen::Map<const Vectors> rhs(r, n, K);
    Eigen::Map<Vectors> out(z, n, K);
    out = coarsest.solve(rhs);
    return;
  }
  level.residual.resize(static_cast<std::size_t>(K) * n);
  level.sum.resize(static_cast<std::size_t>(K) * n);
  const ScalarEntries<K> entries{level};
  ForwardGaussSeidel(entries, r, z, sweeps);
  CoarseCorrection<K>(l, level.residual.data(), z);
  for (int sweep = 0; sweep < sweeps; ++sweep) BackwardGaussSeidel(entries, r, z);
}

template <int K>
void AggregationAmg::Impl::CoarseCorrection(int l, const double* residual, double* z) {
  Level& level = levels[l];
  const int n = level.n;
  const Level& next = levels[l + 1];
  const int nc = next.n;
  const std::size_t size = static_cast<std::size_t>(K) * nc;
  level.rc.assign(size, 0.0);
  level.c1.resize(size);
  for (int i = 0; i < n; ++i) {
    const int a = level.aggregate[i];
    if (a < 0) continue;
    for (int c = 0; c < K; ++c) level.rc[K * a + c] += residual[K * i + c];
  }
  Cycle<K>(l + 1, level.rc.data(), level.c1.data());
  if (l + 2 < static_cast<int>(levels.size())) {
    // Two steps of flexible CG on the next level (K-cycle).
    level.v1.resize(size);
    Multiply<K>(next, level.c1.data(), level.v1.data());
    const Block<K> rho1 = Dot<K>(level.c1, level.v1, nc), alpha1 = Dot<K>(level.c1, level.rc, nc);
    Block<K> coef1;
    for (int c = 0; c < K; ++c) coef1[c] = rho1[c] > 0.0 ? alpha1[c] / rho1[c] : 0.0;
    level.rt.resize(size);
    for (int a = 0; a < nc; ++a)
      for (int c = 0; c < K; ++c) level.rt[K * a + c] = level.rc[K * a + c] - coef1[c] * level.v1[K * a + c];
    const Block<K> rt2 = Dot<K>(level.rt, level.rt, nc), rc2 = Dot<K>(level.rc, level.rc, nc);
    bool enough = true;
    const double t2 = kcycle_reduction * kcycle_reduction;
    for (int c = 0; c < K; ++c) enough = enough && rt2[c] <= t2 * rc2[c];
    Block<K> coef2{};
    if (!enough) {
      level.c2.resize(size);
      level.v2.resize(size);
      Cycle<K>(l + 1, level.rt.data(), level.c2.data());
      Multiply<K>(next, level.c2.data(), level.v2.data());
      const Block<K> gamma = Dot<K>(level.c2, level.v1, nc), beta = Dot<K>(level.c2, level.v2, nc),
                     alpha2 = Dot<K>(level.c2, level.rt, nc);
      for (int c = 0; c < K; ++c) {
        const double rho2 = rho1[c] > 0.0 ? beta[c] - gamma[c] * gamma[c] / rho1[c] : 0.0;
        if (rho2 > 0.0 && std::isfinite(rho2)) {
          coef2[c] = alpha2[c] / rho2;
          coef1[c] -= gamma[c] * alpha2[c] / (rho1[c] * rho2);
        }
      }
    }
    for (int a = 0; a < nc; ++a) {
      for (int c = 0; c < K; ++c) {
        level.c1[K * a + c] = coef1[c] * level.c1[K * a + c] + (enough ? 0.0 : coef2[c] * level.c2[K * a + c]);
      }
    }
  }
  for (int i = 0; i < n; ++i) {
    const int a = level.aggregate[i];
    if (a < 0) continue;
    for (int c = 0; c < K; ++c) z[K * i + c] += level.c1[K * a + c];
  }
}

// The cycle of a block system: block Gauss-Seidel on the blocks, the
// coarse correction on the scalar surrogate's hierarchy (its three
// coordinates as three columns), block Gauss-Seidel back.
void AggregationAmg::Impl::BlockCycle(const double* r, double* z) {
  const std::size_t size = 3 * static_cast<std::size_t>(block.n);
  block.residual.resize(size);
  block.sum.resize(size);
  const BlockEntries entries{block};
  ForwardGaussSeidel(entries, r, z, block_sweeps);
  CoarseCorrection<3>(0, block.residual.data(), z);
  for (int sweep = 0; sweep < block_sweeps; ++sweep) BackwardGaussSeidel(entries, r, z);
}

// Flexible CG on n nodes of K independent columns (apply: y = A x,
// precondition: z ~ A^-1 r, both on K values per node).
template <int K, typename Apply, typename Precondition>
int AggregationAmg::Impl::Solve(int n, const Eigen::MatrixXd& b, int first_column, double tolerance,
                                int max_iterations, bool give_up_early, Eigen::MatrixXd* x_out, bool* converged,
                                Apply apply, Precondition precondition) {
  const std::size_t size = static_cast<std::size_t>(K) * n;
  x.assign(size, 0.0);
  r.resize(size);
  z.resize(size);
  p.resize(size);
  q.resize(size);
  for (int i = 0; i < n; ++i)
    for (int c = 0; c < K; ++c) r[K * i + c] = b(i, first_column + c);
  const Block<K> b2 = Dot<K>(r, r, n);
  Block<K> target, residual2 = b2;
  for (int c = 0; c < K; ++c) target[c] = tolerance * tolerance * b2[c];
  auto done = [&](int c) { return residual2[c] <= target[c]; };
  auto all_done = [&]() {
    for (int c = 0; c < K; ++c)
      if (!done(c)) return false;
    return true;
  };
  int iterations = 0;
  bool failed = false;
  if (!all_done()) {
    precondition(r.data(), z.data());
    p = z;
  }
  while (!all_done() && !failed && iterations < max_iterations) {
    apply(p.data(), q.data());
    ++iterations;
    const Block<K> pq = Dot<K>(p, q, n), pr = Dot<K>(p, r, n);
    Block<K> alpha;
    for (int c = 0; c < K; ++c) {
      alpha[c] = done(c) ? 0.0 : pr[c] / pq[c];
      if (!done(c) && !(std::isfinite(alpha[c]) && pq[c] > 0.0)) failed = true;
    }
    if (failed) break;
    for (std::size_t k = 0; k < size; ++k) {
      x[k] += alpha[k % K] * p[k];
      r[k] -= alpha[k % K] * q[k];
    }
    const Block<K> before = residual2;
    residual2 = Dot<K>(r, r, n);
    for (int c = 0; c < K; ++c)
      if (before[c] <= target[c]) residual2[c] = before[c];  // frozen column
    if (all_done()) break;
    // A block system whose preconditioner does not suit it (information so
    // anisotropic that the scalar surrogate misjudges the smooth error
    // stalls for hundreds of iterations) shows it
    // early; a factorisation is then cheaper than iterating to the cap.
    if (give_up_early && iterations >= 8) {
      for (int c = 0; c < K; ++c) {
        if (done(c)) continue;
        const double rate2 = std::pow(residual2[c] / b2[c], 1.0 / iterations);
        if (!(rate2 < 1.0) || iterations + std::log(target[c] / residual2[c]) / std::log(rate2) > 1.5 * max_iterations) {
          failed = true;
        }
      }
      if (failed) break;
    }
    precondition(r.data(), z.data());
    // Flexible CG: p = z - (z . q / p . q) p keeps p A-orthogonal to the
    // previous direction whatever the cycle did.
    const Block<K> zq = Dot<K>(z, q, n);
    Block<K> beta;
    for (int c = 0; c < K; ++c) beta[c] = pq[c] > 0.0 ? -zq[c] / pq[c] : 0.0;
    for (std::size_t k = 0; k < size; ++k) p[k] = z[k] + beta[k % K] * p[k];
  }
  *converged = !failed && all_done();
  for (int i = 0; i < n; ++i)
    for (int c = 0; c < K; ++c) (*x_out)(i, first_column + c) = x[K * i + c];
  return iterations;
}

AggregationAmg::AggregationAmg() : AggregationAmg(Options()) {}
AggregationAmg::AggregationAmg(const Options& options) : options_(options), impl_(new Impl) {}
AggregationAmg::~AggregationAmg() = default;

void AggregationAmg::Impl::IndexEntries(int l) {
  Level& fine = levels[l];
  const Level& coarse = levels[l + 1];
  fine.entry_target.assign(fine.col.size(), kSkip);
  std::vector<int> start, members;
  AggregateMembers(fine.aggregate, coarse.n, &start, &members);
  std::vector<int> position(coarse.n, -1);
  for (int a = 0; a < coarse.n; ++a) {
    for (int q = coarse.ptr[a]; q < coarse.ptr[a + 1]; ++q) position[coarse.col[q]] = q;
    for (int m = start[a]; m < start[a + 1]; ++m) {
      const int i = members[m];
      for (int p = fine.ptr[i]; p < fine.ptr[i + 1]; ++p) {
        const int b = fine.aggregate[fine.col[p]];
        if (b >= 0) fine.entry_target[p] = b == a ? -1 - a : position[b];
      }
    }
    for (int q = coarse.ptr[a]; q < coarse.ptr[a + 1]; ++q) position[coarse.col[q]] = -1;
  }
}

bool AggregationAmg::Impl::FactorCoarsest(bool analyse) {
  const Level& last = levels.back();
  if (analyse) {
    std::vector<Eigen::Triplet<double>> entries;
    entries.reserve(last.col.size() / 2 + last.n);
    for (int i = 0; i < last.n; ++i) {
      entries.emplace_back(i, i, 0.0);
      for (int p = last.ptr[i]; p < last.ptr[i + 1]; ++p)
        if (last.col[p] > i) entries.emplace_back(last.col[p], i, 0.0);
    }
    coarsest_matrix.resize(last.n, last.n);
    coarsest_matrix.setFromTriplets(entries.begin(), entries.end());
    coarsest_matrix.makeCompressed();
    const int* outer = coarsest_matrix.outerIndexPtr();
    const int* inner = coarsest_matrix.innerIndexPtr();
    auto slot = [&](int row, int column) {
      return static_cast<int>(std::lower_bound(inner + outer[column], inner + outer[column + 1], row) - inner);
    };
    coarsest_diagonal_slot.resize(last.n);
    coarsest_entry_slot.assign(last.col.size(), -1);
    for (int i = 0; i < last.n; ++i) {
      coarsest_diagonal_slot[i] = slot(i, i);
      for (int p = last.ptr[i]; p < last.ptr[i + 1]; ++p)
        if (last.col[p] > i) coarsest_entry_slot[p] = slot(last.col[p], i);
    }
  }
  double* values = coarsest_matrix.valuePtr();
  for (int i = 0; i < last.n; ++i) {
    values[coarsest_diagonal_slot[i]] = last.diag[i];
    for (int p = last.ptr[i]; p < last.ptr[i + 1]; ++p)
      if (coarsest_entry_slot[p] >= 0) values[coarsest_entry_slot[p]] = last.val[p];
  }
  if (analyse) coarsest.analyzePattern(coarsest_matrix);
  coarsest.factorize(coarsest_matrix);
  if (coarsest.info() != Eigen::Success) return false;
  const auto d = coarsest.vectorD();
  return d.size() == 0 || (d.minCoeff() > 0.0 && d.allFinite());
}

bool AggregationAmg::Impl::UpdateNumeric() {
  for (std::size_t l = 0; l + 1 < levels.size(); ++l) {
    const Level& fine = levels[l];
    Level& coarse = levels[l + 1];
    std::fill(coarse.diag.begin(), coarse.diag.end(), 0.0);
    std::fill(coarse.val.begin(), coarse.val.end(), 0.0);
    for (int i = 0; i < fine.n; ++i)
      if (fine.aggregate[i] >= 0) coarse.diag[fine.aggregate[i]] += fine.diag[i];
    for (std::size_t p = 0; p < fine.col.size(); ++p) {
      const int t = fine.entry_target[p];
      if (t >= 0) {
        coarse.val[t] += fine.val[p];
      } else if (t != kSkip) {
        coarse.diag[-1 - t] += fine.val[p];
      }
    }
  }
  return true;
}

bool AggregationAmg::Impl::BuildHierarchy(const AggregationAmg::Options& options,
                                          const Eigen::SparseMatrix<double>& lower, bool reuse) {
  bool pattern_changed = false;
  if (levels.empty()) levels.resize(1);
  if (!BuildFinest(lower, &pattern_changed)) {
    pattern_n = -1;
    return false;
  }
  const bool aggregates_rebuilt = !reuse || pattern_changed;
  if (!aggregates_rebuilt) {
    UpdateNumeric();
  } else {
    levels.resize(1);
    std::vector<int> first, second;
    Level intermediate;
    while (static_cast<int>(levels.size()) < options.max_levels && levels.back().n > options.max_coarsest_size) {
      Level& fine = levels.back();
      int n2 = 0;
      for (const bool relaxed : {false, true}) {
        const int n1 = PairwiseMatch(fine, options.strong_coupling, options.dominance, relaxed, &first);
        Galerkin(fine, first, n1, &intermediate);
        n2 = PairwiseMatch(intermediate, options.strong_coupling, options.dominance, relaxed, &second);
        if (n2 > 0 && n2 <= kStall * fine.n) break;
        // Coarsening stalls when many weakly tied nodes are left alone:
        // below relaxed_coarsening_size this level becomes the coarsest (and
        // is factorised), above it they are merged after all.
        if (fine.n <= options.relaxed_coarsening_size) break;
      }
      if (n2 == 0 || n2 > kStall * fine.n) break;
      fine.aggregate.resize(fine.n);
      for (int i = 0; i < fine.n; ++i) fine.aggregate[i] = first[i] < 0 ? -1 : second[first[i]];
      Level coarse;
      Galerkin(intermediate, second, n2, &coarse);
      levels.push_back(std::move(coarse));
      IndexEntries(static_cast<int>(levels.size()) - 2);
    }
    if (levels.back().n > kMaxCoarsestSize) return false;
  }
  for (Level& level : levels) {
    level.inv_diag.resize(level.n);
    for (int i = 0; i < level.n; ++i) {
      if (!(level.diag[i] > 0.0) || !std::isfinite(level.diag[i])) return false;
      level.inv_diag[i] = 1.0 / level.diag[i];
    }
    if (aggregates_rebuilt) IndexLower(&level);
    UpdateLower(&level);
  }
  return FactorCoarsest(/*analyse=*/aggregates_rebuilt);
}

bool AggregationAmg::Setup(const Eigen::SparseMatrix<double>& lower, bool reuse_aggregates) {
  Impl& m = *impl_;
  if (lower.rows() == 0 || lower.rows() != lower.cols() || !lower.isCompressed()) return false;
  m.kcycle_reduction = options_.kcycle_reduction;
  m.sweeps = std::max(1, options_.smoothing_sweeps);
  const bool reuse = reuse_aggregates && m.structure_valid && !m.block_mode;
  m.structure_valid = false;
  m.block_mode = false;
  if (!m.BuildHierarchy(options_, lower, reuse)) return false;
  m.structure_valid = true;
  return true;
}

namespace {

// Whether a lower triangle has the 3x3 block pattern the block mode needs:
// block column c is three columns holding the same rows, in triples 3r,
// 3r + 1, 3r + 2 of ascending block rows r >= c, the diagonal block first.
bool HasBlockPattern(int rows, const int* outer, const int* inner) {
  if (rows % 3 != 0) return false;
  for (int c = 0; c < rows / 3; ++c) {
    const int* rows_of_c = inner + outer[3 * c];
    const int count = outer[3 * c + 1] - outer[3 * c];
    if (count % 3 != 0 || count == 0 || rows_of_c[0] != 3 * c) return false;
    for (int b = 1; b < 3; ++b) {
      if (outer[3 * c + b + 1] - outer[3 * c + b] != count ||
          !std::equal(rows_of_c, rows_of_c + count, inner + outer[3 * c + b])) {
        return false;
      }
    }
    for (int k = 0; k < count; k += 3) {
      const int first = rows_of_c[k];
      if (first % 3 != 0 || rows_of_c[k + 1] != first + 1 || rows_of_c[k + 2] != first + 2 ||
          (k > 0 && first <= rows_of_c[k - 3])) {
        return false;
      }
    }
  }
  return true;
}

}  // namespace

void AggregationAmg::Impl::IndexBlocks(const Eigen::SparseMatrix<double>& lower) {
  const int rows = static_cast<int>(lower.rows());
  const int* outer = lower.outerIndexPtr();
  const int* inner = lower.innerIndexPtr();
  const int n = rows / 3;
  block = BlockLevel();
  block.n = n;
  block.lower_ptr.assign(n + 1, 0);
  block.diagonal_base.resize(n);
  block.diagonal_stride.resize(n);
  for (int c = 0; c < n; ++c) {
    const int count = outer[3 * c + 1] - outer[3 * c];
    for (int k = 3; k < count; k += 3) ++block.lower_ptr[inner[outer[3 * c] + k] / 3 + 1];
  }
  for (int i = 0; i < n; ++i) block.lower_ptr[i + 1] += block.lower_ptr[i];
  const int entries = block.lower_ptr[n];
  block.lower_col.resize(entries);
  block.base.resize(entries);
  block.stride.resize(entries);
  std::vector<int> fill(block.lower_ptr.begin(), block.lower_ptr.end() - 1);
  // The surrogate: lower triangle of the n x n matrix of the blocks'
  // traces / 3, in the same order.
  std::vector<int> surrogate_outer(n + 1, 0), surrogate_inner;
  surrogate_base.clear();
  surrogate_stride.clear();
  for (int c = 0; c < n; ++c) {
    const int count = outer[3 * c + 1] - outer[3 * c];
    block.diagonal_base[c] = outer[3 * c];
    block.diagonal_stride[c] = count;
    for (int k = 0; k < count; k += 3) {
      const int r = inner[outer[3 * c] + k] / 3;
      surrogate_inner.push_back(r);
      surrogate_base.push_back(outer[3 * c] + k);
      surrogate_stride.push_back(count);
      if (r == c) continue;
      // Block (r, c) below the diagonal, in row r. Block columns are
      // visited in ascending order, so each row's blocks are in ascending
      // columns.
      const int m = fill[r]++;
      block.lower_col[m] = c;
      block.base[m] = outer[3 * c] + k;
      block.stride[m] = count;
    }
    surrogate_outer[c + 1] = static_cast<int>(surrogate_inner.size());
  }
  surrogate.resize(n, n);
  surrogate.resizeNonZeros(static_cast<Eigen::Index>(surrogate_inner.size()));
  std::copy(surrogate_outer.begin(), surrogate_outer.end(), surrogate.outerIndexPtr());
  std::copy(surrogate_inner.begin(), surrogate_inner.end(), surrogate.innerIndexPtr());
  block.val.resize(entries);
  block.val_single.resize(entries);
  block.diag.resize(n);
  block.inv_diag.resize(n);
  block_pattern_outer.assign(outer, outer + rows + 1);
  block_pattern_inner.assign(inner, inner + outer[rows]);
  block_pattern_n = rows;
}

bool AggregationAmg::Impl::ReadBlockValues(const double* values) {
  auto read = [&](int base, int stride) {
    Eigen::Matrix3d m;
    for (int b = 0; b < 3; ++b)
      for (int a = 0; a < 3; ++a) m(a, b) = values[base + b * stride + a];
    return m;
  };
  for (std::size_t m = 0; m < block.val.size(); ++m) {
    const Eigen::Matrix3d g = read(block.base[m], block.stride[m]);
    if (!g.allFinite()) return false;
    block.val[m] = SymmetricBlock<double>::Of(g);
    block.val_single[m] = SymmetricBlock<float>::Of(g);
  }
  for (int i = 0; i < block.n; ++i) {
    // The input's diagonal blocks hold the full 3x3; symmetrised against rounding.
    const Eigen::Matrix3d d = read(block.diagonal_base[i], block.diagonal_stride[i]);
    block.diag[i] = 0.5 * (d + d.transpose());
    Eigen::LLT<Eigen::Matrix3d> llt(block.diag[i]);
    if (llt.info() != Eigen::Success || !block.diag[i].allFinite()) return false;
    block.inv_diag[i] = llt.solve(Eigen::Matrix3d::Identity());
    if (!block.inv_diag[i].allFinite()) return false;
  }
  double* surrogate_values = surrogate.valuePtr();
  for (std::size_t k = 0; k < surrogate_base.size(); ++k) {
    const int base = surrogate_base[k], stride = surrogate_stride[k];
    surrogate_values[k] = (values[base] + values[base + stride + 1] + values[base + 2 * stride + 2]) / 3.0;
  }
  return true;
}

bool AggregationAmg::Impl::BuildBlocks(const Eigen::SparseMatrix<double>& lower) {
  const int rows = static_cast<int>(lower.rows());
  const int* outer = lower.outerIndexPtr();
  const int* inner = lower.innerIndexPtr();
  // The index is rebuilt only when the pattern changed.
  const bool same = block_pattern_n == rows && static_cast<int>(block_pattern_inner.size()) == outer[rows] &&
                    std::memcmp(block_pattern_outer.data(), outer, sizeof(int) * (rows + 1)) == 0 &&
                    std::memcmp(block_pattern_inner.data(), inner, sizeof(int) * outer[rows]) == 0;
  if (!same) {
    block_pattern_n = -1;
    if (!HasBlockPattern(rows, outer, inner)) return false;
    IndexBlocks(lower);
  }
  return ReadBlockValues(lower.valuePtr());
}

bool AggregationAmg::SetupBlocks(const Eigen::SparseMatrix<double>& lower, bool reuse_aggregates) {
  Impl& m = *impl_;
  if (lower.rows() == 0 || lower.rows() != lower.cols() || !lower.isCompressed()) return false;
  m.kcycle_reduction = options_.kcycle_reduction;
  m.sweeps = std::max(1, options_.smoothing_sweeps);
  m.block_sweeps = std::max(1, options_.block_smoothing_sweeps);
  const bool reuse = reuse_aggregates && m.structure_valid && m.block_mode;
  m.structure_valid = false;
  m.block_mode = true;
  if (!m.BuildBlocks(lower)) return false;
  // One level would leave the surrogate's factor as the whole solve.
  if (!m.BuildHierarchy(options_, m.surrogate, reuse) || m.levels.size() < 2) return false;
  m.structure_valid = true;
  return true;
}

int AggregationAmg::Solve(const Eigen::MatrixXd& b, double tolerance, int max_iterations, Eigen::MatrixXd* x,
                          bool* converged) {
  Impl& m = *impl_;
  x->setZero(b.rows(), b.cols());
  *converged = true;
  const int rows = m.levels.empty() ? -1 : m.block_mode ? 3 * m.block.n : m.levels.front().n;
  if (!m.structure_valid || b.rows() != rows) {
    *converged = false;
    return 0;
  }
  int iterations = 0;
  auto run = [&](auto k, int column) {
    constexpr int K = decltype(k)::value;
    bool ok = false;
    int taken = 0;
    if (m.block_mode) {
      taken = m.Solve<1>(
          rows, b, column, tolerance, max_iterations, /*give_up_early=*/true, x, &ok,
          [&](const double* in, double* out) { BlockMultiply(m.block, in, out); },
          [&](const double* r, double* z) { m.BlockCycle(r, z); });
    } else {
      taken = m.Solve<K>(
          rows, b, column, tolerance, max_iterations, /*give_up_early=*/false, x, &ok,
          [&](const double* in, double* out) { Multiply<K>(m.levels.front(), in, out); },
          [&](const double* r, double* z) { m.Cycle<K>(0, r, z); });
    }
    iterations = std::max(iterations, taken);
    *converged = *converged && ok;
  };
  // Scalar systems: three columns at a time (one pass over each matrix for
  // all three); block systems: one coupled system per column.
  for (int c = 0; c < b.cols();) {
    if (!m.block_mode && b.cols() - c >= 3) {
      run(std::integral_constant<int, 3>(), c);
      c += 3;
    } else {
      run(std::integral_constant<int, 1>(), c);
      c += 1;
    }
  }
  return iterations;
}

int AggregationAmg::NumLevels() const { return static_cast<int>(impl_->levels.size()); }
int AggregationAmg::LevelSize(int level) const { return impl_->levels[level].n; }

double AggregationAmg::OperatorComplexity() const {
  if (impl_->levels.empty()) return 0.0;
  double total = 0.0;
  for (const Level& level : impl_->levels) total += static_cast<double>(level.NonZeros());
  return total / static_cast<double>(impl_->levels.front().NonZeros());
}

}  // namespace rotation_averaging
