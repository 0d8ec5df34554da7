// Line-oriented parsing helpers shared by the text readers: strict number
// parsing (the whole token must be a number) and "file:line: message" errors.
// Lines and tokens are views into the reader's buffer: no allocation per line
// or token, numbers parsed with std::from_chars (the readers of large graphs
// spend most of their time here).
#ifndef ROTATION_AVERAGING_UTIL_TEXT_LINES_H_
#define ROTATION_AVERAGING_UTIL_TEXT_LINES_H_

#include <cstdint>
#include <cstdio>
#include <functional>
#include <ostream>
#include <string>
#include <string_view>
#include <vector>

namespace rotation_averaging {

// Splits on whitespace (and, if `comma` is true, on commas too).
std::vector<std::string> SplitTokens(std::string_view line, bool comma = false);
// The same into views of `line` (valid while it is), reusing `tokens`' storage.
void SplitTokens(std::string_view line, std::vector<std::string_view>* tokens, bool comma = false);
// Decimal numbers (a leading '+' allowed; "inf" and "nan" too); out of range
// (overflow, underflow) is an error.
bool ParseDouble(std::string_view token, double* value);
bool ParseUint64(std::string_view token, std::uint64_t* value);
bool ParseInt(std::string_view token, int* value);
// A rotation's quaternion as four tokens, qw qx qy qz from `first`: false if
// one is not a number.
bool ParseQuaternion(const std::string_view* first, double q[4]);
// Of unit norm within 1e-6: the package's files refuse other quaternions
// ("not a unit quaternion") rather than normalise them.
bool IsUnitQuaternion(const double q[4]);

// Appends the shortest decimal text that reads back as exactly `value`
// (std::to_chars): exact round trips, several times faster than iostreams.
void AppendDouble(std::string* out, double value);

// Reads a text file line by line, numbering lines from 1, in blocks of 1 MiB
// (a longer line grows the buffer). '\n' ends a line; a '\r' before it is
// kept (the tokenisers treat it as whitespace).
class LineReader {
 public:
  explicit LineReader(const std::string& path);
  ~LineReader();
  LineReader(const LineReader&) = delete;
  LineReader& operator=(const LineReader&) = delete;
  bool IsOpen() const { return file_ != nullptr; }
  // The next line, valid until the next call; false at end of file.
  bool Next(std::string_view* line);
  bool Next(std::string* line);
  int LineNumber() const { return line_number_; }
  // "path:line: message"
  std::string Where(const std::string& message) const;
  const std::string& Path() const { return path_; }

 private:
  bool Fill();  // moves the unread rest to the front and reads more; false at end of file

  std::string path_;
  std::FILE* file_ = nullptr;
  std::vector<char> buffer_;
  std::size_t begin_ = 0, end_ = 0;  // unread bytes
  bool eof_ = false;
  int line_number_ = 0;
};

// True for empty lines and lines starting with '#'.
bool IsBlankOrComment(std::string_view line);

// The last record of the package's own text files (the view graph, the rig
// file): "END <lines> <checksum>", the number of lines before it and their
// FNV-1a checksum (Fnv1a::AddLine), so that a file cut short or changed is
// refused instead of read in part. EndRecord(body) is that record for
// `body` (whole lines, each ending in a newline), newline included.
std::string EndRecord(const std::string& body);
// Follows a file line by line through its END record: Take says what each
// line is, and why it is wrong (kError; the caller adds the file and line).
class EndRecordCheck {
 public:
  enum class Line { kContent, kEnd, kAfterEnd, kError };
  Line Take(std::string_view line, std::string* why);
  bool Ended() const { return ended_; }
  std::size_t ContentLines() const { return lines_; }

 private:
  std::uint64_t sum_ = 0xcbf29ce484222325ULL;  // Fnv1a's start
  std::size_t lines_ = 0;
  bool ended_ = false;
  std::vector<std::string_view> tokens_;
};

// Reads a file of the package's own text kind whose first line is `header`
// and whose last record is its END record (the rig file, the refinement's
// corrections): `record` gets each other line that is not blank or a
// comment, split into tokens, and returns false with `why` to refuse the
// file. False, with "path:line: why" in `error`, for a file that cannot be
// opened, starts otherwise ("not a <kind> file of this version"), is cut
// short, changed, or refused by `record`.
bool ReadEndRecordedFile(const std::string& path, std::string_view header, const std::string& kind,
                         const std::function<bool(const std::vector<std::string_view>& tokens, std::string* why)>& record,
                         std::string* error);

// Writes `path` atomically: `write` fills a temporary file beside it, which is
// renamed over `path` only when everything was written, so a reader never
// sees half a file, and flushed to disk (fsync) before the rename, so a
// power cut leaves the old file or the new one. Saves to one path must not
// run concurrently (they share the temporary). `write` returns an empty
// string or why it gave up.
bool WriteFileAtomically(const std::string& path, const std::function<std::string(std::ostream&)>& write,
                         std::string* error);

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_UTIL_TEXT_LINES_H_
