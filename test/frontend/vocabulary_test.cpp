#include "rotation_averaging/frontend/features/vocabulary.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <cstdio>
#include <cstring>
#include <limits>
#include <map>
#include <random>
#include <set>

#include "rotation_averaging/frontend/features/features.h"
#include "rotation_averaging/sim/rig_scene.h"

namespace rotation_averaging {
namespace {

namespace fs = std::filesystem;

// Descriptors of rendered views of a room with textures of `seed`.
std::vector<cv::Mat> RenderedDescriptors(std::uint64_t seed, int captures, int step) {
  RigSceneOptions o;
  o.seed = seed;
  o.num_captures = captures * step;
  const RigScene scene(o);
  FeatureOptions f;
  f.max_features = 800;
  std::vector<cv::Mat> out;
  for (int c = 0; c < captures; ++c) out.push_back(ExtractFeatures(scene.Render(c * step, 0), f).descriptors);
  return out;
}

TEST(VocabularyTest, TrainsAssignsAndRoundTripsThroughItsFile) {
  const std::vector<cv::Mat> training = RenderedDescriptors(7, 6, 10);
  VocabularyOptions options;
  options.words = 64;
  std::string error;
  const std::unique_ptr<Vocabulary> v = Vocabulary::Train(training, options, &error);
  ASSERT_TRUE(v) << error;
  EXPECT_EQ(v->NumWords(), 64);
  EXPECT_EQ(v->Dimension(), 128);
  EXPECT_EQ(v->TrainingImages(), 6);
  const std::vector<int> words = v->Assign(training[0]);
  ASSERT_EQ(static_cast<int>(words.size()), training[0].rows);
  std::set<int> distinct(words.begin(), words.end());
  EXPECT_GT(distinct.size(), 20u);  // the descriptors spread over the words
  for (int w : words) EXPECT_TRUE(w >= 0 && w < 64);
  // Byte descriptors (compact keyframes) give the same words.
  cv::Mat bytes;
  training[0].convertTo(bytes, CV_8U);
  EXPECT_EQ(v->Assign(bytes), words);

  const BowVector bow = v->Describe(training[0]);
  double sum = 0.0;
  for (std::size_t k = 0; k < bow.size(); ++k) {
    sum += bow[k].second;
    if (k > 0) EXPECT_LT(bow[k - 1].first, bow[k].first);
  }
  EXPECT_NEAR(sum, 1.0, 1e-5);
  EXPECT_NEAR(BowScore(bow, bow), 1.0, 1e-5);

  const std::string path = (fs::temp_directory_path() / "rotavg_vocabulary_test.vocab").string();
  ASSERT_TRUE(v->Save(path, &error)) << error;
  const std::unique_ptr<Vocabulary> loaded = Vocabulary::Load(path, &error);
  ASSERT_TRUE(loaded) << error;
  EXPECT_EQ(loaded->Assign(training[3]), v->Assign(training[3]));
  EXPECT_EQ(loaded->TrainingImages(), 6);
  fs::remove(path);
}

TEST(VocabularyTest, TooFewDescriptorsAndMalformedFilesFailWithAMessage) {
  std::string error;
  VocabularyOptions options;
  options.words = 5000;
  EXPECT_FALSE(Vocabulary::Train(RenderedDescriptors(7, 1, 1), options, &error));
  EXPECT_NE(error.find("training descriptors"), std::string::npos) << error;

  const std::string path = (fs::temp_directory_path() / "rotavg_bad.vocab").string();
  auto write = [&](const std::string& bytes) {
    std::ofstream out(path, std::ios::binary);
    out << bytes;
  };
  write("not a vocabulary");
  EXPECT_FALSE(Vocabulary::Load(path, &error));
  EXPECT_NE(error.find("not a vocabulary file"), std::string::npos) << error;
  // A valid header promising more than the file holds.
  std::string header = "ROTAVGVOC2";
  const std::int32_t dimension = 128, cells = 1, words = 16, images = 3;
  for (std::int32_t value : {dimension, cells, words, images}) header.append(reinterpret_cast<const char*>(&value), 4);
  write(header + std::string(100, '\0'));
  EXPECT_FALSE(Vocabulary::Load(path, &error));
  EXPECT_NE(error.find("truncated"), std::string::npos) << error;
  // A NaN centroid.
  std::string data(128 * 4, '\0');
  const float nan = std::numeric_limits<float>::quiet_NaN();
  std::memcpy(&data[0], &nan, 4);
  data.append(reinterpret_cast<const char*>(&words), 4);
  data.append(std::string(16 * 128 * 4 + 16 * 4, '\0'));
  write(header + data);
  EXPECT_FALSE(Vocabulary::Load(path, &error));
  EXPECT_NE(error.find("not finite"), std::string::npos) << error;
  EXPECT_FALSE(Vocabulary::Load(path + ".missing", &error));
  fs::remove(path);
}

TEST(VocabularyTest, InvertedIndexRanksByL1ScoreAndAgreesWithTheDirectScore) {
  // Views of one room, trained on another room's textures: a view scores
  // highest against the views closest to it on the path.
  const std::vector<cv::Mat> training = RenderedDescriptors(11, 8, 7);
  VocabularyOptions options;
  options.words = 128;
  std::string error;
  const std::unique_ptr<Vocabulary> v = Vocabulary::Train(training, options, &error);
  ASSERT_TRUE(v) << error;
  const std::vector<cv::Mat> views = RenderedDescriptors(3, 40, 1);  // 40 consecutive captures
  InvertedIndex index(v->NumWords());
  std::vector<BowVector> bows;
  for (int i = 0; i < 40; i += 2) {  // even captures indexed, id = capture
    bows.push_back(v->Describe(views[i]));
    index.Add(i, bows.back());
  }
  EXPECT_EQ(index.NumEntries(), 20u);
  EXPECT_GT(index.MemoryBytes(), 0u);
  const BowVector query = v->Describe(views[21]);
  const auto all = index.Query(query, 40, 0.0, nullptr);
  ASSERT_FALSE(all.empty());
  for (std::size_t k = 0; k < all.size(); ++k) {
    EXPECT_NEAR(all[k].first, BowScore(query, bows[all[k].second / 2]), 1e-5);
    if (k > 0) EXPECT_GE(all[k - 1].first, all[k].first);
  }
  // The two captures either side of the query's are the best.
  const auto best = index.Query(query, 2, 0.0, nullptr);
  ASSERT_EQ(best.size(), 2u);
  EXPECT_EQ(std::min(best[0].second, best[1].second), 20);
  EXPECT_EQ(std::max(best[0].second, best[1].second), 22);
  // Skipped entries and a score floor.
  const auto skipped = index.Query(query, 3, 0.0, [&](int id) { return id == best[0].second; });
  EXPECT_EQ(skipped[0].second, best[1].second);
  EXPECT_TRUE(index.Query(query, 3, 1.01, nullptr).empty());
}

// Checks what CompactFeatures(full, max, priority) kept: in each cell of the
// 4 x 4 grid, every kept feature is better (higher priority, then stronger)
// than every dropped one, and the cells are filled evenly: each keeps all
// its features or one of two consecutive counts.
void ExpectCompactedByCell(const ImageFeatures& full, const ImageFeatures& compact,
                           const std::vector<std::uint16_t>& priority) {
  const int n = static_cast<int>(full.keypoints_px.size());
  // A kept feature in the full set: same position and, of the features
  // there (SIFT repeats a position with another orientation), the nearest
  // descriptor (compact ones are packed at 4 bits).
  std::map<std::pair<double, double>, std::vector<int>> at;
  for (int i = 0; i < n; ++i) at[{full.keypoints_px[i].x(), full.keypoints_px[i].y()}].push_back(i);
  const cv::Mat descriptors = SiftDescriptorsAsFloat(compact);
  std::vector<bool> kept(n, false);
  for (int r = 0; r < static_cast<int>(compact.keypoints_px.size()); ++r) {
    const Eigen::Vector2d& p = compact.keypoints_px[r];
    int found = -1;
    double nearest = std::numeric_limits<double>::infinity();
    for (int i : at[{p.x(), p.y()}]) {
      const double d = cv::norm(full.descriptors.row(i), descriptors.row(r), cv::NORM_L2);
      if (d < nearest) {
        nearest = d;
        found = i;
      }
    }
    ASSERT_GE(found, 0) << "kept feature " << r << " is not in the full set";
    kept[found] = true;
  }
  auto cell = [&](int i) {
    const Eigen::Vector2d& p = full.keypoints_px[i];
    return std::min(3, static_cast<int>(p.y() * 4 / full.height)) * 4 +
           std::min(3, static_cast<int>(p.x() * 4 / full.width));
  };
  auto score = [&](int i) { return std::make_pair(priority.empty() ? 0 : priority[i], full.strength[i]); };
  std::map<int, std::pair<int, int>> counts;  // cell -> (kept, all)
  for (int i = 0; i < n; ++i) {
    ++counts[cell(i)].second;
    if (!kept[i]) continue;
    ++counts[cell(i)].first;
    for (int j = 0; j < n; ++j) {
      if (!kept[j] && cell(j) == cell(i)) EXPECT_GE(score(i), score(j)) << i << " kept, " << j << " dropped";
    }
  }
  int fewest = n;  // of the cells that dropped some
  for (const auto& [c, k] : counts) {
    if (k.first < k.second) fewest = std::min(fewest, k.first);
  }
  for (const auto& [c, k] : counts) {
    EXPECT_LE(std::min(k.second, fewest), k.first) << "cell " << c;
    EXPECT_LE(k.first, fewest + 1) << "cell " << c;
  }
}

TEST(VocabularyTest, CompactFeaturesKeepTheStrongestOfEveryCellPackedAtFourBits) {
  const RigScene scene(RigSceneOptions{});
  FeatureOptions f;
  f.max_features = 1500;
  const ImageFeatures full = ExtractFeatures(scene.Render(0, 0), f);
  ASSERT_GT(full.keypoints_px.size(), 600u);
  ASSERT_EQ(full.strength.size(), full.keypoints_px.size());
  const ImageFeatures compact = CompactFeatures(full, 500);
  ASSERT_EQ(compact.keypoints_px.size(), 500u);
  EXPECT_EQ(compact.descriptors.type(), CV_8U);
  EXPECT_EQ(compact.descriptors.cols, 64);
  ExpectCompactedByCell(full, compact, {});
  // Kept in their order; each value within half a level of its own in the
  // square root (16 levels).
  const ImageFeatures all = CompactFeatures(full, 100000);
  ASSERT_EQ(all.keypoints_px, full.keypoints_px);
  const ImageFeatures matchable = MatchableFeatures(all);
  ASSERT_EQ(matchable.descriptors.type(), CV_32F);
  ASSERT_EQ(matchable.descriptors.size(), full.descriptors.size());
  double worst = 0.0;
  for (int r = 0; r < full.descriptors.rows; ++r) {
    for (int c = 0; c < full.descriptors.cols; ++c) {
      const double exact = std::sqrt(full.descriptors.at<float>(r, c) / 255.0);
      worst = std::max(worst, std::abs(std::sqrt(matchable.descriptors.at<float>(r, c) / 255.0) - exact));
    }
  }
  EXPECT_LE(worst, 0.5 / 15 + 1e-6);
  EXPECT_GT(worst, 0.0);  // lossy: a test of the packing, not of a copy
  EXPECT_EQ(SiftDescriptorsAsFloat(all).size(), full.descriptors.size());
  EXPECT_LT(FeatureMemoryBytes(compact), FeatureMemoryBytes(full) / 4);
}

// A priority per feature (the front end's: inliers of verified pairs) comes
// before strength within each cell.
TEST(VocabularyTest, CompactFeaturesKeepTheFeaturesOfHighestPriorityFirst) {
  const RigScene scene(RigSceneOptions{});
  FeatureOptions f;
  f.max_features = 1500;
  const ImageFeatures full = ExtractFeatures(scene.Render(0, 0), f);
  const int n = static_cast<int>(full.keypoints_px.size());
  ASSERT_GT(n, 600);
  // Priorities 0-2 unrelated to strength; the weakest third all get 2.
  std::vector<float> sorted = full.strength;
  std::sort(sorted.begin(), sorted.end());
  std::vector<std::uint16_t> priority(n);
  int weak_kept = 0;
  for (int i = 0; i < n; ++i) priority[i] = full.strength[i] <= sorted[n / 3] ? 2 : (i * 7) % 2;
  const ImageFeatures compact = CompactFeatures(full, 500, priority);
  ASSERT_EQ(compact.keypoints_px.size(), 500u);
  ExpectCompactedByCell(full, compact, priority);
  for (float s : compact.strength) weak_kept += s <= sorted[n / 3];
  EXPECT_GT(weak_kept, 250);  // without the priority the weakest would go first
  // A priority of the wrong length is ignored.
  EXPECT_EQ(CompactFeatures(full, 500, std::vector<std::uint16_t>(3, 1)).keypoints_px,
            CompactFeatures(full, 500).keypoints_px);
}

// Matching within the vocabulary's branches (the newer view in its two
// nearest) finds nearly every match of the full kd-tree search, and little
// else, on two overlapping views of a room the vocabulary was not trained on.
TEST(VocabularyTest, MatchingWithinBranchesFindsWhatTheFullSearchFinds) {
  VocabularyOptions options;
  options.words = 1024;
  std::string error;
  const std::unique_ptr<Vocabulary> v = Vocabulary::Train(RenderedDescriptors(7, 12, 5), options, &error);
  ASSERT_TRUE(v) << error;
  EXPECT_EQ(v->NumCells(), 32);
  RigSceneOptions o;
  o.num_captures = 40;
  const RigScene scene(o);
  FeatureOptions f;
  f.max_features = 1500;
  ImageFeatures a = ExtractFeatures(scene.Render(0, 0), f), b = ExtractFeatures(scene.Render(2, 0), f);
  a.words = v->Assign(a.descriptors);
  b.words = v->Assign(b.descriptors);
  // A word's branch is its descriptor's nearest branch.
  const std::vector<int> nearest = v->NearestCells(a.descriptors, 2);
  ASSERT_EQ(nearest.size(), 2 * a.words.size());
  std::vector<int> branch_a;
  for (std::size_t i = 0; i < a.words.size(); ++i) {
    branch_a.push_back(v->CellOf(a.words[i]));
    EXPECT_EQ(branch_a.back(), nearest[2 * i]);
    EXPECT_NE(nearest[2 * i], nearest[2 * i + 1]);
  }
  EXPECT_EQ(v->CellOf(-1), -1);
  EXPECT_EQ(v->CellOf(v->NumWords()), -1);

  // The compact set keeps its features' words (those of the full descriptors).
  const ImageFeatures compact = CompactFeatures(a, 1000);
  ASSERT_EQ(compact.words.size(), compact.keypoints_px.size());
  EXPECT_EQ(CompactFeatures(a, 100000).words, a.words);

  const std::vector<std::pair<int, int>> full = MatchFeatures(a, b);
  const std::vector<std::pair<int, int>> grouped =
      MatchFeaturesByGroup(a, branch_a, b, v->NearestCells(b.descriptors, 2));
  ASSERT_GT(full.size(), 200u);
  const std::set<std::pair<int, int>> in_full(full.begin(), full.end());
  std::size_t common = 0;
  for (const auto& m : grouped) common += in_full.count(m);
  std::printf("full search %zu matches, within branches %zu, %zu in common\n", full.size(), grouped.size(), common);
  EXPECT_GT(common, full.size() * 8 / 10);
  EXPECT_GT(common, grouped.size() * 9 / 10);
  // With a's descriptors packed at 4 bits (a compact keyframe's), nearly
  // the same matches.
  const std::vector<std::pair<int, int>> packed =
      MatchFeaturesByGroup(CompactFeatures(a, 100000), branch_a, b, v->NearestCells(b.descriptors, 2));
  std::set<std::pair<int, int>> in_grouped(grouped.begin(), grouped.end());
  std::size_t kept = 0;
  for (const auto& m : packed) kept += in_grouped.count(m);
  std::printf("within branches %zu matches, packed descriptors %zu, %zu in common\n", grouped.size(), packed.size(), kept);
  EXPECT_GT(kept, grouped.size() * 9 / 10);
  EXPECT_GT(kept, packed.size() * 9 / 10);
  // One branch per feature of b as well: fewer, still most.
  std::vector<int> branch_b;
  for (int w : b.words) branch_b.push_back(v->CellOf(w));
  const std::vector<std::pair<int, int>> hard = MatchFeaturesByGroup(a, branch_a, b, branch_b);
  EXPECT_LT(hard.size(), grouped.size());
  EXPECT_GT(hard.size(), full.size() / 2);
  // Groups that do not fit the features give no matches.
  EXPECT_TRUE(MatchFeaturesByGroup(a, std::vector<int>(3, 0), b, branch_b).empty());
  EXPECT_TRUE(MatchFeaturesByGroup(a, branch_a, b, std::vector<int>(b.words.size() + 1, 0)).empty());
}

}  // namespace
}  // namespace rotation_averaging
