#include "rotation_averaging/frontend/io/keyframe_database.h"

#include <fcntl.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>
#include <xxhash.h>

#include <cmath>
#include <cstring>
#include <memory>
#include <set>

#include "rotation_averaging/util/binary_io.h"
#include "rotation_averaging/util/text_lines.h"
#include "rotation_averaging/frontend/estimators/relative_pose.h"
#include "rotation_averaging/frontend/geometry/camera_model.h"

namespace rotation_averaging {

namespace {

constexpr char kMagic[16] = {'R', 'O', 'T', 'A', 'V', 'G', '-', 'K', 'E', 'Y', 'F', 'R', 'A', 'M', 'E', 'S'};
constexpr std::uint32_t kVersion = 2;       // XXH3-64 checksum
constexpr std::uint32_t kFnvVersion = 1;    // FNV-1a checksum, otherwise the same
constexpr std::size_t kSizeOffset = sizeof(kMagic) + 4 + 8;  // after magic, version, fingerprint
constexpr std::size_t kHeaderSize = kSizeOffset + 8 + 8;

void PutMatrix(BinaryWriter* w, const Eigen::Matrix3d& m) { w->PutArray(m.data(), 9); }
bool GetMatrix(BinaryReader* r, Eigen::Matrix3d* m) { return r->GetArray(m->data(), 9) && m->allFinite(); }

void PutKeyframe(const StoredKeyframe& kf, BinaryWriter* w) {
  w->PutString(kf.key.frame_id);
  w->Put(static_cast<std::int64_t>(kf.key.stamp_ns));
  w->Put(kf.chain);
  w->Put(static_cast<std::uint8_t>(kf.has_sequential));
  PutMatrix(w, kf.k);
  PutMatrix(w, kf.sequential_rotation);
  PutMatrix(w, kf.sequential_covariance);
  const ImageFeatures& f = kf.features;
  w->Put(static_cast<std::int32_t>(f.type));
  w->Put(static_cast<std::int32_t>(f.width));
  w->Put(static_cast<std::int32_t>(f.height));
  w->Put(static_cast<std::uint32_t>(f.keypoints_px.size()));
  static_assert(sizeof(Eigen::Vector2d) == 2 * sizeof(double), "keypoints are stored as pairs of doubles");
  w->PutBytes(f.keypoints_px.data(), f.keypoints_px.size() * sizeof(Eigen::Vector2d));
  w->Put(static_cast<std::uint32_t>(f.strength.size()));
  w->PutArray(f.strength.data(), f.strength.size());
  const cv::Mat d = f.descriptors.isContinuous() ? f.descriptors : f.descriptors.clone();
  w->Put(static_cast<std::int32_t>(d.rows));
  w->Put(static_cast<std::int32_t>(d.cols));
  w->Put(static_cast<std::int32_t>(d.type()));
  w->PutBytes(d.data, d.total() * d.elemSize());
  w->Put(static_cast<std::uint32_t>(f.words.size()));
  w->PutArray(f.words.data(), f.words.size());
  w->Put(static_cast<std::uint32_t>(kf.bow.size()));
  for (const auto& [word, weight] : kf.bow) {
    w->Put(static_cast<std::int32_t>(word));
    w->Put(weight);
  }
}

// Reads one keyframe; an empty string or what is wrong with it.
std::string GetKeyframe(BinaryReader* r, int num_words, std::size_t count, StoredKeyframe* kf) {
  std::int64_t stamp = 0;
  std::uint8_t has_sequential = 0;
  if (!r->GetString(&kf->key.frame_id) || !r->Get(&stamp) || !r->Get(&kf->chain) || !r->Get(&has_sequential) ||
      !GetMatrix(r, &kf->k) || !GetMatrix(r, &kf->sequential_rotation) || !GetMatrix(r, &kf->sequential_covariance)) {
    return "truncated or not finite";
  }
  kf->key.stamp_ns = stamp;
  kf->has_sequential = has_sequential != 0;
  if (kf->key.frame_id.empty()) return "empty frame id";
  if (kf->chain >= count) return "bad chain";
  if (!IsCameraIntrinsics(kf->k)) return "not camera intrinsics";
  ImageFeatures& f = kf->features;
  std::int32_t type = 0, width = 0, height = 0, rows = 0, cols = 0, cv_type = 0;
  std::size_t n = 0, strengths = 0, word_count = 0, bow_size = 0;
  if (!r->Get(&type) || !r->Get(&width) || !r->Get(&height) || !r->GetCount(16, &n)) return "truncated";
  if (type != static_cast<std::int32_t>(FeatureType::kSift) && type != static_cast<std::int32_t>(FeatureType::kOrb)) {
    return "unknown feature type";
  }
  f.type = static_cast<FeatureType>(type);
  f.width = width;
  f.height = height;
  f.keypoints_px.resize(n);
  if (!r->GetBytes(f.keypoints_px.data(), n * sizeof(Eigen::Vector2d))) return "keypoints truncated";
  for (const Eigen::Vector2d& p : f.keypoints_px) {
    if (!p.allFinite()) return "keypoints not finite";
  }
  if (!r->GetCount(sizeof(float), &strengths) || (strengths != 0 && strengths != n)) return "strengths";
  f.strength.resize(strengths);
  if (!r->GetArray(f.strength.data(), strengths)) return "strengths truncated";
  if (!r->Get(&rows) || !r->Get(&cols) || !r->Get(&cv_type) || rows != static_cast<std::int32_t>(n) || cols < 1 ||
      cols > 128 || (cv_type != CV_8U && cv_type != CV_32F)) {
    return "descriptors do not fit the keypoints";
  }
  // Checked before the allocation: a corrupted size allocates nothing.
  if (n * static_cast<std::size_t>(cols) * (cv_type == CV_32F ? 4 : 1) > r->Remaining()) return "descriptors truncated";
  f.descriptors.create(rows, cols, cv_type);
  if (!r->GetBytes(f.descriptors.data, f.descriptors.total() * f.descriptors.elemSize())) {
    return "descriptors truncated";
  }
  if (!r->GetCount(sizeof(int), &word_count) || (word_count != 0 && word_count != n)) return "words";
  f.words.resize(word_count);
  if (!r->GetArray(f.words.data(), word_count)) return "words truncated";
  for (int word : f.words) {
    if (word < 0 || word >= num_words) return "a word the vocabulary does not have";
  }
  if (!r->GetCount(8, &bow_size)) return "bag of words truncated";
  kf->bow.resize(bow_size);
  for (auto& [word, weight] : kf->bow) {
    std::int32_t w = 0;
    if (!r->Get(&w) || !r->Get(&weight) || w < 0 || w >= num_words || !std::isfinite(weight)) {
      return "bag of words truncated or out of range";
    }
    word = w;
  }
  return "";
}

// A read-only view of a whole file: mapped, so that a large database is not
// copied into memory before its keyframes are.
class MappedFile {
 public:
  explicit MappedFile(const std::string& path) {
    fd_ = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd_ < 0) return;
    struct stat st;
    if (::fstat(fd_, &st) != 0 || !S_ISREG(st.st_mode)) return;
    size_ = static_cast<std::size_t>(st.st_size);
    opened_ = true;
    if (size_ == 0) return;
    void* p = ::mmap(nullptr, size_, PROT_READ, MAP_PRIVATE, fd_, 0);
    if (p == MAP_FAILED) {
      opened_ = false;
      return;
    }
    ::madvise(p, size_, MADV_SEQUENTIAL);
    data_ = static_cast<const char*>(p);
  }
  ~MappedFile() {
    if (data_) ::munmap(const_cast<char*>(data_), size_);
    if (fd_ >= 0) ::close(fd_);
  }
  MappedFile(const MappedFile&) = delete;
  MappedFile& operator=(const MappedFile&) = delete;
  bool opened() const { return opened_; }
  const char* data() const { return data_ ? data_ : ""; }
  std::size_t size() const { return size_; }

 private:
  int fd_ = -1;
  bool opened_ = false;
  const char* data_ = nullptr;
  std::size_t size_ = 0;
};

}  // namespace

bool WriteKeyframeDatabase(const std::string& path, const KeyframeDatabase& database, std::string* error) {
  return WriteFileAtomically(path, [&](std::ostream& out) -> std::string {
    BinaryWriter header;
    header.PutBytes(kMagic, sizeof(kMagic));
    header.Put(kVersion);
    header.Put(database.vocabulary_fingerprint);
    header.Put(std::uint64_t{0});  // size and checksum, filled in at the end
    header.Put(std::uint64_t{0});
    out.write(header.Bytes().data(), static_cast<std::streamsize>(header.Bytes().size()));
    std::unique_ptr<XXH3_state_t, decltype(&XXH3_freeState)> state(XXH3_createState(), &XXH3_freeState);
    if (!state || XXH3_64bits_reset(state.get()) != XXH_OK) return "cannot start the checksum";
    std::uint64_t size = 0;
    BinaryWriter w;
    auto flush = [&] {
      XXH3_64bits_update(state.get(), w.Bytes().data(), w.Bytes().size());
      out.write(w.Bytes().data(), static_cast<std::streamsize>(w.Bytes().size()));
      size += w.Bytes().size();
      w.Clear();
    };
    w.Put(static_cast<std::int32_t>(database.feature_type));
    w.Put(static_cast<std::int32_t>(database.num_words));
    w.Put(static_cast<std::uint32_t>(database.keyframes.size()));
    for (const StoredKeyframe& kf : database.keyframes) {
      PutKeyframe(kf, &w);
      if (w.Bytes().size() >= (1u << 20)) flush();
    }
    flush();
    BinaryWriter trailer;
    trailer.Put(size);
    trailer.Put(static_cast<std::uint64_t>(XXH3_64bits_digest(state.get())));
    out.seekp(static_cast<std::streamoff>(kSizeOffset));
    out.write(trailer.Bytes().data(), static_cast<std::streamsize>(trailer.Bytes().size()));
    return out ? "" : "write to " + path + " failed";
  }, error);
}

bool ReadKeyframeDatabase(const std::string& path, std::uint64_t vocabulary_fingerprint, KeyframeDatabase* database,
                          std::string* error) {
  auto fail = [&](const std::string& why) {
    if (error) *error = path + ": " + why;
    return false;
  };
  const MappedFile file(path);
  if (!file.opened()) return fail("cannot open the keyframe database");
  BinaryReader header(file.data(), file.size());
  char magic[sizeof(kMagic)];
  if (!header.GetBytes(magic, sizeof(magic)) || std::memcmp(magic, kMagic, sizeof(magic)) != 0) {
    return fail("not a keyframe database");
  }
  std::uint32_t version = 0;
  std::uint64_t fingerprint = 0, size = 0, checksum = 0;
  if (!header.Get(&version) || !header.Get(&fingerprint) || !header.Get(&size) || !header.Get(&checksum)) {
    return fail("truncated header");
  }
  if (version != kVersion && version != kFnvVersion) {
    return fail("format version " + std::to_string(version) + ", this build reads versions " +
                std::to_string(kFnvVersion) + " and " + std::to_string(kVersion) +
                (version > kVersion ? " (written by a newer version)" : ""));
  }
  if (fingerprint != vocabulary_fingerprint) {
    return fail("written with another vocabulary (its words mean nothing to this one's index)");
  }
  if (size != header.Remaining()) {
    return fail("truncated or extended: " + std::to_string(header.Remaining()) + " bytes of contents, " +
                std::to_string(size) + " written (a save that was interrupted?)");
  }
  const char* payload = file.data() + kHeaderSize;
  std::uint64_t sum = 0;
  if (version == kFnvVersion) {
    Fnv1a fnv;
    fnv.Add(payload, size);
    sum = fnv.h;
  } else {
    sum = XXH3_64bits(payload, size);
  }
  if (sum != checksum) return fail("checksum mismatch: the file is corrupted");

  BinaryReader r(payload, size);
  KeyframeDatabase read;
  read.vocabulary_fingerprint = fingerprint;
  std::int32_t feature_type = 0, num_words = 0;
  std::size_t count = 0;
  if (!r.Get(&feature_type) || !r.Get(&num_words) || !r.GetCount(64, &count)) return fail("truncated contents");
  if (num_words < 1 || (feature_type != static_cast<std::int32_t>(FeatureType::kSift) &&
                        feature_type != static_cast<std::int32_t>(FeatureType::kOrb))) {
    return fail("unknown feature type or no vocabulary words");
  }
  read.feature_type = static_cast<FeatureType>(feature_type);
  read.num_words = num_words;
  read.keyframes.resize(count);
  std::set<KeyframeKey> keys;
  for (std::size_t i = 0; i < count; ++i) {
    StoredKeyframe& kf = read.keyframes[i];
    const std::string why = GetKeyframe(&r, num_words, count, &kf);
    if (!why.empty()) return fail("keyframe " + std::to_string(i) + ": " + why);
    if (!keys.insert(kf.key).second) return fail("keyframe " + std::to_string(i) + ": repeated key");
  }
  if (r.Remaining() != 0) return fail("bytes after the last keyframe");
  *database = std::move(read);
  return true;
}

}  // namespace rotation_averaging
