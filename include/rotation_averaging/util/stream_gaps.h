// Images that never reached the node, counted from the gaps in each camera's
// stamps. A driver publishes at a steady rate; ROS drops the oldest message
// of a subscriber's queue when the callback falls behind, and a recording
// may have lost frames too. Neither says so, so a missing frame shows only
// as a gap of two or more periods between consecutive stamps. The period is
// each camera's median gap over its recent frames (a robust figure for a
// driver whose stamps jitter); until enough frames have come, nothing is
// counted. A gap longer than kPauseS is the stream pausing (a driver
// restarted, a bag's recordings joined), not frames lost.
#ifndef ROTATION_AVERAGING_UTIL_STREAM_GAPS_H_
#define ROTATION_AVERAGING_UTIL_STREAM_GAPS_H_

#include <cstdint>
#include <deque>
#include <map>
#include <string>

namespace rotation_averaging {

class StreamGaps {
 public:
  // Frames of one camera in stamp order (ns). Returns how many frames are
  // missing between the previous one and this one: 0 for a gap under 1.5
  // periods or over kPauseS, else the gap in periods, rounded, less one. A
  // stamp that does not advance counts nothing and is not remembered.
  std::uint64_t Observe(const std::string& camera, std::int64_t stamp_ns);
  std::uint64_t Missing() const { return missing_; }  // over every camera
  std::uint64_t Missing(const std::string& camera) const;
  // The camera's period (s) as estimated; 0 until it is.
  double PeriodS(const std::string& camera) const;
  void Reset() { cameras_.clear(); }  // a gap in the streams (counts are kept)

  static constexpr std::size_t kGapsForPeriod = 8;  // before any gap is counted
  static constexpr std::size_t kGapsHeld = 32;      // the period's window
  static constexpr double kPauseS = 2.0;

 private:
  struct Camera {
    std::int64_t last_ns = 0;
    bool has_last = false;
    std::deque<std::int64_t> gaps_ns;
    std::uint64_t missing = 0;
  };
  static std::int64_t Period(const Camera& camera);
  std::map<std::string, Camera> cameras_;
  std::uint64_t missing_ = 0;
};

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_UTIL_STREAM_GAPS_H_
