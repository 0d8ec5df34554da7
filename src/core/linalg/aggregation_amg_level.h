// Internal to the core: the levels of AggregationAmg's hierarchy and the
// coarsening that builds them (aggregation_amg_coarsening.cpp), shared with
// the cycles and the set-up (aggregation_amg.cpp).
#ifndef ROTATION_AVERAGING_SRC_CORE_LINALG_AGGREGATION_AMG_LEVEL_H_
#define ROTATION_AVERAGING_SRC_CORE_LINALG_AGGREGATION_AMG_LEVEL_H_

#include <cstddef>
#include <limits>
#include <vector>

namespace rotation_averaging {
namespace amg {

constexpr int kUnassigned = -2;
constexpr int kSkip = std::numeric_limits<int>::min();  // entry with an end outside every aggregate

// One level: off-diagonal entries of every row in compressed rows (the full
// symmetric pattern) and the diagonal apart.
struct Level {
  int n = 0;
  std::vector<int> ptr, col;
  std::vector<double> val, diag, inv_diag;
  std::vector<int> aggregate;  // node -> node of the next level; -1: smoothed only
  // Per off-diagonal entry: its slot in the next level's entries, -1 - a for
  // the diagonal of aggregate a, or kSkip (see Impl::UpdateNumeric).
  std::vector<int> entry_target;
  // The cycle's copy of the entries left of the diagonal, row by row (from
  // lower_ptr[i]; lower_source: their positions in col / val). The passes
  // of the cycle apply each entry to both of its nodes, gathering for one
  // and scattering to the other, so they stream half the entries.
  std::vector<int> lower_ptr, lower_col, lower_source;
  std::vector<double> lower_val;
  // Work vectors, K values per node (row-major blocks).
  std::vector<double> residual, sum;
  // Coarse-correction work on the next level's nodes.
  std::vector<double> rc, c1, v1, rt, c2, v2;
  std::size_t NonZeros() const { return col.size() + static_cast<std::size_t>(n); }
};

// Pairwise matching along the strongest couplings; returns the number of
// groups, group[i] = -1 for rows left out (strongly diagonally dominant).
int PairwiseMatch(const Level& level, double strong_coupling, double dominance, bool relaxed,
                  std::vector<int>* group_out);

// The nodes of each aggregate (counting sort): members[start[a] ..
// start[a + 1]) in ascending order; nodes outside every aggregate left out.
void AggregateMembers(const std::vector<int>& aggregate, int num_aggregates, std::vector<int>* start_out,
                      std::vector<int>* members_out);

// coarse = P^T A P for the piecewise-constant P of `aggregate`.
void Galerkin(const Level& fine, const std::vector<int>& aggregate, int num_coarse, Level* coarse_out);

// The entries left of the diagonal of every row (Level::lower_ptr ...),
// indexed on a new pattern (IndexLower), their values on every setup
// (UpdateLower).
void IndexLower(Level* level_out);
void UpdateLower(Level* level);

}  // namespace amg
}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_SRC_CORE_LINALG_AGGREGATION_AMG_LEVEL_H_
