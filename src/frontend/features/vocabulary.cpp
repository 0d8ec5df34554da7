#include "rotation_averaging/frontend/features/vocabulary.h"

#include <faiss/Clustering.h>
#include <faiss/IndexFlat.h>
#include <omp.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <fstream>

#include "rotation_averaging/util/binary_io.h"

namespace rotation_averaging {
namespace {

constexpr char kMagic[] = "ROTAVGVOC2";
constexpr std::size_t kMagicSize = sizeof(kMagic) - 1;
using Idx = faiss::Index::idx_t;

cv::Mat AsFloatRows(const cv::Mat& descriptors) {
  cv::Mat f;
  if (descriptors.type() == CV_32F) f = descriptors;
  else descriptors.convertTo(f, CV_32F);
  return f.isContinuous() ? f : f.clone();
}

// k-means of n points (row-major, d columns) into k centroids with faiss.
std::vector<float> KMeans(const float* points, std::size_t n, int d, int k, const VocabularyOptions& options,
                          std::uint64_t seed) {
  if (static_cast<std::size_t>(k) >= n) return std::vector<float>(points, points + n * d);  // each point a word
  faiss::ClusteringParameters params;
  params.niter = options.iterations;
  params.seed = static_cast<int>(seed & 0x7fffffff);
  params.max_points_per_centroid = std::max(1, options.max_points_per_word);
  params.min_points_per_centroid = 1;  // sparse cells are expected: no warning
  params.verbose = false;
  faiss::Clustering clustering(d, k, params);
  faiss::IndexFlatL2 index(d);
  clustering.train(static_cast<Idx>(n), points, index);
  return clustering.centroids;
}

std::vector<Idx> Nearest(const faiss::IndexFlatL2& index, const float* points, std::size_t n, int k = 1) {
  std::vector<Idx> labels(n * k);
  std::vector<float> distances(n * k);
  if (n == 0) return labels;
  // One OpenMP thread for faiss on this thread: the searches are a few
  // milliseconds, and an OpenMP team would keep spinning on the cores
  // afterwards, taking them from the front end's pair verification.
  const int threads = omp_get_max_threads();
  omp_set_num_threads(1);
  index.search(static_cast<Idx>(n), points, k, distances.data(), labels.data());
  omp_set_num_threads(threads);
  return labels;
}

}  // namespace

// A two-level vocabulary tree (Nister and Stewenius): `branching` top
// centroids, and under each the words of its cell. A descriptor goes to its
// nearest top centroid, then to the nearest word of that cell: 2 x branching
// distances instead of one per word, each level a BLAS product (faiss' flat
// index), so the tree is both faster than a flat search of the words and
// deterministic.
struct Vocabulary::Impl {
  int dimension = 0;
  std::unique_ptr<faiss::IndexFlatL2> top;
  std::vector<std::unique_ptr<faiss::IndexFlatL2>> cells;
  std::vector<int> first_word;  // of each cell; words are numbered cell by cell
  std::vector<float> idf;       // per word

  void AddCell(const float* words, int count) {
    first_word.push_back(static_cast<int>(idf.size()));
    auto cell = std::make_unique<faiss::IndexFlatL2>(dimension);
    cell->add(count, words);
    cells.push_back(std::move(cell));
    idf.resize(idf.size() + count, 0.0f);
  }
};

Vocabulary::Vocabulary() : impl_(new Impl) {}
Vocabulary::~Vocabulary() = default;

int Vocabulary::NumWords() const { return static_cast<int>(impl_->idf.size()); }
int Vocabulary::Dimension() const { return impl_->dimension; }

std::uint64_t Vocabulary::Fingerprint() const {
  const Impl& impl = *impl_;
  Fnv1a sum;
  const std::int32_t header[3] = {impl.dimension, static_cast<std::int32_t>(impl.cells.size()), NumWords()};
  sum.Add(header, sizeof(header));
  sum.Add(impl.top->get_xb(), impl.cells.size() * impl.dimension * sizeof(float));
  for (const auto& cell : impl.cells) {
    const std::int64_t n = cell->ntotal;
    sum.Add(&n, sizeof(n));
    sum.Add(cell->get_xb(), static_cast<std::size_t>(n) * impl.dimension * sizeof(float));
  }
  sum.Add(impl.idf.data(), impl.idf.size() * sizeof(float));
  return sum.h;
}

std::unique_ptr<Vocabulary> Vocabulary::Train(const std::vector<cv::Mat>& descriptors_per_image,
                                              const VocabularyOptions& options, std::string* error) {
  auto fail = [error](const std::string& why) {
    if (error) *error = why;
    return nullptr;
  };
  if (options.words < 2) return fail("a vocabulary needs at least 2 words");
  int dimension = 0;
  std::size_t total = 0;
  for (const cv::Mat& d : descriptors_per_image) {
    if (d.empty()) continue;
    if (dimension == 0) dimension = d.cols;
    if (d.cols != dimension) return fail("descriptors of different lengths");
    if (d.type() != CV_32F && d.type() != CV_8U) return fail("descriptors must be CV_32F or CV_8U");
    total += static_cast<std::size_t>(d.rows);
  }
  if (total < static_cast<std::size_t>(options.words)) {
    return fail("only " + std::to_string(total) + " training descriptors for " + std::to_string(options.words) +
                " words");
  }
  std::vector<float> data;
  data.reserve(total * static_cast<std::size_t>(dimension));
  for (const cv::Mat& d : descriptors_per_image) {
    if (d.empty()) continue;
    const cv::Mat f = AsFloatRows(d);
    data.insert(data.end(), f.ptr<float>(), f.ptr<float>() + static_cast<std::size_t>(f.rows) * dimension);
  }
  std::unique_ptr<Vocabulary> v(new Vocabulary);
  Impl& impl = *v->impl_;
  impl.dimension = dimension;
  const int branching = std::max(2, static_cast<int>(std::ceil(std::sqrt(static_cast<double>(options.words)))));
  try {
    const std::vector<float> top = KMeans(data.data(), total, dimension, branching, options, options.seed);
    impl.top = std::make_unique<faiss::IndexFlatL2>(dimension);
    impl.top->add(static_cast<Idx>(top.size() / dimension), top.data());
    // Split the points by top cell, then cluster each cell into its share of
    // the words (as many as it has points, if fewer).
    const std::vector<Idx> cell_of = Nearest(*impl.top, data.data(), total);
    const int num_cells = static_cast<int>(impl.top->ntotal);
    std::vector<std::vector<float>> members(num_cells);
    for (std::size_t i = 0; i < total; ++i) {
      std::vector<float>& m = members[cell_of[i]];
      m.insert(m.end(), data.begin() + i * dimension, data.begin() + (i + 1) * dimension);
    }
    for (int c = 0; c < num_cells; ++c) {
      const std::size_t n = members[c].size() / dimension;
      if (n == 0) {  // an empty cell keeps its centroid as its one word
        impl.AddCell(top.data() + static_cast<std::size_t>(c) * dimension, 1);
        continue;
      }
      const int k = static_cast<int>(std::min<std::size_t>(n, static_cast<std::size_t>(options.words / num_cells)));
      const std::vector<float> words = KMeans(members[c].data(), n, dimension, std::max(1, k), options,
                                              options.seed + 1 + static_cast<std::uint64_t>(c));
      impl.AddCell(words.data(), static_cast<int>(words.size() / dimension));
    }
  } catch (const std::exception& e) {
    return fail(std::string("k-means failed: ") + e.what());
  }
  // Document frequencies over the training images.
  std::vector<int> images_with(v->NumWords(), 0);
  int images = 0;
  for (const cv::Mat& d : descriptors_per_image) {
    if (d.empty()) continue;
    ++images;
    std::vector<int> words = v->Assign(d);
    std::sort(words.begin(), words.end());
    words.erase(std::unique(words.begin(), words.end()), words.end());
    for (int w : words) ++images_with[w];
  }
  for (int w = 0; w < v->NumWords(); ++w) {
    // Smoothed idf, log(1 + N / n_w): a word every training image holds still
    // counts (a little), so a small training set does not silence most
    // words; a word no training image holds is as rare as one held by one.
    impl.idf[w] = static_cast<float>(std::log1p(static_cast<double>(images) / std::max(1, images_with[w])));
  }
  v->training_images_ = images;
  return v;
}

bool Vocabulary::Save(const std::string& path, std::string* error) const {
  std::ofstream out(path, std::ios::binary);
  if (!out) {
    if (error) *error = "cannot write " + path;
    return false;
  }
  auto put = [&out](std::int32_t value) { out.write(reinterpret_cast<const char*>(&value), sizeof(value)); };
  auto put_floats = [&out](const float* p, std::size_t n) {
    out.write(reinterpret_cast<const char*>(p), static_cast<std::streamsize>(n * sizeof(float)));
  };
  const Impl& impl = *impl_;
  out.write(kMagic, kMagicSize);
  put(Dimension());
  put(static_cast<std::int32_t>(impl.cells.size()));
  put(NumWords());
  put(training_images_);
  put_floats(impl.top->get_xb(), impl.cells.size() * Dimension());
  for (const auto& cell : impl.cells) put(static_cast<std::int32_t>(cell->ntotal));
  for (const auto& cell : impl.cells) put_floats(cell->get_xb(), static_cast<std::size_t>(cell->ntotal) * Dimension());
  put_floats(impl.idf.data(), impl.idf.size());
  out.close();
  if (!out) {
    if (error) *error = "error writing " + path;
    return false;
  }
  return true;
}

std::unique_ptr<Vocabulary> Vocabulary::Load(const std::string& path, std::string* error) {
  auto fail = [&](const std::string& why) {
    if (error) *error = path + ": " + why;
    return nullptr;
  };
  std::ifstream in(path, std::ios::binary);
  if (!in) return fail("cannot open the vocabulary file");
  char magic[kMagicSize];
  if (!in.read(magic, kMagicSize) || std::memcmp(magic, kMagic, kMagicSize) != 0) {
    return fail("not a vocabulary file of this version (train one with `rotavg vocabulary`)");
  }
  std::int32_t header[4];  // dimension, cells, words, images
  if (!in.read(reinterpret_cast<char*>(header), sizeof(header))) return fail("truncated header");
  const std::int32_t dimension = header[0], num_cells = header[1], words = header[2], images = header[3];
  if (dimension < 1 || dimension > 4096 || num_cells < 1 || words < num_cells || words > (1 << 24) || images < 0) {
    return fail("implausible header (" + std::to_string(words) + " words in " + std::to_string(num_cells) +
                " cells of dimension " + std::to_string(dimension) + ")");
  }
  auto read_floats = [&in](std::vector<float>* v, std::size_t n) {
    v->resize(n);
    return static_cast<bool>(in.read(reinterpret_cast<char*>(v->data()), static_cast<std::streamsize>(n * sizeof(float))));
  };
  auto finite = [](const std::vector<float>& v) {
    return std::all_of(v.begin(), v.end(), [](float x) { return std::isfinite(x); });
  };
  std::unique_ptr<Vocabulary> v(new Vocabulary);
  Impl& impl = *v->impl_;
  impl.dimension = dimension;
  std::vector<float> top, cell_words, idf;
  if (!read_floats(&top, static_cast<std::size_t>(num_cells) * dimension)) return fail("truncated data");
  std::vector<std::int32_t> counts(num_cells);
  if (!in.read(reinterpret_cast<char*>(counts.data()), static_cast<std::streamsize>(counts.size() * sizeof(std::int32_t)))) {
    return fail("truncated data");
  }
  std::int64_t sum = 0;
  for (std::int32_t c : counts) {
    if (c < 1) return fail("a cell without words");
    sum += c;
  }
  if (sum != words) return fail("the cells hold " + std::to_string(sum) + " words, the header says " + std::to_string(words));
  if (!finite(top)) return fail("a centroid is not finite");
  impl.top = std::make_unique<faiss::IndexFlatL2>(dimension);
  impl.top->add(num_cells, top.data());
  for (std::int32_t c : counts) {
    if (!read_floats(&cell_words, static_cast<std::size_t>(c) * dimension)) return fail("truncated data");
    if (!finite(cell_words)) return fail("a centroid is not finite");
    impl.AddCell(cell_words.data(), c);
  }
  if (!read_floats(&idf, static_cast<std::size_t>(words))) return fail("truncated data");
  if (in.peek() != std::char_traits<char>::eof()) return fail("trailing bytes after the data");
  for (float w : idf) {
    if (!std::isfinite(w) || w < 0.0f) return fail("an idf weight is negative or not finite");
  }
  impl.idf = idf;
  v->training_images_ = images;
  return v;
}

std::vector<int> Vocabulary::Assign(const cv::Mat& descriptors) const {
  if (descriptors.cols != impl_->dimension && descriptors.rows > 0) return std::vector<int>();
  std::vector<int> words(descriptors.rows, 0);
  if (descriptors.rows == 0) return words;
  const cv::Mat f = AsFloatRows(descriptors);
  const int d = impl_->dimension;
  const std::vector<Idx> cell_of = Nearest(*impl_->top, f.ptr<float>(), static_cast<std::size_t>(f.rows));
  // The rows of each cell together: one product per cell.
  std::vector<std::vector<int>> rows(impl_->cells.size());
  for (int i = 0; i < f.rows; ++i) rows[std::max<Idx>(0, cell_of[i])].push_back(i);
  std::vector<float> batch;
  for (std::size_t c = 0; c < rows.size(); ++c) {
    if (rows[c].empty()) continue;
    batch.resize(rows[c].size() * d);
    for (std::size_t r = 0; r < rows[c].size(); ++r) std::memcpy(&batch[r * d], f.ptr<float>(rows[c][r]), d * sizeof(float));
    const std::vector<Idx> nearest = Nearest(*impl_->cells[c], batch.data(), rows[c].size());
    for (std::size_t r = 0; r < rows[c].size(); ++r) {
      words[rows[c][r]] = impl_->first_word[c] + static_cast<int>(std::max<Idx>(0, nearest[r]));
    }
  }
  return words;
}

int Vocabulary::CellOf(int word) const {
  if (word < 0 || word >= NumWords()) return -1;
  const std::vector<int>& first = impl_->first_word;
  return static_cast<int>(std::upper_bound(first.begin(), first.end(), word) - first.begin()) - 1;
}

int Vocabulary::NumCells() const { return static_cast<int>(impl_->cells.size()); }

std::vector<int> Vocabulary::NearestCells(const cv::Mat& descriptors, int k) const {
  k = std::max(1, std::min(k, NumCells()));
  if (descriptors.rows == 0 || descriptors.cols != impl_->dimension) return std::vector<int>();
  const cv::Mat f = AsFloatRows(descriptors);
  const std::vector<Idx> nearest = Nearest(*impl_->top, f.ptr<float>(), static_cast<std::size_t>(f.rows), k);
  return std::vector<int>(nearest.begin(), nearest.end());
}

BowVector Vocabulary::Describe(const std::vector<int>& words) const {
  std::vector<int> sorted = words;
  std::sort(sorted.begin(), sorted.end());
  BowVector v;
  double total = 0.0;
  for (std::size_t i = 0; i < sorted.size();) {
    std::size_t j = i;
    while (j < sorted.size() && sorted[j] == sorted[i]) ++j;
    const int w = sorted[i];
    if (w >= 0 && w < NumWords() && impl_->idf[w] > 0.0f) {  // a loaded file may hold zero weights
      const float weight = static_cast<float>(j - i) * impl_->idf[w];
      v.emplace_back(w, weight);
      total += weight;
    }
    i = j;
  }
  if (total > 0.0) {
    for (auto& [w, weight] : v) weight = static_cast<float>(weight / total);
  }
  return v;
}

BowVector Vocabulary::Describe(const cv::Mat& descriptors) const { return Describe(Assign(descriptors)); }

double BowScore(const BowVector& a, const BowVector& b) {
  // For non-negative vectors of unit L1 norm, 1 - |a - b|_1 / 2 = sum of min(a_w, b_w).
  double score = 0.0;
  std::size_t i = 0, j = 0;
  while (i < a.size() && j < b.size()) {
    if (a[i].first < b[j].first) ++i;
    else if (b[j].first < a[i].first) ++j;
    else score += std::min(a[i++].second, b[j++].second);
  }
  return score;
}

InvertedIndex::InvertedIndex(int num_words) : postings_(std::max(0, num_words)) {}

void InvertedIndex::Add(int id, const BowVector& v) {
  const int position = static_cast<int>(num_entries_);
  for (const auto& [w, weight] : v) {
    // Zero weights would not count as a shared word (and would read as untouched).
    if (w >= 0 && w < static_cast<int>(postings_.size()) && weight > 0.0f) postings_[w].push_back({position, weight});
  }
  ids_.push_back(id);
  ++num_entries_;
}

std::vector<std::pair<double, int>> InvertedIndex::Query(const BowVector& query, int max_results, double min_score,
                                                         const std::function<bool(int)>& skip) const {
  // Scores accumulate in a dense array over the entries' positions (one
  // pass over the posting lists, no hashing), in the query's word order:
  // the same sums on every run.
  std::vector<double> scores(num_entries_, 0.0);
  std::vector<int> touched;
  for (const auto& [w, weight] : query) {
    if (w < 0 || w >= static_cast<int>(postings_.size())) continue;
    for (const Posting& p : postings_[w]) {
      if (scores[p.position] == 0.0) touched.push_back(p.position);
      scores[p.position] += std::min(weight, p.weight);
    }
  }
  std::vector<std::pair<double, int>> best;
  best.reserve(touched.size());
  for (int position : touched) {
    const int id = ids_[position];
    if (scores[position] >= min_score && !(skip && skip(id))) best.emplace_back(scores[position], id);
  }
  // Best first, ties by the lower id.
  auto better = [](const std::pair<double, int>& a, const std::pair<double, int>& b) {
    return a.first > b.first || (a.first == b.first && a.second < b.second);
  };
  const std::size_t keep = std::min(best.size(), static_cast<std::size_t>(std::max(0, max_results)));
  std::partial_sort(best.begin(), best.begin() + keep, best.end(), better);
  best.resize(keep);
  return best;
}

std::size_t InvertedIndex::MemoryBytes() const {
  std::size_t bytes = postings_.capacity() * sizeof(std::vector<Posting>) + ids_.capacity() * sizeof(int);
  for (const auto& p : postings_) bytes += p.capacity() * sizeof(Posting);
  return bytes;
}

}  // namespace rotation_averaging
