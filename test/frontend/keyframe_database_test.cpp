#include "rotation_averaging/frontend/io/keyframe_database.h"

#include <gtest/gtest.h>

#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>

#include "rotation_averaging/core/geometry/so3.h"

namespace rotation_averaging {
namespace {

namespace fs = std::filesystem;

constexpr std::uint64_t kFingerprint = 0x0123456789abcdefULL;

StoredKeyframe MakeKeyframe(const std::string& camera, std::int64_t stamp, std::uint32_t chain, int features) {
  StoredKeyframe kf;
  kf.key = KeyframeKey{camera, stamp};
  kf.chain = chain;
  kf.has_sequential = features > 0;
  kf.k << 400.0, 0.0, 320.0, 0.0, 410.0, 240.0, 0.0, 0.0, 1.0;
  kf.sequential_rotation = ExpSO3(Eigen::Vector3d(0.01, -0.02, 0.03));
  kf.sequential_covariance = Eigen::Vector3d(1e-6, 2e-6, 3e-6).asDiagonal();
  kf.features.width = 640;
  kf.features.height = 480;
  kf.features.descriptors = cv::Mat(features, 64, CV_8U);
  for (int i = 0; i < features; ++i) {
    kf.features.keypoints_px.emplace_back(1.5 * i, 480.0 - i);
    kf.features.strength.push_back(100.0f / (i + 1));
    kf.features.words.push_back(i % 32);
    for (int c = 0; c < 64; ++c) kf.features.descriptors.at<std::uint8_t>(i, c) = static_cast<std::uint8_t>(i * 7 + c);
  }
  if (features > 0) kf.bow = {{1, 0.25f}, {7, 0.75f}};
  return kf;
}

std::string ReadAll(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

// Every field comes back as written, including a keyframe without features
// (a blank image; fuzz_readers found reading it passed a null pointer to
// memcpy), and the file is refused with its reason when it is damaged.
TEST(KeyframeDatabase, EveryFieldComesBackAndDamageIsRefused) {
  KeyframeDatabase database;
  database.num_words = 32;
  database.vocabulary_fingerprint = kFingerprint;
  database.keyframes.push_back(MakeKeyframe("cam_front", 1'000'000'000LL, 0, 40));
  database.keyframes.push_back(MakeKeyframe("cam_left", 1'000'000'000LL, 1, 25));
  database.keyframes.push_back(MakeKeyframe("cam_front", 2'000'000'000LL, 0, 0));
  const std::string path = ::testing::TempDir() + "/database_test.keyframes";
  std::string error;
  ASSERT_TRUE(WriteKeyframeDatabase(path, database, &error)) << error;

  KeyframeDatabase back;
  ASSERT_TRUE(ReadKeyframeDatabase(path, kFingerprint, &back, &error)) << error;
  EXPECT_EQ(back.num_words, 32);
  EXPECT_EQ(back.feature_type, FeatureType::kSift);
  ASSERT_EQ(back.keyframes.size(), 3u);
  for (std::size_t i = 0; i < 3; ++i) {
    const StoredKeyframe& a = database.keyframes[i];
    const StoredKeyframe& b = back.keyframes[i];
    EXPECT_EQ(b.key.frame_id, a.key.frame_id);
    EXPECT_EQ(b.key.stamp_ns, a.key.stamp_ns);
    EXPECT_EQ(b.chain, a.chain);
    EXPECT_EQ(b.has_sequential, a.has_sequential);
    EXPECT_EQ(b.k, a.k);
    EXPECT_EQ(b.sequential_rotation, a.sequential_rotation);
    EXPECT_EQ(b.sequential_covariance, a.sequential_covariance);
    EXPECT_EQ(b.features.keypoints_px, a.features.keypoints_px);
    EXPECT_EQ(b.features.strength, a.features.strength);
    EXPECT_EQ(b.features.words, a.features.words);
    EXPECT_EQ(b.features.width, 640);
    ASSERT_EQ(b.features.descriptors.rows, a.features.descriptors.rows);
    EXPECT_EQ(cv::norm(b.features.descriptors, a.features.descriptors, cv::NORM_L1), 0.0);
    EXPECT_EQ(b.bow, a.bow);
  }

  const std::string good = ReadAll(path);
  const std::string damaged_path = ::testing::TempDir() + "/database_test_damaged.keyframes";
  auto refused = [&](const std::string& bytes, std::uint64_t fingerprint, const std::string& reason) {
    std::ofstream(damaged_path, std::ios::binary | std::ios::trunc) << bytes;
    KeyframeDatabase kept = back;
    std::string why;
    EXPECT_FALSE(ReadKeyframeDatabase(damaged_path, fingerprint, &kept, &why)) << reason;
    EXPECT_NE(why.find(reason), std::string::npos) << why;
    EXPECT_EQ(kept.keyframes.size(), 3u);  // left as it was
  };
  refused(good, kFingerprint + 1, "another vocabulary");
  refused(good.substr(0, good.size() - 10), kFingerprint, "truncated");
  std::string flipped = good;
  flipped[good.size() / 2] ^= 0x01;
  refused(flipped, kFingerprint, "checksum mismatch");
  refused("", kFingerprint, "not a keyframe database");
  // A word beyond the vocabulary, with the size and checksum made to match:
  // the checks behind the checksum refuse it too.
  KeyframeDatabase bad = database;
  bad.keyframes[1].features.words[3] = 32;
  ASSERT_TRUE(WriteKeyframeDatabase(damaged_path, bad, &error)) << error;
  KeyframeDatabase kept;
  EXPECT_FALSE(ReadKeyframeDatabase(damaged_path, kFingerprint, &kept, &error));
  EXPECT_NE(error.find("keyframe 1: a word the vocabulary does not have"), std::string::npos) << error;
  bad = database;
  bad.keyframes[2].key = bad.keyframes[0].key;
  ASSERT_TRUE(WriteKeyframeDatabase(damaged_path, bad, &error)) << error;
  EXPECT_FALSE(ReadKeyframeDatabase(damaged_path, kFingerprint, &kept, &error));
  EXPECT_NE(error.find("keyframe 2: repeated key"), std::string::npos) << error;
  fs::remove(path);
  fs::remove(damaged_path);
}

}  // namespace
}  // namespace rotation_averaging
