// Little helpers for the package's binary files (the keyframe database):
// a byte buffer written field by field, a bounds-checked reader over one, and
// the 64-bit FNV-1a checksum of the text files (and of version 1 keyframe
// databases). Values are stored
// in the machine's byte order (little-endian on every supported platform).
#ifndef ROTATION_AVERAGING_UTIL_BINARY_IO_H_
#define ROTATION_AVERAGING_UTIL_BINARY_IO_H_

#include <cstdint>
#include <cstring>
#include <string>
#include <string_view>
#include <type_traits>
#include <vector>

namespace rotation_averaging {

// FNV-1a, 64 bit.
struct Fnv1a {
  std::uint64_t h = 0xcbf29ce484222325ULL;
  void Add(const void* data, std::size_t size) {
    const auto* p = static_cast<const unsigned char*>(data);
    for (std::size_t i = 0; i < size; ++i) h = (h ^ p[i]) * 0x100000001b3ULL;
  }
  // The checksum as 16 lowercase hex digits (the END record of text files).
  std::string Hex() const {
    static const char kDigits[] = "0123456789abcdef";
    std::string out(16, '0');
    for (int i = 0; i < 16; ++i) out[15 - i] = kDigits[(h >> (4 * i)) & 0xf];
    return out;
  }
  // A text line and its newline.
  void AddLine(std::string_view line) {
    Add(line.data(), line.size());
    const char newline = '\n';
    Add(&newline, 1);
  }
};

class BinaryWriter {
 public:
  template <typename T>
  void Put(const T& value) {
    static_assert(std::is_trivially_copyable_v<T>, "plain values only");
    PutBytes(&value, sizeof(T));
  }
  template <typename T>
  void PutArray(const T* values, std::size_t count) {
    static_assert(std::is_trivially_copyable_v<T>, "plain values only");
    PutBytes(values, count * sizeof(T));
  }
  void PutString(const std::string& s) {
    Put(static_cast<std::uint32_t>(s.size()));
    PutBytes(s.data(), s.size());
  }
  void PutBytes(const void* data, std::size_t size) {
    if (size == 0) return;
    const auto* p = static_cast<const char*>(data);
    bytes_.insert(bytes_.end(), p, p + size);
  }
  const std::vector<char>& Bytes() const { return bytes_; }
  void Clear() { bytes_.clear(); }  // keeps the capacity, for the next block

 private:
  std::vector<char> bytes_;
};

// Every Get fails (returns false, and keeps failing) past the end: a
// truncated or corrupted file never reads out of bounds.
class BinaryReader {
 public:
  BinaryReader(const char* data, std::size_t size) : data_(data), size_(size) {}
  template <typename T>
  bool Get(T* value) {
    static_assert(std::is_trivially_copyable_v<T>, "plain values only");
    return GetBytes(value, sizeof(T));
  }
  template <typename T>
  bool GetArray(T* values, std::size_t count) {
    static_assert(std::is_trivially_copyable_v<T>, "plain values only");
    if (count > Remaining() / sizeof(T)) return Fail();
    return GetBytes(values, count * sizeof(T));
  }
  // A count of elements of `element_size` bytes each that the rest of the
  // buffer can hold: a corrupted count cannot make the caller allocate more
  // than the file's size.
  bool GetCount(std::size_t element_size, std::size_t* count) {
    std::uint32_t n = 0;
    if (!Get(&n)) return false;
    if (element_size > 0 && n > Remaining() / element_size) return Fail();
    *count = n;
    return true;
  }
  bool GetString(std::string* s) {
    std::size_t n = 0;
    if (!GetCount(1, &n)) return false;
    s->assign(data_ + offset_, n);
    offset_ += n;
    return true;
  }
  bool GetBytes(void* out, std::size_t size) {
    if (!ok_ || size > Remaining()) return Fail();
    if (size == 0) return true;  // `out` may be an empty vector's null data()
    std::memcpy(out, data_ + offset_, size);
    offset_ += size;
    return true;
  }
  std::size_t Remaining() const { return ok_ ? size_ - offset_ : 0; }
  bool ok() const { return ok_; }

 private:
  bool Fail() {
    ok_ = false;
    return false;
  }
  const char* data_;
  std::size_t size_;
  std::size_t offset_ = 0;
  bool ok_ = true;
};

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_UTIL_BINARY_IO_H_
