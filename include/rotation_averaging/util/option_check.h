// Checks an options struct field by field and keeps the first value out of
// its range, as a message naming the field: what every Options::Validate of
// the package returns, and what the CLI, the Python module, the node's
// parameters and dynamic_reconfigure report. NaN is never in range.
#ifndef ROTATION_AVERAGING_UTIL_OPTION_CHECK_H_
#define ROTATION_AVERAGING_UTIL_OPTION_CHECK_H_

#include <cmath>
#include <sstream>
#include <string>

namespace rotation_averaging {

class OptionCheck {
 public:
  // value >= min
  OptionCheck& AtLeast(const char* name, double value, double min) {
    if (!(value >= min)) Fail(name, value, "at least " + Number(min));
    return *this;
  }
  // value > min
  OptionCheck& Above(const char* name, double value, double min) {
    if (!(value > min)) Fail(name, value, "above " + Number(min));
    return *this;
  }
  // lo <= value <= hi
  OptionCheck& Within(const char* name, double value, double lo, double hi) {
    if (!(value >= lo && value <= hi)) Fail(name, value, "in [" + Number(lo) + ", " + Number(hi) + "]");
    return *this;
  }
  // lo < value < hi
  OptionCheck& Between(const char* name, double value, double lo, double hi) {
    if (!(value > lo && value < hi)) Fail(name, value, "in (" + Number(lo) + ", " + Number(hi) + ")");
    return *this;
  }
  OptionCheck& Finite(const char* name, double value) {
    if (!std::isfinite(value)) Fail(name, value, "finite");
    return *this;
  }
  OptionCheck& NotNan(const char* name, double value) {
    if (std::isnan(value)) Fail(name, value, "a number");
    return *this;
  }
  // A problem found elsewhere (a nested struct's Validate, a name that is
  // not one of an enumeration's).
  OptionCheck& Require(bool ok, const std::string& message) {
    if (!ok && error_.empty()) error_ = message;
    return *this;
  }
  // True if every check passed; otherwise `error` (if given) gets the first problem.
  bool Ok(std::string* error) const {
    if (error && !error_.empty()) *error = error_;
    return error_.empty();
  }

 private:
  static std::string Number(double v) {
    std::ostringstream s;
    s << v;
    return s.str();
  }
  void Fail(const char* name, double value, const std::string& range) {
    if (error_.empty()) error_ = std::string(name) + " must be " + range + " (got " + Number(value) + ")";
  }
  std::string error_;
};

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_UTIL_OPTION_CHECK_H_
