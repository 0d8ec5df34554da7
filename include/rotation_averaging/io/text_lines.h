// Line-oriented parsing helpers shared by the text readers: strict number
// parsing (the whole token must be a number) and "file:line: message" errors.
#ifndef ROTATION_AVERAGING_IO_TEXT_LINES_H_
#define ROTATION_AVERAGING_IO_TEXT_LINES_H_

#include <cstdint>
#include <fstream>
#include <functional>
#include <ostream>
#include <string>
#include <vector>

namespace rotation_averaging {

// Splits on whitespace (and, if `comma` is true, on commas too).
std::vector<std::string> SplitTokens(const std::string& line, bool comma = false);
bool ParseDouble(const std::string& token, double* value);  // finite or not, but a number
bool ParseUint64(const std::string& token, std::uint64_t* value);
bool ParseInt(const std::string& token, int* value);

// Reads a text file line by line, numbering lines from 1.
class LineReader {
 public:
  explicit LineReader(const std::string& path);
  bool IsOpen() const { return stream_.is_open(); }
  bool Next(std::string* line);  // false at end of file
  int LineNumber() const { return line_number_; }
  // "path:line: message"
  std::string Where(const std::string& message) const;
  const std::string& Path() const { return path_; }

 private:
  std::string path_;
  std::ifstream stream_;
  int line_number_ = 0;
};

// True for empty lines and lines starting with '#'.
bool IsBlankOrComment(const std::string& line);

// Writes `path` atomically: `write` fills a temporary file beside it, which is
// renamed over `path` only when everything was written, so a reader never
// sees half a file. `write` returns an empty string or why it gave up.
bool WriteFileAtomically(const std::string& path, const std::function<std::string(std::ostream&)>& write,
                         std::string* error);

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_IO_TEXT_LINES_H_
