#include "rotation_averaging/io/text_lines.h"

#include <cerrno>
#include <cstdio>
#include <filesystem>
#include <cstdlib>
#include <limits>

namespace rotation_averaging {

std::vector<std::string> SplitTokens(const std::string& line, bool comma) {
  std::vector<std::string> tokens;
  std::string current;
  for (char c : line) {
    if (c == ' ' || c == '\t' || c == '\r' || c == '\n' || (comma && c == ',')) {
      if (!current.empty()) tokens.push_back(current);
      current.clear();
    } else {
      current.push_back(c);
    }
  }
  if (!current.empty()) tokens.push_back(current);
  return tokens;
}

bool ParseDouble(const std::string& token, double* value) {
  if (token.empty()) return false;
  char* end = nullptr;
  errno = 0;
  const double v = std::strtod(token.c_str(), &end);
  if (end != token.c_str() + token.size() || errno == ERANGE) return false;
  *value = v;
  return true;
}

bool ParseUint64(const std::string& token, std::uint64_t* value) {
  if (token.empty() || token[0] == '-' || token[0] == '+') return false;
  char* end = nullptr;
  errno = 0;
  const unsigned long long v = std::strtoull(token.c_str(), &end, 10);
  if (end != token.c_str() + token.size() || errno == ERANGE) return false;
  *value = v;
  return true;
}

bool ParseInt(const std::string& token, int* value) {
  if (token.empty()) return false;
  char* end = nullptr;
  errno = 0;
  const long v = std::strtol(token.c_str(), &end, 10);
  if (end != token.c_str() + token.size() || errno == ERANGE || v < std::numeric_limits<int>::min() ||
      v > std::numeric_limits<int>::max()) {
    return false;
  }
  *value = static_cast<int>(v);
  return true;
}

LineReader::LineReader(const std::string& path) : path_(path), stream_(path) {}

bool LineReader::Next(std::string* line) {
  if (!std::getline(stream_, *line)) return false;
  ++line_number_;
  return true;
}

std::string LineReader::Where(const std::string& message) const {
  return path_ + ":" + std::to_string(line_number_) + ": " + message;
}

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
  std::error_code ec;
  std::filesystem::rename(temporary, path, ec);
  if (ec) {
    std::remove(temporary.c_str());
    if (error) *error = "cannot rename " + temporary + " to " + path + ": " + ec.message();
    return false;
  }
  return true;
}

bool IsBlankOrComment(const std::string& line) {
  for (char c : line) {
    if (c == '#') return true;
    if (c != ' ' && c != '\t' && c != '\r') return false;
  }
  return true;
}

}  // namespace rotation_averaging
