#include "core/linalg/block_sparse_system.h"

#include "core/linalg/block_cholesky.h"

#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <algorithm>
#include <limits>
#include <numeric>
#include <random>

namespace rotation_averaging {
namespace {

// Random symmetric positive definite block system on a ring of 30 blocks.
struct RandomSystem {
  std::vector<std::pair<int, int>> pairs;
  std::vector<std::pair<std::pair<int, int>, Eigen::Matrix3d>> off;
  Eigen::MatrixXd dense;
  Eigen::VectorXd rhs;
};

// `extra` more couplings per block to blocks drawn at random (a factor that
// fills in); none: a ring, whose factor stays thin.
RandomSystem MakeSystem(int blocks, unsigned seed, int extra = 0) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> normal;
  std::uniform_int_distribution<int> pick(0, blocks - 1);
  RandomSystem s;
  s.dense = Eigen::MatrixXd::Zero(3 * blocks, 3 * blocks);
  for (int b = 0; b < blocks; ++b) {
    for (int k = 0; k <= extra; ++k) {
      const int c = k == 0 ? (b + 1) % blocks : pick(rng);
      if (c == b) continue;
      Eigen::Matrix3d m;
      for (int e = 0; e < 9; ++e) m(e / 3, e % 3) = 0.3 * normal(rng);
      s.pairs.emplace_back(b, c);
      s.off.push_back({{b, c}, m});
      s.dense.block<3, 3>(3 * b, 3 * c) += m;
      s.dense.block<3, 3>(3 * c, 3 * b) += m.transpose();
    }
  }
  // Diagonally dominant.
  s.dense += (5.0 + 2.0 * extra) * Eigen::MatrixXd::Identity(3 * blocks, 3 * blocks);
  s.rhs = Eigen::VectorXd::NullaryExpr(3 * blocks, [&]() { return normal(rng); });
  return s;
}

void Fill(const RandomSystem& s, BlockSparseSystem* system, double diagonal_scale = 1.0) {
  system->SetZero();
  const int blocks = system->NumBlocks();
  for (int b = 0; b < blocks; ++b) {
    system->AddBlock(b, b, s.dense.block<3, 3>(3 * b, 3 * b) * diagonal_scale);
  }
  for (const auto& [pair, m] : s.off) system->AddSymmetric(pair.first, pair.second, m);
  system->Rhs() = s.rhs;
}

TEST(BlockSparseSystem, MatchesADenseSolve) {
  const RandomSystem s = MakeSystem(30, 1);
  BlockSparseSystem system(30, s.pairs);
  Fill(s, &system);
  Eigen::VectorXd x;
  ASSERT_TRUE(system.Solve(0.0, 0, &x));
  const Eigen::VectorXd expected = s.dense.ldlt().solve(s.rhs);
  EXPECT_LT((x - expected).norm(), 1e-10 * expected.norm());
  EXPECT_EQ(system.NumFactorizations(), 1);
  // The product with H, from its stored lower triangle, both triangles.
  Eigen::MatrixXd v(90, 2);
  v.col(0) = s.rhs;
  v.col(1) = Eigen::VectorXd::LinSpaced(90, -2.0, 3.0);
  const Eigen::MatrixXd product = system.Multiply(v);
  EXPECT_LT((product - s.dense * v).norm(), 1e-12 * (s.dense * v).norm());
}

// A thin factor (a ring) goes to BlockCholesky, a filled one (random
// couplings) to the supernodal factor where CHOLMOD is built in; both solve
// exactly.
TEST(BlockSparseSystem, ThinAndFilledFactorsBothSolveExactly) {
  for (const int extra : {0, 6}) {
    const RandomSystem s = MakeSystem(200, 11, extra);
    BlockSparseSystem system(200, s.pairs);
    Fill(s, &system);
    Eigen::VectorXd x;
    ASSERT_TRUE(system.Solve(0.0, 0, &x));
    const Eigen::VectorXd expected = s.dense.ldlt().solve(s.rhs);
    EXPECT_LT((x - expected).norm(), 1e-10 * expected.norm()) << "extra couplings " << extra;
    if (extra == 0) {
      EXPECT_STREQ(system.FactorizationMethod(), "block_simplicial");
    } else {
#ifdef ROTAVG_HAVE_CHOLMOD
      EXPECT_STREQ(system.FactorizationMethod(), "supernodal");
#else
      EXPECT_STREQ(system.FactorizationMethod(), "block_simplicial");
#endif
    }
  }
  BlockSparseSystem scalar(200, MakeSystem(200, 12).pairs, /*block_dim=*/1);
  EXPECT_STREQ(scalar.FactorizationMethod(), "simplicial");
}

// The lower block triangle of `dense` laid out as BlockSparseSystem stores
// it (block column c: its block rows r >= c, c first; each 3x3 block in the
// three scalar columns of c), with the block pattern of `pairs`.
struct LowerBlocks {
  std::vector<std::vector<int>> rows_of_column;
  Eigen::SparseMatrix<double> lower;
};

LowerBlocks StoreLowerBlocks(const Eigen::MatrixXd& dense, const std::vector<std::pair<int, int>>& pairs) {
  const int n = static_cast<int>(dense.rows() / 3);
  LowerBlocks out;
  out.rows_of_column.resize(n);
  for (int c = 0; c < n; ++c) out.rows_of_column[c].push_back(c);
  for (const auto& [a, b] : pairs) {
    if (a != b) out.rows_of_column[std::min(a, b)].push_back(std::max(a, b));
  }
  std::vector<Eigen::Triplet<double>> entries;
  for (int c = 0; c < n; ++c) {
    std::vector<int>& rows = out.rows_of_column[c];
    std::sort(rows.begin(), rows.end());
    rows.erase(std::unique(rows.begin(), rows.end()), rows.end());
    for (int r : rows) {
      for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b) entries.emplace_back(3 * r + a, 3 * c + b, dense(3 * r + a, 3 * c + b));
    }
  }
  out.lower.resize(3 * n, 3 * n);
  out.lower.setFromTriplets(entries.begin(), entries.end());
  out.lower.makeCompressed();
  return out;
}

// Any elimination order gives the dense solution, for every right-hand side.
TEST(BlockCholesky, MatchesADenseSolveInAnyOrder) {
  for (const int extra : {0, 2}) {
    const int n = 60;
    const RandomSystem s = MakeSystem(n, 21 + extra, extra);
    LowerBlocks stored = StoreLowerBlocks(s.dense, s.pairs);
    // Every block of the pattern is stored (setFromTriplets keeps zeros).
    ASSERT_EQ(stored.lower.nonZeros(), [&] {
      Eigen::Index count = 0;
      for (const auto& rows : stored.rows_of_column) count += 9 * static_cast<Eigen::Index>(rows.size());
      return count;
    }());
    std::vector<int> shuffled(n);
    std::iota(shuffled.begin(), shuffled.end(), 0);
    std::shuffle(shuffled.begin(), shuffled.end(), std::mt19937(5));
    std::vector<int> reversed(shuffled.size());
    for (int k = 0; k < n; ++k) reversed[k] = n - 1 - k;
    std::vector<int> identity(n);
    std::iota(identity.begin(), identity.end(), 0);
    Eigen::MatrixXd rhs(3 * n, 3);
    rhs.col(0) = s.rhs;
    rhs.col(1) = Eigen::VectorXd::LinSpaced(3 * n, -1.0, 1.0);
    rhs.col(2).setOnes();
    const Eigen::MatrixXd expected = s.dense.ldlt().solve(rhs);
    for (const std::vector<int>* order : {&identity, &reversed, &shuffled}) {
      BlockCholesky factor;
      factor.Analyze(stored.rows_of_column, Eigen::Map<const Eigen::VectorXi>(order->data(), n), stored.lower);
      ASSERT_TRUE(factor.Factorize(stored.lower));
      const Eigen::MatrixXd x = factor.Solve(rhs);
      EXPECT_LT((x - expected).norm(), 1e-10 * expected.norm()) << "extra couplings " << extra;
      EXPECT_GE(factor.NumFactorBlocks(), static_cast<std::size_t>(n + s.off.size() / 2));
    }
    // A new matrix on the same pattern reuses the analysis.
    BlockCholesky factor;
    factor.Analyze(stored.rows_of_column, Eigen::Map<const Eigen::VectorXi>(shuffled.data(), n), stored.lower);
    ASSERT_TRUE(factor.Factorize(stored.lower));
    const Eigen::MatrixXd scaled = 2.0 * s.dense;
    const LowerBlocks stored2 = StoreLowerBlocks(scaled, s.pairs);
    ASSERT_TRUE(factor.Factorize(stored2.lower));
    EXPECT_LT((factor.Solve(rhs) - 0.5 * expected).norm(), 1e-10 * expected.norm());
  }
}

TEST(BlockCholesky, IndefiniteOrNonFiniteMatricesAreRefused) {
  const int n = 20;
  const RandomSystem s = MakeSystem(n, 31);
  std::vector<int> identity(n);
  std::iota(identity.begin(), identity.end(), 0);
  const Eigen::Map<const Eigen::VectorXi> order(identity.data(), n);
  Eigen::MatrixXd indefinite = s.dense;
  indefinite.block<3, 3>(3 * 7, 3 * 7) -= 20.0 * Eigen::Matrix3d::Identity();
  LowerBlocks stored = StoreLowerBlocks(indefinite, s.pairs);
  BlockCholesky factor;
  factor.Analyze(stored.rows_of_column, order, stored.lower);
  EXPECT_FALSE(factor.Factorize(stored.lower));
  Eigen::MatrixXd not_finite = s.dense;
  not_finite(3 * 4 + 1, 3 * 4 + 1) = std::numeric_limits<double>::quiet_NaN();
  stored = StoreLowerBlocks(not_finite, s.pairs);
  EXPECT_FALSE(factor.Factorize(stored.lower));
  stored = StoreLowerBlocks(s.dense, s.pairs);
  EXPECT_TRUE(factor.Factorize(stored.lower));
}

TEST(BlockSparseSystem, ReusedFactorAsPreconditionerGivesTheNewSolution) {
  const RandomSystem s = MakeSystem(30, 2);
  BlockSparseSystem system(30, s.pairs);
  Fill(s, &system);
  Eigen::VectorXd x;
  ASSERT_TRUE(system.Solve(0.0, 0, &x));
  // A slightly different matrix (as between IRLS iterations): solved by PCG.
  Fill(s, &system, 1.05);
  ASSERT_TRUE(system.Solve(0.0, 0, &x));
  Eigen::MatrixXd changed = s.dense;
  for (int b = 0; b < 30; ++b) changed.block<3, 3>(3 * b, 3 * b) *= 1.05;
  const Eigen::VectorXd expected = changed.ldlt().solve(s.rhs);
  EXPECT_LT((x - expected).norm(), 1e-4 * expected.norm());
  EXPECT_EQ(system.NumFactorizations(), 1);
  EXPECT_EQ(system.NumPreconditionedSolves(), 1);
}

TEST(BlockSparseSystem, InverseDiagonalBlocksMatchADenseInverse) {
  const RandomSystem s = MakeSystem(30, 3);
  BlockSparseSystem system(30, s.pairs);
  Fill(s, &system);
  std::vector<Eigen::Matrix3d> blocks;
  ASSERT_TRUE(system.InverseDiagonalBlocks(&blocks));
  const Eigen::MatrixXd inverse = s.dense.inverse();
  for (int b = 0; b < 30; ++b) {
    EXPECT_LT((blocks[b] - inverse.block<3, 3>(3 * b, 3 * b)).norm(), 1e-9 * inverse.norm()) << "block " << b;
  }
  // Beyond the work budget it declines instead of taking long.
  EXPECT_FALSE(system.InverseDiagonalBlocks(&blocks, 1.0));
}

TEST(BlockSparseSystem, SingularSystemIsRegularisedNotFatal) {
  // Block 1 has no information at all (a view whose edges all have weight 0).
  BlockSparseSystem system(3, {{0, 1}, {1, 2}});
  system.SetZero();
  system.AddBlock(0, 0, Eigen::Matrix3d::Identity());
  system.AddBlock(2, 2, Eigen::Matrix3d::Identity());
  system.Rhs().setOnes();
  Eigen::VectorXd x;
  double lambda = 0.0;
  ASSERT_TRUE(system.Solve(0.0, 6, &x, &lambda));
  EXPECT_GT(lambda, 0.0);
  EXPECT_TRUE(x.allFinite());
  // Without retries it reports failure instead of returning garbage.
  BlockSparseSystem strict(3, {{0, 1}, {1, 2}});
  strict.SetZero();
  strict.AddBlock(0, 0, Eigen::Matrix3d::Identity());
  strict.Rhs().setOnes();
  EXPECT_FALSE(strict.Solve(0.0, 0, &x));
}

TEST(BlockSparseSystem, NonFiniteInputIsRejected) {
  BlockSparseSystem system(2, {{0, 1}});
  system.SetZero();
  system.AddBlock(0, 0, Eigen::Matrix3d::Identity());
  system.AddBlock(1, 1, Eigen::Matrix3d::Identity());
  system.Rhs()(2, 0) = std::nan("");
  Eigen::VectorXd x;
  EXPECT_FALSE(system.Solve(0.0, 3, &x));
}

// Scalar systems larger than kScalarCholmodMinBlocks take CHOLMOD (and, past
// kMetisMinRows, a METIS ordering); the answer must not change with the backend,
// also when the factor of an earlier matrix preconditions the next solve.
TEST(BlockSparseSystem, LargeScalarLaplacianSolvesExactly) {
  const int side = 130;  // 16,900 blocks on a grid: CHOLMOD with METIS
  const int n = side * side;
  ASSERT_GT(n, BlockSparseSystem::kScalarCholmodMinBlocks);
  ASSERT_GT(n, BlockSparseSystem::kMetisMinRows);
  std::vector<std::pair<int, int>> pairs;
  for (int r = 0; r < side; ++r) {
    for (int c = 0; c < side; ++c) {
      if (c + 1 < side) pairs.emplace_back(r * side + c, r * side + c + 1);
      if (r + 1 < side) pairs.emplace_back(r * side + c, (r + 1) * side + c);
    }
  }
  std::mt19937 rng(4);
  std::uniform_real_distribution<double> weight(0.5, 2.0);
  std::normal_distribution<double> normal;
  BlockSparseSystem system(n, pairs, 1);
  Eigen::SparseMatrix<double> reference(n, n);
  for (int pass = 0; pass < 2; ++pass) {  // the second pass reuses the first factor as a preconditioner
    system.SetZero();
    std::vector<Eigen::Triplet<double>> triplets;
    for (const auto& [a, b] : pairs) {
      const double w = weight(rng);
      system.AddScalarAt(a, system.Locate(a, a), w);
      system.AddScalarAt(b, system.Locate(b, b), w);
      system.AddScalarAt(a, system.Locate(b, a), -w);
      triplets.emplace_back(a, a, w);
      triplets.emplace_back(b, b, w);
      triplets.emplace_back(a, b, -w);
      triplets.emplace_back(b, a, -w);
    }
    for (int v = 0; v < n; ++v) {  // anchor: a Laplacian plus a small diagonal
      system.AddScalarAt(v, system.Locate(v, v), 0.01);
      triplets.emplace_back(v, v, 0.01);
    }
    reference.setFromTriplets(triplets.begin(), triplets.end());
    for (int v = 0; v < n; ++v) system.Rhs()(v, 0) = normal(rng);
    const Eigen::VectorXd b = system.Rhs().col(0);
    Eigen::VectorXd x;
    ASSERT_TRUE(system.Solve(0.0, 2, &x));
    EXPECT_LT((reference * x - b).norm(), 1e-6 * b.norm()) << "pass " << pass;
  }
  EXPECT_EQ(system.NumFactorizations() + system.NumPreconditionedSolves(), 2);
}

// The Laplacian's three coordinates go through the preconditioned solve
// together: each column must reach the tolerance on its own (a zero column
// included), and a matrix the old factor no longer describes is factorised
// again rather than iterated on.
TEST(BlockSparseSystem, PreconditionedSolveTakesEveryRightHandSideToTheTolerance) {
  const int n = 400;  // a ring with chords, scalar blocks
  std::vector<std::pair<int, int>> pairs;
  for (int v = 0; v < n; ++v) {
    pairs.emplace_back(v, (v + 1) % n);
    pairs.emplace_back(v, (v + 37) % n);
  }
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> weight(0.5, 2.0);
  std::normal_distribution<double> normal;
  std::vector<double> weights(pairs.size());
  for (double& w : weights) w = weight(rng);
  Eigen::MatrixXd rhs(n, 3);
  for (int v = 0; v < n; ++v) rhs.row(v) << normal(rng), 0.0, 1e-6 * normal(rng);
  BlockSparseSystem system(n, pairs, 1, 3);
  Eigen::MatrixXd dense;
  auto fill = [&](double scale_of_first_half) {
    system.SetZero();
    dense = 0.01 * Eigen::MatrixXd::Identity(n, n);
    for (std::size_t k = 0; k < pairs.size(); ++k) {
      const auto [a, b] = pairs[k];
      const double w = weights[k] * (a < n / 2 ? scale_of_first_half : 1.0);
      const int hi = std::max(a, b), lo = std::min(a, b);
      system.AddScalarAt(hi, 0, w);
      system.AddScalarAt(lo, 0, w);
      system.AddScalarAt(lo, system.Locate(hi, lo), -w);
      dense(a, a) += w;
      dense(b, b) += w;
      dense(a, b) -= w;
      dense(b, a) -= w;
    }
    for (int v = 0; v < n; ++v) system.AddScalarAt(v, 0, 0.01);
    system.Rhs() = rhs;
  };
  auto relative_residuals = [&](const Eigen::MatrixXd& x) {
    Eigen::Vector3d out;
    for (int c = 0; c < 3; ++c) {
      const double b = rhs.col(c).norm();
      out(c) = b > 0.0 ? (dense * x.col(c) - rhs.col(c)).norm() / b : (dense * x.col(c)).norm();
    }
    return out;
  };
  Eigen::MatrixXd x;
  fill(1.0);
  ASSERT_TRUE(system.Solve(0.0, 0, &x));
  EXPECT_EQ(system.NumFactorizations(), 1);
  for (const double tolerance : {1e-8, 1e-2}) {
    system.SetPcgTolerance(tolerance);
    fill(1.05);  // a small change, as between IRLS iterations
    ASSERT_TRUE(system.Solve(0.0, 0, &x));
    EXPECT_EQ(system.NumFactorizations(), 1) << tolerance;
    const Eigen::Vector3d residuals = relative_residuals(x);
    EXPECT_LE(residuals.maxCoeff(), tolerance) << residuals.transpose();
    EXPECT_EQ(x.col(1).norm(), 0.0);
  }
  EXPECT_EQ(system.NumPreconditionedSolves(), 2);
  // Half the weights a hundred times larger: the old factor would need far
  // more iterations than a new factorisation costs.
  system.SetPcgTolerance(1e-8);
  fill(100.0);
  ASSERT_TRUE(system.Solve(0.0, 0, &x));
  EXPECT_EQ(system.NumFactorizations(), 2);
  EXPECT_LE(system.LastPcgIterations(), 3);
  EXPECT_LE(relative_residuals(x).maxCoeff(), 1e-8);
}

}  // namespace
}  // namespace rotation_averaging
