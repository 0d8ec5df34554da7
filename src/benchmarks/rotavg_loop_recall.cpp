// rotavg_loop_recall: how many of the loop closures an exhaustive two-view
// search can verify does the keyframe front end's retrieval find?
//
//   rotavg_loop_recall --exhaustive exhaustive_graph.txt --keyframes replay_graph.txt --gt GT
//       [--window 5] [--min-inliers 60] [--max-error-deg 2]
//
// exhaustive_graph.txt: `rotavg images --pairs exhaustive --graph-out` on the
// image folder (views named by file name); replay_graph.txt: the graph saved
// by rotation_averaging_replay on a bag made from the same folder (views
// named <frame>@<stamp_ns>). Both are put in image order (file names sorted;
// keyframe stamps sorted) and compared by index. A loop pair is a pair more
// than `window` images apart; it is verifiable when the exhaustive search
// related it with at least `min_inliers` inliers, and correct when its
// rotation is within `max_error_deg` of the ground truth.
#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <map>
#include <set>
#include <string>
#include <vector>

#include "rotation_averaging/core/controllers/online_averager.h"
#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/core/io/graph_io.h"
#include "rotation_averaging/core/io/orientation_io.h"
#include "rotation_averaging/util/freed_memory.h"

namespace ra = rotation_averaging;

namespace {

struct Pair {
  int a, b;  // image indices, a < b
  int inliers;
  double error_deg;
  double nees;  // whitened squared error against the edge's covariance; -1 without one
};

double Median(std::vector<double> values) {
  std::sort(values.begin(), values.end());
  const std::size_t n = values.size();
  return n % 2 ? values[n / 2] : 0.5 * (values[n / 2 - 1] + values[n / 2]);
}

// Edges of a graph file as image-index pairs with their error against the
// ground truth (given in the same image order).
bool LoadPairs(const std::string& path, bool keyframe_names, const std::vector<Eigen::Matrix3d>& truth,
               ra::EdgeSource only, bool filter_source, std::vector<Pair>* pairs, std::string* error) {
  ra::ViewGraph graph;
  const ra::ReadReport report = ra::ReadRotavgGraph(path, &graph);
  if (!report.ok()) {
    *error = report.error;
    return false;
  }
  // Image order: by name (file names) or by stamp (keyframes).
  std::vector<std::pair<std::string, ra::ViewId>> order;
  for (const ra::View& v : graph.Views()) {
    std::string key = v.name;
    if (keyframe_names) {
      ra::KeyframeKey k;
      if (!ra::OnlineAverager::ParseKeyframeName(v.name, &k)) {
        *error = "view name " + v.name + " is not <frame>@<stamp_ns>";
        return false;
      }
      char buffer[32];
      std::snprintf(buffer, sizeof(buffer), "%020lld", static_cast<long long>(k.stamp_ns));
      key = buffer;
    }
    order.emplace_back(key, v.id);
  }
  std::sort(order.begin(), order.end());
  if (order.size() != truth.size()) {
    *error = path + " has " + std::to_string(order.size()) + " views, the ground truth " + std::to_string(truth.size());
    return false;
  }
  std::map<ra::ViewId, int> index;
  for (std::size_t k = 0; k < order.size(); ++k) index[order[k].second] = static_cast<int>(k);
  for (const ra::RelativeRotation& e : graph.Edges()) {
    if (filter_source && e.source != only) continue;
    const int a = index[e.view1], b = index[e.view2];
    const Eigen::Matrix3d true_rotation = truth[a] * truth[b].transpose();
    const double err = ra::RadToDeg(ra::AngularDistanceRad(e.rotation, true_rotation));
    double nees = -1.0;
    if (e.has_covariance) {
      // Right perturbation: R_true = R_12 Exp(delta).
      const Eigen::Vector3d delta = ra::LogSO3(e.rotation.transpose() * true_rotation);
      const Eigen::LDLT<Eigen::Matrix3d> ldlt(e.covariance);
      if (ldlt.info() == Eigen::Success && ldlt.isPositive()) nees = delta.dot(ldlt.solve(delta));
    }
    pairs->push_back(Pair{std::min(a, b), std::max(a, b), e.num_inliers, err, nees});
  }
  return true;
}

}  // namespace

int main(int argc, char** argv) {
  rotation_averaging::KeepFreedMemoryForReuse();  // util/freed_memory.h: buffers of each image reused, not faulted in again
  std::string exhaustive, keyframes, gt;
  int window = 5, min_inliers = 60;
  double max_error = 2.0;
  for (int k = 1; k + 1 < argc; k += 2) {
    const std::string a = argv[k], v = argv[k + 1];
    if (a == "--exhaustive") exhaustive = v;
    else if (a == "--keyframes") keyframes = v;
    else if (a == "--gt") gt = v;
    else if (a == "--window") window = std::atoi(v.c_str());
    else if (a == "--min-inliers") min_inliers = std::atoi(v.c_str());
    else if (a == "--max-error-deg") max_error = std::atof(v.c_str());
  }
  if (exhaustive.empty() || keyframes.empty() || gt.empty()) {
    std::cerr << "usage: rotavg_loop_recall --exhaustive G --keyframes G --gt GT [--window 5] [--min-inliers 60]"
                 " [--max-error-deg 2]\n";
    return 2;
  }
  ra::NamedOrientations named;
  const ra::ReadReport report = ra::ReadGroundTruth(gt, ra::GroundTruthFormat::kAuto, &named);
  if (!report.ok()) {
    std::cerr << "ground truth: " << report.error << "\n";
    return 1;
  }
  std::vector<Eigen::Matrix3d> truth;
  for (const auto& [name, r] : named) truth.push_back(r);  // sorted by image name
  std::vector<Pair> all, found;
  std::string error;
  if (!LoadPairs(exhaustive, false, truth, ra::EdgeSource::kOther, false, &all, &error) ||
      !LoadPairs(keyframes, true, truth, ra::EdgeSource::kLoopClosure, true, &found, &error)) {
    std::cerr << error << "\n";
    return 1;
  }
  std::set<std::pair<int, int>> verifiable, correct;
  for (const Pair& p : all) {
    if (p.b - p.a <= window || p.inliers < min_inliers) continue;
    verifiable.insert({p.a, p.b});
    if (p.error_deg < max_error) correct.insert({p.a, p.b});
  }
  int found_correct = 0, found_wrong = 0;
  std::cout << "loop closures found by retrieval (image pair, inliers, error deg):";
  for (const Pair& p : found) {
    std::cout << " (" << p.a << "," << p.b << ", " << p.inliers << ", " << p.error_deg << ")";
    if (p.error_deg < max_error) ++found_correct; else ++found_wrong;
  }
  int recalled = 0;
  for (const Pair& p : found) recalled += correct.count({p.a, p.b});
  std::cout << "\nloop pairs (more than " << window << " images apart) the exhaustive search verifies with >= "
            << min_inliers << " inliers: " << verifiable.size() << ", of them correct (< " << max_error
            << " deg): " << correct.size() << "\nfound by retrieval: " << found.size() << " (" << found_correct
            << " correct, " << found_wrong << " wrong)\nrecall of the correct verifiable loop pairs: " << recalled
            << " / " << correct.size() << "\n";
  std::cout << "correct verifiable pairs:";
  for (const auto& [a, b] : correct) std::cout << " (" << a << "," << b << ")";
  // Inliers of a found loop against those the exhaustive search (all
  // features of both images) gave the same pair: what a compact keyframe
  // keeps.
  std::map<std::pair<int, int>, int> exhaustive_inliers;
  for (const Pair& p : all) exhaustive_inliers[{p.a, p.b}] = p.inliers;
  std::vector<double> kept;
  std::cout << "\ninliers of the found loops against the exhaustive search's:";
  for (const Pair& p : found) {
    const auto it = exhaustive_inliers.find({p.a, p.b});
    if (it == exhaustive_inliers.end() || it->second <= 0) continue;
    kept.push_back(static_cast<double>(p.inliers) / it->second);
    std::cout << " (" << p.a << "," << p.b << ") " << p.inliers << "/" << it->second;
  }
  char text[32];
  if (!kept.empty()) {
    std::snprintf(text, sizeof(text), "%.2f", Median(kept));
    std::cout << "; median fraction " << text;
  }
  // How far the found loops are from what their covariances say (3 on
  // average when calibrated; the 50% quantile of chi2(3) is 2.37).
  std::vector<double> nees;
  std::cout << "\nwhitened squared errors (NEES) of the found loops:";
  for (const Pair& p : found) {
    if (p.nees < 0.0) continue;
    nees.push_back(p.nees);
    std::snprintf(text, sizeof(text), "%.1f", p.nees);
    std::cout << " (" << p.a << "," << p.b << ") " << text;
  }
  if (!nees.empty()) {
    std::snprintf(text, sizeof(text), "%.1f", Median(nees));
    std::cout << "; median " << text;
  }
  std::cout << std::endl;
  return 0;
}
