#include "core/linalg/aggregation_amg.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include <cmath>
#include <limits>
#include <random>
#include <vector>

#include "core/linalg/block_sparse_system.h"
#include "rotation_averaging/util/random_draws.h"

namespace rotation_averaging {
namespace {

// A weighted graph Laplacian with one node grounded (the gauge view's
// edges kept on its neighbours' diagonals, its row removed), as the IRLS
// solver builds it: nodes on a side x side grid joined to the nodes within
// `reach` cells, weights log-uniform over `decades`.
struct Laplacian {
  int n = 0;
  std::vector<std::pair<int, int>> pairs;
  std::vector<double> weights;
  Eigen::SparseMatrix<double> lower;  // lower triangle, compressed columns
  Eigen::SparseMatrix<double> full;
};

void Assemble(Laplacian* l) {
  std::vector<Eigen::Triplet<double>> lower, full;
  std::vector<double> diagonal(l->n + 1, 0.0);
  for (std::size_t k = 0; k < l->pairs.size(); ++k) {
    const auto [a, b] = l->pairs[k];
    const double w = l->weights[k];
    diagonal[a] += w;
    diagonal[b] += w;
    // Node n is the grounded gauge: only its neighbours' diagonals see it.
    if (a == l->n || b == l->n) continue;
    lower.emplace_back(std::max(a, b), std::min(a, b), -w);
    full.emplace_back(a, b, -w);
    full.emplace_back(b, a, -w);
  }
  for (int i = 0; i < l->n; ++i) {
    lower.emplace_back(i, i, diagonal[i]);
    full.emplace_back(i, i, diagonal[i]);
  }
  l->lower.resize(l->n, l->n);
  l->lower.setFromTriplets(lower.begin(), lower.end());
  l->lower.makeCompressed();
  l->full.resize(l->n, l->n);
  l->full.setFromTriplets(full.begin(), full.end());
}

Laplacian GridLaplacian(int side, int reach, double decades, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> exponent(-0.5 * decades, 0.5 * decades);
  Laplacian l;
  l.n = side * side - 1;  // the last grid node is the gauge
  for (int y = 0; y < side; ++y) {
    for (int x = 0; x < side; ++x) {
      for (int dy = 0; dy <= reach; ++dy) {
        for (int dx = -reach; dx <= reach; ++dx) {
          if ((dy == 0 && dx <= 0) || x + dx < 0 || x + dx >= side || y + dy >= side) continue;
          // The right and lower neighbours (connected, no isolated node) and
          // about a third of the rest of the window.
          const bool lattice = (dy == 0 && dx == 1) || (dy == 1 && dx == 0);
          if (!lattice && rng() % 3 != 0) continue;
          l.pairs.emplace_back(y * side + x, (y + dy) * side + x + dx);
          l.weights.push_back(std::pow(10.0, exponent(rng)));
        }
      }
    }
  }
  Assemble(&l);
  return l;
}

Eigen::MatrixXd RandomRhs(int n, int columns, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> normal;
  return Eigen::MatrixXd::NullaryExpr(n, columns, [&]() { return normal(rng); });
}

double MaxRelativeResidual(const Eigen::SparseMatrix<double>& a, const Eigen::MatrixXd& x, const Eigen::MatrixXd& b) {
  double worst = 0.0;
  for (int c = 0; c < b.cols(); ++c) {
    const double norm = b.col(c).norm();
    const double r = (a * x.col(c) - b.col(c)).norm();
    worst = std::max(worst, norm > 0.0 ? r / norm : r);
  }
  return worst;
}

// The 3x3-block counterpart, as the IRLS solver builds it for anisotropic
// information: each edge of a grid Laplacian gets a symmetric positive
// definite G = w Q diag(l) Q^T with a random rotation Q and per-axis factors
// l spread over `anisotropy` (lambda_max / lambda_min up to it); the matrix is
// the matrix-weighted Laplacian (G on both diagonal blocks, -G off the
// diagonal), the gauge node grounded.
struct BlockLaplacian {
  int n = 0;
  std::vector<std::pair<int, int>> pairs;
  std::vector<Eigen::Matrix3d> g;
  Eigen::SparseMatrix<double> lower;  // lower block triangle, full diagonal blocks, compressed columns
  Eigen::SparseMatrix<double> full;
};

BlockLaplacian GridBlockLaplacian(int side, int reach, double decades, double anisotropy, unsigned seed) {
  const Laplacian scalar = GridLaplacian(side, reach, decades, seed);
  std::mt19937 rng(seed + 100);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  std::normal_distribution<double> normal;
  BlockLaplacian l;
  l.n = scalar.n;
  l.pairs = scalar.pairs;
  std::vector<Eigen::Matrix3d> diagonal(l.n + 1, Eigen::Matrix3d::Zero());
  std::vector<Eigen::Triplet<double>> lower, full;
  auto add = [](std::vector<Eigen::Triplet<double>>* t, int r, int c, const Eigen::Matrix3d& m) {
    for (int a = 0; a < 3; ++a)
      for (int b = 0; b < 3; ++b) t->emplace_back(3 * r + a, 3 * c + b, m(a, b));
  };
  for (std::size_t k = 0; k < l.pairs.size(); ++k) {
    const Eigen::Quaterniond q =
        DrawQuaternion(rng, normal).normalized();
    const Eigen::Vector3d exponents = DrawVector3(rng, unit);
    const Eigen::Vector3d axes(std::pow(anisotropy, exponents.x()), std::pow(anisotropy, exponents.y()),
                               std::pow(anisotropy, exponents.z()));
    const Eigen::Matrix3d g = scalar.weights[k] * q.toRotationMatrix() * axes.asDiagonal() *
                              q.toRotationMatrix().transpose() / axes.maxCoeff();
    l.g.push_back(g);
    const auto [a, b] = l.pairs[k];
    diagonal[a] += g;
    diagonal[b] += g;
    if (a == l.n || b == l.n) continue;
    add(&lower, std::max(a, b), std::min(a, b), -g);
    add(&full, a, b, -g);
    add(&full, b, a, -g);
  }
  for (int i = 0; i < l.n; ++i) {
    add(&lower, i, i, diagonal[i]);
    add(&full, i, i, diagonal[i]);
  }
  l.lower.resize(3 * l.n, 3 * l.n);
  l.lower.setFromTriplets(lower.begin(), lower.end());
  l.lower.makeCompressed();
  l.full.resize(3 * l.n, 3 * l.n);
  l.full.setFromTriplets(full.begin(), full.end());
  return l;
}

// Solves to a loose (1e-2) and a tight (1e-8) relative residual within the
// given iterations.
void ExpectSolvesToEachTolerance(AggregationAmg* amg, const Eigen::SparseMatrix<double>& full, const Eigen::MatrixXd& b,
                                 int loose_iterations, int tight_iterations) {
  for (const double tolerance : {1e-2, 1e-8}) {
    Eigen::MatrixXd x;
    bool converged = false;
    const int iterations = amg->Solve(b, tolerance, 100, &x, &converged);
    EXPECT_TRUE(converged) << tolerance;
    EXPECT_LE(MaxRelativeResidual(full, x, b), tolerance) << tolerance;
    EXPECT_LE(iterations, tolerance > 1e-3 ? loose_iterations : tight_iterations) << tolerance;
  }
}

TEST(AggregationAmg, SolvesAWeightedGridLaplacianToTheTolerance) {
  // 4 decades of weights, as IRLS weights times covariance information.
  const Laplacian l = GridLaplacian(90, 2, 4.0, 1);
  AggregationAmg amg;
  ASSERT_TRUE(amg.Setup(l.lower));
  EXPECT_GE(amg.NumLevels(), 3);
  EXPECT_LT(amg.LevelSize(1), l.n / 3);  // aggregates of about four
  EXPECT_LT(amg.OperatorComplexity(), 2.0);
  // A multigrid preconditioner: iterations do not grow like sqrt(condition).
  ExpectSolvesToEachTolerance(&amg, l.full, RandomRhs(l.n, 3, 2), 10, 40);
}

TEST(AggregationAmg, TakesAnyNumberOfColumnsAndZeroColumns) {
  const Laplacian l = GridLaplacian(40, 1, 2.0, 3);
  AggregationAmg amg;
  ASSERT_TRUE(amg.Setup(l.lower));
  for (const int columns : {1, 2, 3, 4}) {
    Eigen::MatrixXd b = RandomRhs(l.n, columns, 4);
    b.col(0).setZero();
    Eigen::MatrixXd x;
    bool converged = false;
    amg.Solve(b, 1e-9, 100, &x, &converged);
    EXPECT_TRUE(converged) << columns;
    EXPECT_EQ(x.cols(), columns);
    EXPECT_EQ(x.col(0).norm(), 0.0) << columns;
    EXPECT_LE(MaxRelativeResidual(l.full, x, b), 1e-9) << columns;
  }
  // An iteration cap that is too small is reported, not hidden.
  Eigen::MatrixXd x;
  bool converged = true;
  EXPECT_EQ(amg.Solve(RandomRhs(l.n, 3, 5), 1e-12, 1, &x, &converged), 1);
  EXPECT_FALSE(converged);
}

TEST(AggregationAmg, NearlyFloatingClustersDoNotStallIt) {
  // Views whose edges are mostly outliers (weight ~0) hang on a few weak
  // inliers: clusters of strongly tied nodes joined to the rest 1e-4 times
  // more weakly. Merging such a cluster into a strongly coupled neighbour
  // pair leaves its motion to nothing; the solve would stall near 1e-4.
  Laplacian l = GridLaplacian(60, 2, 1.0, 6);
  std::mt19937 rng(7);
  const int first = l.n + 1;  // new nodes after the gauge: renumber below
  std::vector<std::pair<int, int>> pairs;
  std::vector<double> weights;
  const int gauge = l.n;
  int next = first;
  for (int c = 0; c < 200; ++c) {
    const int a = next++, b = next++, anchor = static_cast<int>(rng() % gauge);
    pairs.push_back({a, b});
    weights.push_back(1e3);
    pairs.push_back({a, anchor});
    weights.push_back(1e-1);
    pairs.push_back({b, static_cast<int>(rng() % gauge)});
    weights.push_back(1e-1);
  }
  // Renumber so that the gauge stays last.
  auto map = [&](int v) { return v == gauge ? next - 1 : (v >= first ? v - 1 : v); };
  for (auto& p : l.pairs) p = {map(p.first), map(p.second)};
  for (std::size_t k = 0; k < pairs.size(); ++k) {
    l.pairs.push_back({map(pairs[k].first), map(pairs[k].second)});
    l.weights.push_back(weights[k]);
  }
  l.n = next - 1;
  Assemble(&l);
  AggregationAmg amg;
  ASSERT_TRUE(amg.Setup(l.lower));
  const Eigen::MatrixXd b = RandomRhs(l.n, 3, 8);
  Eigen::MatrixXd x;
  bool converged = false;
  const int iterations = amg.Solve(b, 1e-8, 100, &x, &converged);
  EXPECT_TRUE(converged);
  EXPECT_LE(iterations, 40);
  EXPECT_LE(MaxRelativeResidual(l.full, x, b), 1e-8);
}

TEST(AggregationAmg, ReusedAggregatesFollowNewWeights) {
  Laplacian l = GridLaplacian(70, 2, 2.0, 9);
  AggregationAmg amg;
  ASSERT_TRUE(amg.Setup(l.lower));
  const Eigen::MatrixXd b = RandomRhs(l.n, 3, 10);
  Eigen::MatrixXd fresh_x, reused_x;
  bool converged = false;
  const int fresh = amg.Solve(b, 1e-8, 100, &fresh_x, &converged);
  ASSERT_TRUE(converged);
  // The same matrix through the kept aggregates: the same hierarchy.
  ASSERT_TRUE(amg.Setup(l.lower, /*reuse_aggregates=*/true));
  EXPECT_EQ(amg.Solve(b, 1e-8, 100, &reused_x, &converged), fresh);
  EXPECT_LT((reused_x - fresh_x).norm(), 1e-12 * fresh_x.norm());
  // New weights (as the next IRLS iteration's): the kept aggregates still
  // precondition, and the solution is that of the new matrix.
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> factor(0.5, 2.0);
  for (double& w : l.weights) w *= factor(rng);
  Assemble(&l);
  ASSERT_TRUE(amg.Setup(l.lower, /*reuse_aggregates=*/true));
  EXPECT_LE(amg.Solve(b, 1e-8, 100, &reused_x, &converged), 2 * fresh + 5);
  EXPECT_TRUE(converged);
  EXPECT_LE(MaxRelativeResidual(l.full, reused_x, b), 1e-8);
}

TEST(AggregationAmg, RefusesMatricesItCannotPrecondition) {
  Laplacian l = GridLaplacian(20, 1, 1.0, 12);
  AggregationAmg amg;
  Eigen::SparseMatrix<double> bad = l.lower;
  bad.coeffRef(5, 5) = 0.0;
  EXPECT_FALSE(amg.Setup(bad));
  bad = l.lower;
  bad.coeffRef(7, 7) = -1.0;
  EXPECT_FALSE(amg.Setup(bad));
  bad = l.lower;
  bad.valuePtr()[3] = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(amg.Setup(bad));
  EXPECT_FALSE(amg.Setup(Eigen::SparseMatrix<double>()));
  // And recovers on a good one, with the reuse request ignored after a
  // failure.
  EXPECT_TRUE(amg.Setup(l.lower, /*reuse_aggregates=*/true));
  Eigen::MatrixXd x;
  bool converged = false;
  const Eigen::MatrixXd b = RandomRhs(l.n, 3, 13);
  amg.Solve(b, 1e-10, 100, &x, &converged);
  EXPECT_TRUE(converged);
  EXPECT_LE(MaxRelativeResidual(l.full, x, b), 1e-10);
}

TEST(AggregationAmg, BlockSparseSystemSolvesWithItAndFallsBackToTheFactor) {
  const Laplacian l = GridLaplacian(50, 2, 3.0, 14);
  auto fill = [&](BlockSparseSystem* system) {
    system->SetZero();
    for (std::size_t k = 0; k < l.pairs.size(); ++k) {
      const auto [a, b] = l.pairs[k];
      const double w = l.weights[k];
      if (a < l.n) system->AddScalarAt(a, 0, w);
      if (b < l.n) system->AddScalarAt(b, 0, w);
      if (a < l.n && b < l.n) system->AddScalarAt(std::min(a, b), system->Locate(std::max(a, b), std::min(a, b)), -w);
    }
    system->Rhs() = RandomRhs(l.n, 3, 15);
  };
  std::vector<std::pair<int, int>> pairs;
  for (const auto& p : l.pairs)
    if (p.first < l.n && p.second < l.n) pairs.push_back(p);
  BlockSparseSystem multigrid(l.n, pairs, 1, 3), factor(l.n, pairs, 1, 3);
  multigrid.SetUseMultigrid(true);
  for (BlockSparseSystem* s : {&multigrid, &factor}) {
    s->SetPcgTolerance(1e-9);
    fill(s);
  }
  Eigen::MatrixXd x_multigrid, x_factor;
  ASSERT_TRUE(multigrid.Solve(0.0, 0, &x_multigrid));
  ASSERT_TRUE(factor.Solve(0.0, 0, &x_factor));
  EXPECT_EQ(multigrid.NumMultigridSolves(), 1);
  EXPECT_EQ(multigrid.NumFactorizations(), 0);
  EXPECT_EQ(factor.NumFactorizations(), 1);
  EXPECT_LT((x_multigrid - x_factor).norm(), 1e-6 * x_factor.norm());
  // A tolerance multigrid cannot reach within its iteration cap: the
  // factorisation answers.
  multigrid.SetPcgTolerance(1e-300);
  fill(&multigrid);
  ASSERT_TRUE(multigrid.Solve(0.0, 0, &x_multigrid));
  EXPECT_EQ(multigrid.NumMultigridSolves(), 1);
  EXPECT_EQ(multigrid.NumFactorizations(), 1);
  EXPECT_LT((x_multigrid - x_factor).norm(), 1e-9 * x_factor.norm());
}

}  // namespace
}  // namespace rotation_averaging

namespace rotation_averaging {
namespace {

TEST(AggregationAmg, SolvesAMatrixWeightedLaplacianOfAnisotropicBlocks) {
  // Information anisotropic up to 100x per edge (standard deviations 10x
  // apart), weights over 3 decades.
  const BlockLaplacian l = GridBlockLaplacian(60, 2, 3.0, 100.0, 21);
  AggregationAmg amg;
  ASSERT_TRUE(amg.SetupBlocks(l.lower));
  EXPECT_GE(amg.NumLevels(), 3);
  EXPECT_EQ(amg.LevelSize(0), l.n);  // the surrogate: one node per block row
  const Eigen::MatrixXd b = RandomRhs(3 * l.n, 2, 22);
  ExpectSolvesToEachTolerance(&amg, l.full, b, 12, 50);
  // Isotropic blocks (G = w I): as few iterations as the scalar Laplacian.
  const BlockLaplacian iso = GridBlockLaplacian(60, 2, 3.0, 1.0, 21);
  ASSERT_TRUE(amg.SetupBlocks(iso.lower));
  Eigen::MatrixXd x;
  bool converged = false;
  EXPECT_LE(amg.Solve(RandomRhs(3 * iso.n, 1, 23), 1e-8, 100, &x, &converged), 40);
  EXPECT_TRUE(converged);
  // Kept aggregates after new values of the same pattern.
  BlockLaplacian changed = GridBlockLaplacian(60, 2, 3.0, 100.0, 21);
  for (int k = 0; k < changed.lower.nonZeros(); ++k) changed.lower.valuePtr()[k] *= 2.0;
  ASSERT_TRUE(amg.SetupBlocks(l.lower));
  ASSERT_TRUE(amg.SetupBlocks(changed.lower, /*reuse_aggregates=*/true));
  amg.Solve(b, 1e-8, 100, &x, &converged);
  EXPECT_TRUE(converged);
  EXPECT_LE(MaxRelativeResidual(l.full, 2.0 * x, b), 1e-8);
}

// Iterations to a relative residual of 1e-8 with one, two and three
// smoothing sweeps each way (block sweeps for a block system), each solve
// checked against the tolerance.
std::vector<int> IterationsBySweeps(const Eigen::SparseMatrix<double>& lower, const Eigen::SparseMatrix<double>& full,
                                    bool blocks, const Eigen::MatrixXd& b) {
  std::vector<int> iterations;
  for (const int sweeps : {1, 2, 3}) {
    SCOPED_TRACE("sweeps " + std::to_string(sweeps));
    AggregationAmg::Options options;
    (blocks ? options.block_smoothing_sweeps : options.smoothing_sweeps) = sweeps;
    AggregationAmg amg(options);
    EXPECT_TRUE(blocks ? amg.SetupBlocks(lower) : amg.Setup(lower));
    Eigen::MatrixXd x;
    bool converged = false;
    iterations.push_back(amg.Solve(b, 1e-8, 100, &x, &converged));
    EXPECT_TRUE(converged);
    EXPECT_LE(MaxRelativeResidual(full, x, b), 1e-8);
  }
  return iterations;
}

TEST(AggregationAmg, AnyNumberOfSmoothingSweepsSolvesTheSystem) {
  // The last forward sweep leaves the residual: after the sweep from zero
  // (one sweep) or after in-place sweeps (two, three).
  const Laplacian l = GridLaplacian(50, 2, 4.0, 33);
  const std::vector<int> iterations = IterationsBySweeps(l.lower, l.full, false, RandomRhs(l.n, 3, 34));
  // A stronger smoother: no more iterations than a weaker one.
  EXPECT_LE(iterations[1], iterations[0]);
  EXPECT_LE(iterations[2], iterations[1]);
}

TEST(AggregationAmg, MoreBlockSmoothingSweepsSolveTheSameSystem) {
  // The in-place forward sweep and the residual after it, which one sweep
  // from zero does not use.
  const BlockLaplacian l = GridBlockLaplacian(40, 2, 3.0, 100.0, 31);
  const std::vector<int> iterations = IterationsBySweeps(l.lower, l.full, true, RandomRhs(3 * l.n, 1, 32));
  // A second sweep each way takes a quarter fewer iterations (23 to 16
  // here; 19 when the in-place forward sweep ignores the blocks right of the
  // diagonal), a third no more.
  EXPECT_LE(iterations[1], 3 * iterations[0] / 4);
  EXPECT_LE(iterations[2], iterations[1]);
}

TEST(AggregationAmg, RefusesBlockMatricesItCannotPrecondition) {
  const BlockLaplacian l = GridBlockLaplacian(30, 1, 1.0, 10.0, 24);
  AggregationAmg amg;
  // Not of 3x3 block form: a scalar Laplacian, and a row count that is no
  // multiple of three.
  EXPECT_FALSE(amg.SetupBlocks(GridLaplacian(30, 1, 1.0, 24).lower));
  EXPECT_FALSE(amg.SetupBlocks(Eigen::SparseMatrix<double>(l.lower.topLeftCorner(3 * l.n - 1, 3 * l.n - 1))));
  // A diagonal block that is not positive definite, a NaN.
  Eigen::SparseMatrix<double> bad = l.lower;
  bad.coeffRef(4, 4) = -1.0;
  EXPECT_FALSE(amg.SetupBlocks(bad));
  bad = l.lower;
  bad.valuePtr()[10] = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(amg.SetupBlocks(bad));
  // Too small to coarsen: a factorisation is the better solver.
  EXPECT_FALSE(amg.SetupBlocks(GridBlockLaplacian(12, 1, 1.0, 10.0, 25).lower));
  // A failed setup leaves nothing to solve with, and a good one recovers.
  Eigen::MatrixXd x;
  bool converged = true;
  amg.Solve(RandomRhs(3 * l.n, 1, 26), 1e-6, 100, &x, &converged);
  EXPECT_FALSE(converged);
  ASSERT_TRUE(amg.SetupBlocks(l.lower, /*reuse_aggregates=*/true));
  const Eigen::MatrixXd b = RandomRhs(3 * l.n, 1, 26);
  amg.Solve(b, 1e-10, 100, &x, &converged);
  EXPECT_TRUE(converged);
  EXPECT_LE(MaxRelativeResidual(l.full, x, b), 1e-10);
}

TEST(AggregationAmg, BlockSparseSystemSolvesBlocksWithItAsWithTheFactor) {
  const BlockLaplacian l = GridBlockLaplacian(50, 2, 2.0, 30.0, 27);
  std::vector<std::pair<int, int>> pairs;
  for (const auto& p : l.pairs)
    if (p.first < l.n && p.second < l.n) pairs.push_back(p);
  BlockSparseSystem multigrid(l.n, pairs), factor(l.n, pairs);
  multigrid.SetUseMultigrid(true);
  const Eigen::MatrixXd rhs = RandomRhs(3 * l.n, 1, 28);
  for (BlockSparseSystem* s : {&multigrid, &factor}) {
    s->SetPcgTolerance(1e-9);
    s->SetZero();
    for (std::size_t k = 0; k < l.pairs.size(); ++k) {
      const auto [a, b] = l.pairs[k];
      if (a < l.n) s->AddBlock(a, a, l.g[k]);
      if (b < l.n) s->AddBlock(b, b, l.g[k]);
      if (a < l.n && b < l.n) s->AddSymmetric(a, b, -l.g[k]);
    }
    s->Rhs() = rhs;
  }
  Eigen::MatrixXd x_multigrid, x_factor;
  ASSERT_TRUE(multigrid.Solve(0.0, 0, &x_multigrid));
  ASSERT_TRUE(factor.Solve(0.0, 0, &x_factor));
  EXPECT_EQ(multigrid.NumMultigridSolves(), 1);
  EXPECT_EQ(multigrid.NumFactorizations(), 0);
  EXPECT_LT((x_multigrid - x_factor).norm(), 1e-6 * x_factor.norm());
  EXPECT_LE(MaxRelativeResidual(l.full, x_multigrid, rhs), 1e-9);
}

}  // namespace
}  // namespace rotation_averaging
