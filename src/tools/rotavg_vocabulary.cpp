// rotavg_vocabulary: `rotavg vocabulary`, trains the visual vocabulary the
// keyframe front end finds loop-closure candidates with (k-means on SIFT
// descriptors with faiss, idf over the training images). Train it on images
// like the ones the robot will see, but not the sequences you evaluate on.
#include <algorithm>
#include <chrono>
#include <filesystem>
#include <iostream>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <string>
#include <vector>

#include "cli.h"
#include "rotation_averaging/frontend/features/features.h"
#include "rotation_averaging/frontend/features/vocabulary.h"
#include "rotation_averaging/util/parallel_for.h"

namespace {

using namespace rotation_averaging_cli;  // NOLINT: the tool's own helpers
namespace fs = std::filesystem;

const char* kUsage = R"(usage:
  rotavg vocabulary --output FILE [--words N] [--max-features N] [--max-size PX] [--iterations N] [--threads N] DIR|IMAGE...
      trains a vocabulary of N words (default 4096) on the SIFT descriptors of the given images (folders are
      searched recursively for .jpg, .jpeg, .png, .ppm, .pgm, .bmp, .tif); each image is first shrunk so its
      longer side is at most --max-size pixels (default 1024), and keeps its --max-features strongest
      features (default 2000). Set the front end's `vocabulary` parameter to FILE.
)";

bool IsImage(const fs::path& p) {
  std::string ext = p.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return ext == ".jpg" || ext == ".jpeg" || ext == ".png" || ext == ".ppm" || ext == ".pgm" || ext == ".bmp" ||
         ext == ".tif" || ext == ".tiff";
}

int Train(int argc, char** argv) {
  Args args;
  std::string error;
  if (!ParseArgs(argc, argv, 1, {}, &args, &error)) return Fail(error);
  if (!CheckKnown(args, {"--output", "--words", "--max-features", "--max-size", "--iterations", "--threads"}, &error)) {
    return Fail(error);
  }
  const std::string output = args.Get("--output");
  if (output.empty() || args.positional.empty()) return Fail(std::string("vocabulary needs --output and images\n") + kUsage);
  ra::VocabularyOptions options;
  options.words = std::atoi(args.Get("--words", "4096").c_str());
  options.iterations = std::atoi(args.Get("--iterations", "20").c_str());
  const int max_features = std::atoi(args.Get("--max-features", "2000").c_str());
  const int max_size = std::atoi(args.Get("--max-size", "1024").c_str());
  const int threads = std::atoi(args.Get("--threads", "0").c_str());
  if (options.words < 2 || options.iterations < 1 || max_features < 10 || max_size < 64 || threads < 0) {
    return Fail("--words >= 2, --iterations >= 1, --max-features >= 10, --max-size >= 64, --threads >= 0");
  }
  std::vector<fs::path> images;
  for (const std::string& p : args.positional) {
    std::error_code ec;
    if (fs::is_directory(p, ec)) {
      for (const auto& e : fs::recursive_directory_iterator(p, fs::directory_options::skip_permission_denied, ec)) {
        if (e.is_regular_file() && IsImage(e.path())) images.push_back(e.path());
      }
    } else if (fs::is_regular_file(p, ec)) {
      images.push_back(p);
    } else {
      return Fail("no such image or folder: " + p);
    }
  }
  std::sort(images.begin(), images.end());  // the same vocabulary whatever the directory order
  if (images.empty()) return Fail("no images found");

  const auto start = std::chrono::steady_clock::now();
  std::vector<cv::Mat> descriptors(images.size());
  std::vector<std::string> skipped(images.size());
  ra::ParallelFor(static_cast<int>(images.size()), ra::ResolveThreadCount(threads), [&](int i) {
    cv::Mat image = cv::imread(images[i].string(), cv::IMREAD_GRAYSCALE);
    if (image.empty()) {
      skipped[i] = "does not decode";
      return;
    }
    ra::FeatureOptions f;
    f.max_features = max_features;
    const int longer = std::max(image.cols, image.rows);
    if (longer > max_size) f.downsample = static_cast<double>(max_size) / longer;
    descriptors[i] = ra::ExtractFeatures(image, f).descriptors;
  });
  std::size_t total = 0;
  int used = 0;
  for (std::size_t i = 0; i < images.size(); ++i) {
    if (!skipped[i].empty()) std::cerr << "warning: skipped " << images[i].string() << ": " << skipped[i] << "\n";
    if (!descriptors[i].empty()) ++used;
    total += static_cast<std::size_t>(descriptors[i].rows);
  }
  const double features_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::cout << "features: " << total << " SIFT descriptors from " << used << " of " << images.size() << " images ("
            << features_s << " s)" << std::endl;
  const auto train_start = std::chrono::steady_clock::now();
  const std::unique_ptr<ra::Vocabulary> vocabulary = ra::Vocabulary::Train(descriptors, options, &error);
  if (!vocabulary) return Fail(error);
  if (!vocabulary->Save(output, &error)) return Fail(error);
  const double train_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - train_start).count();
  std::cout << "wrote " << output << ": " << vocabulary->NumWords() << " words, idf over "
            << vocabulary->TrainingImages() << " images (k-means " << train_s << " s)" << std::endl;
  return 0;
}

}  // namespace

int main(int argc, char** argv) { return rotation_averaging_cli::RunCommand(argc, argv, kUsage, Train); }
