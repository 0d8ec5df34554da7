#include "rotation_averaging/util/time_distribution.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

namespace rotation_averaging {

TimeDistribution::TimeDistribution(std::size_t window) : window_(std::max<std::size_t>(1, window)) {}

void TimeDistribution::Add(double seconds) {
  if (ring_.size() < window_) {
    ring_.push_back(seconds);
  } else {
    ring_[next_] = seconds;
    next_ = (next_ + 1) % window_;
  }
  ++count_;
  total_ += seconds;
  last_ = seconds;
}

double TimeDistribution::Quantile(double q) const {
  if (ring_.empty()) return 0.0;
  std::vector<double> sorted = ring_;
  const double clamped = std::clamp(q, 0.0, 1.0);
  const std::size_t rank = static_cast<std::size_t>(std::ceil(clamped * static_cast<double>(sorted.size())));
  const std::size_t k = rank == 0 ? 0 : rank - 1;
  std::nth_element(sorted.begin(), sorted.begin() + k, sorted.end());
  return sorted[k];
}

std::string TimeDistribution::DescribeMs() const {
  if (ring_.empty()) return "none";
  char text[96];
  std::snprintf(text, sizeof(text), "median %.2f ms, p95 %.2f ms (of %zu)", 1e3 * Median(), 1e3 * P95(),
                ring_.size());
  return text;
}

}  // namespace rotation_averaging
