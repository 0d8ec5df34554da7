#include "rotation_averaging/util/stream_gaps.h"

#include <algorithm>
#include <cmath>
#include <vector>

namespace rotation_averaging {

std::int64_t StreamGaps::Period(const Camera& camera) {
  if (camera.gaps_ns.size() < kGapsForPeriod) return 0;
  std::vector<std::int64_t> gaps(camera.gaps_ns.begin(), camera.gaps_ns.end());
  std::nth_element(gaps.begin(), gaps.begin() + gaps.size() / 2, gaps.end());
  return gaps[gaps.size() / 2];
}

std::uint64_t StreamGaps::Observe(const std::string& camera_name, std::int64_t stamp_ns) {
  Camera& camera = cameras_[camera_name];
  if (!camera.has_last) {
    camera.has_last = true;
    camera.last_ns = stamp_ns;
    return 0;
  }
  if (stamp_ns <= camera.last_ns) return 0;
  const std::int64_t gap = stamp_ns - camera.last_ns;
  camera.last_ns = stamp_ns;
  if (static_cast<double>(gap) > 1e9 * kPauseS) return 0;
  const std::int64_t period = Period(camera);
  std::uint64_t missing = 0;
  if (period > 0 && 2 * gap >= 3 * period) {
    missing = static_cast<std::uint64_t>(std::llround(static_cast<double>(gap) / static_cast<double>(period))) - 1;
    // 1.5 periods rounds to 2: one missing frame.
    missing = std::max<std::uint64_t>(missing, 1);
  } else {
    // Only the gaps between consecutive frames make the period: a gap with
    // frames missing would stretch it.
    camera.gaps_ns.push_back(gap);
    if (camera.gaps_ns.size() > kGapsHeld) camera.gaps_ns.pop_front();
  }
  camera.missing += missing;
  missing_ += missing;
  return missing;
}

std::uint64_t StreamGaps::Missing(const std::string& camera) const {
  const auto it = cameras_.find(camera);
  return it == cameras_.end() ? 0 : it->second.missing;
}

double StreamGaps::PeriodS(const std::string& camera) const {
  const auto it = cameras_.find(camera);
  return it == cameras_.end() ? 0.0 : 1e-9 * static_cast<double>(Period(it->second));
}

}  // namespace rotation_averaging
