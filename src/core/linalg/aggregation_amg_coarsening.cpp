// AggregationAmg's coarsening: pairwise matching of the strongest
// couplings, the aggregates' Galerkin products, and the lower-triangle
// copies the cycles stream.
#include <algorithm>
#include <cmath>
#include <vector>

#include "core/linalg/aggregation_amg_level.h"

namespace rotation_averaging {
namespace amg {
namespace {

// Relaxed matching merges singletons into groups of up to this size.
constexpr int kMaxRelaxedGroup = 6;

}  // namespace

int PairwiseMatch(const Level& level, double strong_coupling, double dominance, bool relaxed,
                  std::vector<int>* group_out) {
  const int n = level.n;
  std::vector<int>& group = *group_out;
  group.assign(n, kUnassigned);
  std::vector<double> strongest(n, 0.0);
  for (int i = 0; i < n; ++i) {
    double sum_abs = 0.0, max_negative = 0.0;
    for (int p = level.ptr[i]; p < level.ptr[i + 1]; ++p) {
      sum_abs += std::abs(level.val[p]);
      max_negative = std::max(max_negative, -level.val[p]);
    }
    strongest[i] = max_negative;
    if (level.diag[i] >= dominance * sum_abs) group[i] = -1;
  }
  // Heavy-edge matching: couplings in decreasing order of their strength
  // relative to the two diagonals, c_ij = -a_ij / sqrt(a_ii a_jj) in (0, 1]
  // (bucketed by quarter octaves: a counting sort), so that the strongest
  // pairs stay together; a greedy pass in node order splits chains of strong
  // couplings, leaving modes that neither the smoother nor the coarse
  // level reduces.
  constexpr int kBuckets = 128;
  std::vector<int> bucket_start(kBuckets + 1, 0);
  std::vector<std::pair<int, int>> pairs;  // (node, position of the coupling in its row)
  std::vector<unsigned char> bucket_of;
  pairs.reserve(level.col.size() / 2);
  bucket_of.reserve(level.col.size() / 2);
  for (int i = 0; i < n; ++i) {
    if (group[i] != kUnassigned) continue;
    for (int p = level.ptr[i]; p < level.ptr[i + 1]; ++p) {
      const int j = level.col[p];
      const double coupling = -level.val[p];
      if (j <= i || group[j] != kUnassigned || !(coupling > 0.0)) continue;
      // Strong for both ends (relaxed: for either end).
      const double needed = strong_coupling * (relaxed ? std::min(strongest[i], strongest[j])
                                                       : std::max(strongest[i], strongest[j]));
      if (coupling < needed) continue;
      const double relative = coupling / std::sqrt(level.diag[i] * level.diag[j]);
      const int b = std::min(kBuckets - 1, std::max(0, static_cast<int>(-4.0 * std::log2(std::min(relative, 1.0)))));
      pairs.emplace_back(i, p);
      bucket_of.push_back(static_cast<unsigned char>(b));
      ++bucket_start[b + 1];
    }
  }
  for (int b = 0; b < kBuckets; ++b) bucket_start[b + 1] += bucket_start[b];
  std::vector<int> order(pairs.size());
  {
    std::vector<int> fill(bucket_start.begin(), bucket_start.end() - 1);
    for (std::size_t k = 0; k < pairs.size(); ++k) order[fill[bucket_of[k]]++] = static_cast<int>(k);
  }
  int groups = 0;
  for (int k : order) {
    const int i = pairs[k].first, j = level.col[pairs[k].second];
    if (group[i] != kUnassigned || group[j] != kUnassigned) continue;
    group[i] = group[j] = groups++;
  }
  for (int i = 0; i < n; ++i)
    if (group[i] == kUnassigned) group[i] = groups++;
  // A node left alone because its strong neighbours were taken joins the
  // pair of its strongest neighbour (groups of at most three) when that
  // coupling is strong for the neighbour too. A node tied to everything
  // weakly (a view whose edges are mostly outliers, hanging on a few
  // low-weight inliers) stays alone: merged into a strongly coupled pair,
  // its own motion could be reduced neither by the coarse level nor by the
  // smoother. Such nodes may stall the coarsening; the coarsest level is
  // then larger and factorised sparsely. `relaxed` (for levels too large to
  // factorise) pairs along couplings strong for either end and merges every
  // singleton into the group of its strongest neighbour (up to six nodes).
  std::vector<int> size(groups, 0);
  for (int i = 0; i < n; ++i)
    if (group[i] >= 0) ++size[group[i]];
  for (int i = 0; i < n; ++i) {
    if (group[i] < 0 || size[group[i]] != 1) continue;
    int best = -1;
    double best_coupling = 0.0;
    for (int p = level.ptr[i]; p < level.ptr[i + 1]; ++p) {
      const int j = level.col[p];
      const double coupling = -level.val[p];
      if (j != i && group[j] >= 0 && coupling > best_coupling) {
        best = j;
        best_coupling = coupling;
      }
    }
    const double needed =
        relaxed ? 0.0 : strong_coupling * std::max(strongest[i], strongest[best < 0 ? i : best]);
    if (best >= 0 && best_coupling >= needed && (size[group[best]] == 2 || (relaxed && size[group[best]] < kMaxRelaxedGroup))) {
      --size[group[i]];
      group[i] = group[best];
      ++size[group[i]];
    }
  }
  // Renumber the groups that are left.
  std::vector<int> renumber(groups, -1);
  int kept = 0;
  for (int g = 0; g < groups; ++g)
    if (size[g] > 0) renumber[g] = kept++;
  for (int i = 0; i < n; ++i)
    if (group[i] >= 0) group[i] = renumber[group[i]];
  return kept;
}

void AggregateMembers(const std::vector<int>& aggregate, int num_aggregates, std::vector<int>* start_out,
                      std::vector<int>* members_out) {
  std::vector<int>& start = *start_out;
  std::vector<int>& members = *members_out;
  start.assign(num_aggregates + 1, 0);
  for (int a : aggregate)
    if (a >= 0) ++start[a + 1];
  for (int a = 0; a < num_aggregates; ++a) start[a + 1] += start[a];
  members.resize(start[num_aggregates]);
  std::vector<int> fill(start.begin(), start.end() - 1);
  for (std::size_t i = 0; i < aggregate.size(); ++i)
    if (aggregate[i] >= 0) members[fill[aggregate[i]]++] = static_cast<int>(i);
}

void Galerkin(const Level& fine, const std::vector<int>& aggregate, int num_coarse, Level* coarse_out) {
  Level& coarse = *coarse_out;
  coarse = Level();
  coarse.n = num_coarse;
  std::vector<int> start, members;
  AggregateMembers(aggregate, num_coarse, &start, &members);
  coarse.ptr.assign(num_coarse + 1, 0);
  coarse.diag.assign(num_coarse, 0.0);
  coarse.col.reserve(fine.col.size() / 2);
  coarse.val.reserve(fine.col.size() / 2);
  std::vector<int> position(num_coarse, -1);  // of column J in the current row
  for (int a = 0; a < num_coarse; ++a) {
    const int row_start = static_cast<int>(coarse.col.size());
    double d = 0.0;
    for (int m = start[a]; m < start[a + 1]; ++m) {
      const int i = members[m];
      d += fine.diag[i];
      for (int p = fine.ptr[i]; p < fine.ptr[i + 1]; ++p) {
        const int b = aggregate[fine.col[p]];
        if (b < 0) continue;
        if (b == a) {
          d += fine.val[p];
        } else if (position[b] < row_start) {
          position[b] = static_cast<int>(coarse.col.size());
          coarse.col.push_back(b);
          coarse.val.push_back(fine.val[p]);
        } else {
          coarse.val[position[b]] += fine.val[p];
        }
      }
    }
    coarse.diag[a] = d;
    coarse.ptr[a + 1] = static_cast<int>(coarse.col.size());
  }
}

void IndexLower(Level* level_out) {
  Level& level = *level_out;
  level.lower_ptr.assign(level.n + 1, 0);
  level.lower_col.clear();
  level.lower_source.clear();
  for (int i = 0; i < level.n; ++i) {
    for (int p = level.ptr[i]; p < level.ptr[i + 1]; ++p) {
      if (level.col[p] >= i) continue;
      level.lower_col.push_back(level.col[p]);
      level.lower_source.push_back(p);
    }
    level.lower_ptr[i + 1] = static_cast<int>(level.lower_col.size());
  }
}

void UpdateLower(Level* level) {
  level->lower_val.resize(level->lower_source.size());
  for (std::size_t m = 0; m < level->lower_source.size(); ++m) level->lower_val[m] = level->val[level->lower_source[m]];
}

}  // namespace amg
}  // namespace rotation_averaging
