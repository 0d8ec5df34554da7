// The distribution of one kind of work's times: how many, their total, and
// over the most recent ones (a window, so that memory stays bounded on a
// robot that runs for days) the median and the 95th percentile, which say
// more of a budget than a mean: one slow keyframe in twenty is what holds
// up the next image.
#ifndef ROTATION_AVERAGING_UTIL_TIME_DISTRIBUTION_H_
#define ROTATION_AVERAGING_UTIL_TIME_DISTRIBUTION_H_

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace rotation_averaging {

// Wall time since `start` (s), on the steady clock every timing here uses.
inline double SecondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

class TimeDistribution {
 public:
  static constexpr std::size_t kDefaultWindow = 4096;
  explicit TimeDistribution(std::size_t window = kDefaultWindow);

  void Add(double seconds);
  std::uint64_t Count() const { return count_; }  // every time added
  double Total() const { return total_; }         // s, of every time added
  double Last() const { return last_; }
  std::size_t Held() const { return ring_.size(); }  // the window's times, at most `window`
  // The q-quantile (q in [0, 1]) of the window's times by nearest rank: the
  // smallest time that at least a fraction q of them do not exceed; 0 when
  // there are none.
  double Quantile(double q) const;
  double Median() const { return Quantile(0.5); }
  double P95() const { return Quantile(0.95); }
  // "median 2.10 ms, p95 3.40 ms (of 512)"; "none" when empty.
  std::string DescribeMs() const;

 private:
  std::size_t window_;
  std::vector<double> ring_;
  std::size_t next_ = 0;  // where the next time goes once the window is full
  std::uint64_t count_ = 0;
  double total_ = 0.0, last_ = 0.0;
};

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_UTIL_TIME_DISTRIBUTION_H_
