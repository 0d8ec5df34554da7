#include "rotation_averaging/util/text_lines.h"

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>

#include "rotation_averaging/util/binary_io.h"

namespace rotation_averaging {

namespace {

// Separator classes: 1 = whitespace, 2 = comma (a separator only when asked).
struct SeparatorTable {
  unsigned char kind[256] = {};
  constexpr SeparatorTable() {
    kind[static_cast<unsigned char>(' ')] = 1;
    kind[static_cast<unsigned char>('\t')] = 1;
    kind[static_cast<unsigned char>('\r')] = 1;
    kind[static_cast<unsigned char>('\n')] = 1;
    kind[static_cast<unsigned char>(',')] = 2;
  }
};
constexpr SeparatorTable kSeparators;

constexpr std::size_t kBlockBytes = 1 << 20;

}  // namespace

void SplitTokens(std::string_view line, std::vector<std::string_view>* tokens, bool comma) {
  tokens->clear();
  const unsigned char mask = comma ? 3 : 1;
  const char* p = line.data();
  const char* const end = p + line.size();
  while (p < end) {
    while (p < end && (kSeparators.kind[static_cast<unsigned char>(*p)] & mask)) ++p;
    const char* first = p;
    while (p < end && !(kSeparators.kind[static_cast<unsigned char>(*p)] & mask)) ++p;
    if (p > first) tokens->emplace_back(first, static_cast<std::size_t>(p - first));
  }
}

std::vector<std::string> SplitTokens(std::string_view line, bool comma) {
  std::vector<std::string_view> views;
  SplitTokens(line, &views, comma);
  return std::vector<std::string>(views.begin(), views.end());
}

namespace {

// The whole token as one number of type T, by std::from_chars; a leading '+'
// is taken where `plus` allows (from_chars takes none), a second sign after it
// is still an error.
template <typename T>
bool ParseWhole(std::string_view token, bool plus, T* value) {
  if (plus && token.size() > 1 && token[0] == '+' && token[1] != '-' && token[1] != '+') token.remove_prefix(1);
  if (token.empty()) return false;
  T v{};
  const char* end = token.data() + token.size();
  const auto [ptr, ec] = std::from_chars(token.data(), end, v);
  if (ec != std::errc() || ptr != end) return false;
  *value = v;
  return true;
}

}  // namespace

bool ParseDouble(std::string_view token, double* value) { return ParseWhole(token, true, value); }

bool ParseUint64(std::string_view token, std::uint64_t* value) { return ParseWhole(token, false, value); }

bool ParseInt(std::string_view token, int* value) { return ParseWhole(token, true, value); }

bool ParseQuaternion(const std::string_view* first, double q[4]) {
  for (int k = 0; k < 4; ++k) {
    if (!ParseDouble(first[k], &q[k])) return false;
  }
  return true;
}

bool IsUnitQuaternion(const double q[4]) {
  const double norm = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
  return std::isfinite(norm) && std::abs(norm - 1.0) <= 1e-6;
}

void AppendDouble(std::string* out, double value) {
  char buffer[32];
  const auto [ptr, ec] = std::to_chars(buffer, buffer + sizeof(buffer), value);
  out->append(buffer, ec == std::errc() ? ptr - buffer : 0);
}

LineReader::LineReader(const std::string& path) : path_(path), file_(std::fopen(path.c_str(), "rb")) {
  // fopen succeeds on a directory on Linux; reading it then fails.
  std::error_code ec;
  if (file_ != nullptr && std::filesystem::is_directory(path, ec)) {
    std::fclose(file_);
    file_ = nullptr;
  }
  if (file_ != nullptr) buffer_.resize(kBlockBytes);
}

LineReader::~LineReader() {
  if (file_ != nullptr) std::fclose(file_);
}

bool LineReader::Fill() {
  if (eof_ || file_ == nullptr) return false;
  if (begin_ > 0) {
    std::memmove(buffer_.data(), buffer_.data() + begin_, end_ - begin_);
    end_ -= begin_;
    begin_ = 0;
  }
  if (end_ == buffer_.size()) buffer_.resize(2 * buffer_.size());  // a line longer than the buffer
  const std::size_t got = std::fread(buffer_.data() + end_, 1, buffer_.size() - end_, file_);
  end_ += got;
  if (got == 0) eof_ = true;
  return got > 0;
}

bool LineReader::Next(std::string_view* line) {
  if (file_ == nullptr) return false;
  std::size_t scanned = begin_;
  for (;;) {
    const char* data = buffer_.data();
    const void* newline = std::memchr(data + scanned, '\n', end_ - scanned);
    if (newline != nullptr) {
      const std::size_t at = static_cast<const char*>(newline) - data;
      *line = std::string_view(data + begin_, at - begin_);
      begin_ = at + 1;
      ++line_number_;
      return true;
    }
    const std::size_t unread = end_ - begin_;
    if (!Fill()) {
      if (begin_ == end_) return false;
      *line = std::string_view(buffer_.data() + begin_, end_ - begin_);  // last line without '\n'
      begin_ = end_;
      ++line_number_;
      return true;
    }
    scanned = unread;  // Fill() moved the unread bytes to the front
  }
}

bool LineReader::Next(std::string* line) {
  std::string_view view;
  if (!Next(&view)) return false;
  line->assign(view.data(), view.size());
  return true;
}

std::string LineReader::Where(const std::string& message) const {
  return path_ + ":" + std::to_string(line_number_) + ": " + message;
}

std::string EndRecord(const std::string& body) {
  Fnv1a sum;
  sum.Add(body.data(), body.size());
  const std::size_t lines = static_cast<std::size_t>(std::count(body.begin(), body.end(), '\n'));
  return "END " + std::to_string(lines) + ' ' + sum.Hex() + '\n';
}

EndRecordCheck::Line EndRecordCheck::Take(std::string_view line, std::string* why) {
  if (ended_) {
    if (IsBlankOrComment(line)) return Line::kAfterEnd;
    *why = "records after the END record";
    return Line::kError;
  }
  if (line.rfind("END ", 0) == 0) {
    SplitTokens(line, &tokens_);
    std::uint64_t count = 0;
    if (tokens_.size() != 3 || !ParseUint64(tokens_[1], &count)) {
      *why = "expected 'END lines checksum'";
      return Line::kError;
    }
    Fnv1a sum;
    sum.h = sum_;
    if (count != lines_ || tokens_[2] != sum.Hex()) {
      *why = "checksum mismatch: the file is corrupted (" + std::to_string(lines_) + " lines read, " +
             std::string(tokens_[1]) + " written)";
      return Line::kError;
    }
    ended_ = true;
    return Line::kEnd;
  }
  Fnv1a sum;
  sum.h = sum_;
  sum.AddLine(line);
  sum_ = sum.h;
  ++lines_;
  return Line::kContent;
}

bool ReadEndRecordedFile(const std::string& path, std::string_view header, const std::string& kind,
                         const std::function<bool(const std::vector<std::string_view>& tokens, std::string* why)>& record,
                         std::string* error) {
  auto fail = [&](const std::string& why) {
    if (error) *error = why;
    return false;
  };
  LineReader reader(path);
  if (!reader.IsOpen()) return fail("cannot open " + path);
  std::string_view line;
  std::vector<std::string_view> tokens;
  EndRecordCheck end;
  while (reader.Next(&line)) {
    if (end.ContentLines() == 0 && !end.Ended() && line != header) {
      return fail(reader.Where("not a " + kind + " file of this version"));
    }
    std::string why;
    const EndRecordCheck::Line kind_of_line = end.Take(line, &why);
    if (kind_of_line == EndRecordCheck::Line::kError) return fail(reader.Where(why));
    if (kind_of_line != EndRecordCheck::Line::kContent || IsBlankOrComment(line)) continue;
    SplitTokens(line, &tokens);
    if (!record(tokens, &why)) return fail(reader.Where(why));
  }
  if (!end.Ended()) return fail(path + ": no END record: the file is truncated (a save that was interrupted?)");
  return true;
}

namespace {

bool SyncToDisk(const std::string& path) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return false;
  const bool ok = ::fsync(fd) == 0;
  ::close(fd);
  return ok;
}

}  // namespace

bool WriteFileAtomically(const std::string& path, const std::function<std::string(std::ostream&)>& write,
                         std::string* error) {
  const std::string temporary = path + ".tmp";
  {
    std::ofstream out(temporary);
    if (!out) {
      if (error) *error = "cannot write " + temporary;
      return false;
    }
    const std::string why = write(out);
    if (!why.empty() || !out.flush()) {
      out.close();
      std::remove(temporary.c_str());
      if (error) *error = why.empty() ? "write to " + temporary + " failed" : why;
      return false;
    }
  }
  // The contents reach the disk before the rename does, and the rename before
  // this returns: after a power cut (not only a killed process) the file is
  // the old one or the new one, never a renamed empty one.
  if (!SyncToDisk(temporary)) {
    std::remove(temporary.c_str());
    if (error) *error = "cannot flush " + temporary + " to disk";
    return false;
  }
  std::error_code ec;
  std::filesystem::rename(temporary, path, ec);
  if (ec) {
    std::remove(temporary.c_str());
    if (error) *error = "cannot rename " + temporary + " to " + path + ": " + ec.message();
    return false;
  }
  const std::filesystem::path parent = std::filesystem::path(path).parent_path();
  SyncToDisk(parent.empty() ? std::string(".") : parent.string());  // best effort: some file systems refuse it
  return true;
}

bool IsBlankOrComment(std::string_view line) {
  for (char c : line) {
    if (c == '#') return true;
    if (c != ' ' && c != '\t' && c != '\r') return false;
  }
  return true;
}

}  // namespace rotation_averaging
