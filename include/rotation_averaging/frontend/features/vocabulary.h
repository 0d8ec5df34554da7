// Public header of rotation_averaging::frontend (docs/embedding.md).
// A visual vocabulary for place recognition: a two-level vocabulary tree of
// SIFT descriptors (k-means with faiss, sqrt(words) branches, then the words
// of each branch), tf-idf bag-of-words vectors, and an inverted index that
// finds the keyframes sharing the most weighted words with a query.
//
// The cost of a query is the assignment of its descriptors to words (fixed)
// plus one pass over the posting lists of its words; with a vocabulary of
// thousands of words those lists are short, so the cost barely grows with the
// map. The score is DBoW2's L1 score of L1-normalised tf-idf vectors:
// 1 - |v - w|_1 / 2, in [0, 1].
#ifndef ROTATION_AVERAGING_FRONTEND_FEATURES_VOCABULARY_H_
#define ROTATION_AVERAGING_FRONTEND_FEATURES_VOCABULARY_H_

#include <cstdint>
#include <functional>
#include <memory>
#include <opencv2/core.hpp>
#include <string>
#include <utility>
#include <vector>

namespace rotation_averaging {

struct VocabularyOptions {
  int words = 4096;              // leaves of the tree (fewer if the training data is short of them)
  int iterations = 20;           // k-means iterations
  int max_points_per_word = 128; // training descriptors are subsampled to at most words x this
  std::uint64_t seed = 20230618;
};

// (word, weight) sorted by word; weights are tf-idf, L1-normalised.
using BowVector = std::vector<std::pair<int, float>>;

class Vocabulary {
 public:
  ~Vocabulary();

  // Trains on the SIFT descriptors of a set of images (one CV_32F matrix per
  // image, 128 columns). The idf of a word is log(1 + images / images
  // containing it). Fails with a message when there are fewer descriptors than words.
  static std::unique_ptr<Vocabulary> Train(const std::vector<cv::Mat>& descriptors_per_image,
                                           const VocabularyOptions& options, std::string* error);
  // Binary file written by Save (magic "ROTAVGVOC2"; dimension, cells, words,
  // training images; the cells' centroids, their word counts, the words'
  // centroids, the idf; little-endian). Fails with a message on a malformed file.
  static std::unique_ptr<Vocabulary> Load(const std::string& path, std::string* error);
  bool Save(const std::string& path, std::string* error) const;

  int NumWords() const;
  int Dimension() const;
  int TrainingImages() const { return training_images_; }
  // A 64-bit checksum of everything that decides words and scores (centroids,
  // cells, idf): two vocabularies with the same fingerprint assign the same
  // words. Saved keyframes record it, so that words of another vocabulary
  // are never mixed into an index.
  std::uint64_t Fingerprint() const;

  // The nearest word of each descriptor row (CV_32F or CV_8U, Dimension()
  // columns). Deterministic; safe to call from several threads at once.
  std::vector<int> Assign(const cv::Mat& descriptors) const;
  // The first-level branch of the tree a word belongs to, in [0, NumCells()):
  // descriptors in different branches are far apart, so matching can be
  // confined to each branch (MatchFeaturesByGroup). -1 for an unknown word.
  int CellOf(int word) const;
  int NumCells() const;
  // The k nearest branches of each descriptor row, nearest first (rows x k,
  // row-major; -1 where there are fewer branches).
  std::vector<int> NearestCells(const cv::Mat& descriptors, int k) const;
  // The tf-idf vector of one image's descriptors.
  BowVector Describe(const cv::Mat& descriptors) const;
  BowVector Describe(const std::vector<int>& words) const;

 private:
  Vocabulary();
  struct Impl;
  std::unique_ptr<Impl> impl_;
  int training_images_ = 0;
};

// DBoW2's L1 score of two L1-normalised vectors, in [0, 1].
double BowScore(const BowVector& a, const BowVector& b);

// word -> (entry, weight) posting lists over the added vectors.
class InvertedIndex {
 public:
  explicit InvertedIndex(int num_words);
  // Entries may have any ids.
  void Add(int id, const BowVector& v);
  // The `max_results` best entries by L1 score with `query`, best first (ties
  // by lower id), skipping those `skip` returns true for and those scoring
  // below `min_score`.
  std::vector<std::pair<double, int>> Query(const BowVector& query, int max_results, double min_score,
                                            const std::function<bool(int)>& skip) const;
  std::size_t NumEntries() const { return num_entries_; }
  std::size_t MemoryBytes() const;

 private:
  struct Posting {
    int position;  // order of addition
    float weight;
  };
  std::vector<std::vector<Posting>> postings_;
  std::vector<int> ids_;  // by position
  std::size_t num_entries_ = 0;
};

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_FRONTEND_FEATURES_VOCABULARY_H_
