#include "rotation_averaging/frontend/controllers/image_pipeline.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <functional>
#include <iomanip>
#include <limits>
#include <map>
#include <opencv2/imgcodecs.hpp>
#include <sstream>

#include "frontend/geometry/epipolar.h"
#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/util/text_lines.h"
#include "rotation_averaging/util/parallel_for.h"
#include "rotation_averaging/util/time_distribution.h"

namespace rotation_averaging {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;


std::vector<std::pair<int, int>> SelectPairs(int n, const PairSelection& selection,
                                             const std::vector<std::string>& names, std::vector<std::string>* errors) {
  std::vector<std::pair<int, int>> pairs;
  switch (selection.mode) {
    case PairSelection::Mode::kExhaustive:
      for (int i = 0; i < n; ++i)
        for (int j = i + 1; j < n; ++j) pairs.emplace_back(i, j);
      break;
    case PairSelection::Mode::kSequential:
      for (int i = 0; i < n; ++i)
        for (int j = i + 1; j < n && j <= i + selection.window; ++j) pairs.emplace_back(i, j);
      break;
    case PairSelection::Mode::kList: {
      for (const auto& [i, j] : selection.pairs) {
        if (i >= 0 && j >= 0 && i < n && j < n && i != j) pairs.emplace_back(std::min(i, j), std::max(i, j));
      }
      for (const auto& [a, b] : selection.named_pairs) {
        const auto ia = std::find(names.begin(), names.end(), a), ib = std::find(names.begin(), names.end(), b);
        if (ia == names.end() || ib == names.end() || ia == ib) {
          errors->push_back("pair list: '" + a + " " + b + "' does not name two different images");
          continue;
        }
        const int i = static_cast<int>(ia - names.begin()), j = static_cast<int>(ib - names.begin());
        pairs.emplace_back(std::min(i, j), std::max(i, j));
      }
      std::sort(pairs.begin(), pairs.end());
      pairs.erase(std::unique(pairs.begin(), pairs.end()), pairs.end());
      break;
    }
  }
  return pairs;
}

}  // namespace

bool PairSelection::Parse(const std::string& text, PairSelection* selection, std::string* error) {
  if (text.rfind("list:", 0) == 0) {
    LineReader reader(text.substr(5));
    if (!reader.IsOpen()) {
      if (error) *error = "cannot open pair list " + text.substr(5);
      return false;
    }
    std::string line;
    selection->named_pairs.clear();
    while (reader.Next(&line)) {
      if (IsBlankOrComment(line)) continue;
      const std::vector<std::string> t = SplitTokens(line);
      if (t.size() != 2) {
        if (error) *error = reader.Where("expected 'image1 image2'");
        return false;
      }
      selection->named_pairs.emplace_back(t[0], t[1]);
    }
    selection->mode = Mode::kList;
    return true;
  }
  if (text == "exhaustive") {
    selection->mode = Mode::kExhaustive;
    return true;
  }
  if (text.rfind("sequential:", 0) == 0) {
    int window = 0;
    if (!ParseInt(text.substr(11), &window) || window < 1) return false;
    selection->mode = Mode::kSequential;
    selection->window = window;
    return true;
  }
  return false;
}

std::vector<std::string> ListImages(const std::string& directory) {
  std::vector<std::string> images;
  std::error_code ec;
  for (const auto& entry : fs::directory_iterator(directory, ec)) {
    std::string ext = entry.path().extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return std::tolower(c); });
    if (ext == ".jpg" || ext == ".jpeg" || ext == ".png" || ext == ".ppm" || ext == ".pgm" || ext == ".tif" ||
        ext == ".tiff" || ext == ".bmp") {
      images.push_back(entry.path().string());
    }
  }
  std::sort(images.begin(), images.end());
  return images;
}

RelativeRotation EdgeFromPair(const PairReport& pair) {
  RelativeRotation edge;
  edge.view1 = static_cast<ViewId>(pair.image1);
  edge.view2 = static_cast<ViewId>(pair.image2);
  edge.rotation = pair.pose.EdgeRotation();
  edge.has_covariance = true;
  edge.covariance = pair.pose.covariance;
  edge.num_inliers = static_cast<int>(pair.pose.inliers.size());
  edge.source = pair.image2 == pair.image1 + 1 ? EdgeSource::kSequential : EdgeSource::kOther;
  return edge;
}

PairReport EstimatePair(int image1, int image2, const std::vector<Eigen::Vector2d>& points1,
                        const std::vector<Eigen::Vector2d>& points2, const Eigen::Matrix3d& k,
                        const RelativePoseOptions& options) {
  PairReport report;
  report.image1 = image1;
  report.image2 = image2;
  report.matches = static_cast<int>(points1.size());
  report.pose = EstimateRelativePoseWithCovariance(points1, points2, k, k, options);
  if (report.pose.success) {
    report.inlier_points1 = NormalisedPoints(points1, k, report.pose.inliers);
    report.inlier_points2 = NormalisedPoints(points2, k, report.pose.inliers);
  }
  return report;
}

namespace {
// Inliers of a pair in the focal-length profile: within this many of its
// noise standard deviations (the two-view refinement's own rule), and at
// least this many pixels (its smallest adaptive threshold).
constexpr double kFocalInlierSigmas = 3.0;
constexpr double kFocalMinThresholdPx = 0.5;
// Groups of pairs (by index modulo) the jackknife leaves out in turn.
constexpr int kFocalJackknifeGroups = 4;

// A pair of a profile: its matches, its noise and threshold.
struct ProfilePair {
  const FocalPair* pair;
  double sigma, threshold;
};

// The successful essential-matrix pairs with at least min_inliers inliers.
std::vector<ProfilePair> ProfilePairs(const std::vector<FocalPair>& pairs, int min_inliers) {
  std::vector<ProfilePair> used;
  for (const FocalPair& p : pairs) {
    if (!p.pose || !p.points1 || !p.points2 || !p.pose->success || p.pose->model != TwoViewModel::kEssential ||
        !(p.pose->sigma_px > 0.0) || static_cast<int>(p.pose->inliers.size()) < min_inliers) {
      continue;
    }
    used.push_back({&p, p.pose->sigma_px, std::max(kFocalInlierSigmas * p.pose->sigma_px, kFocalMinThresholdPx)});
  }
  return used;
}

// Where the keypoints are taken to be: moved by `warp` (null: as given).
// Moves all of a pair's keypoints of one image at once (one OpenCV call for
// a lens's undistortion).
using PointWarp = std::function<std::vector<Eigen::Vector2d>(const std::vector<Eigen::Vector2d>&)>;

// Each pair's part of the profile's cost with intrinsics k. Every pair's
// pose is refined from its estimate on the matches within its threshold,
// which are selected again at the refined pose (twice, unless they come
// out as they went in: the pose refined on them again is the one it is,
// and a fifth of the profile's refinements went to that), and scored by
// the truncated squared Sampson error of all its matches in units of its
// noise. Selecting the inliers anew matters: those the pose kept with the
// given intrinsics favour them.
std::vector<double> PairCosts(const std::vector<ProfilePair>& used, const Eigen::Matrix3d& k, const PointWarp* warp,
                              int min_inliers, int threads) {
  std::vector<double> per_pair(used.size(), 0.0);
  const Eigen::Matrix3d k_inv = k.inverse();
  ParallelFor(static_cast<int>(used.size()), threads, [&](int u) {
    const FocalPair& p = *used[u].pair;
    std::vector<Eigen::Vector2d> warped1, warped2;
    if (warp) {
      warped1 = (*warp)(*p.points1);
      warped2 = (*warp)(*p.points2);
    }
    const std::vector<Eigen::Vector2d>& all1 = warp ? warped1 : *p.points1;
    const std::vector<Eigen::Vector2d>& all2 = warp ? warped2 : *p.points2;
    Eigen::Matrix3d rotation = p.pose->rotation;
    Eigen::Vector3d translation = p.pose->translation;
    std::vector<int> inliers = p.pose->inliers, selected;
    const double threshold = used[u].threshold;
    double truncated = 0.0;
    for (int round = 0; round < 3; ++round) {
      if (static_cast<int>(inliers.size()) < min_inliers / 2) break;
      RefinePoseOnInliers(all1, all2, inliers, k, k, &rotation, &translation);
      const Eigen::Matrix3d f = k_inv.transpose() * Hat(translation) * rotation * k_inv;
      selected.clear();
      truncated = 0.0;
      for (std::size_t m = 0; m < all1.size() && m < all2.size(); ++m) {
        const double r = SampsonError<double>(f, all1[m].homogeneous(), all2[m].homogeneous());
        if (std::abs(r) < threshold) selected.push_back(static_cast<int>(m));
        truncated += std::min(r * r, threshold * threshold);
      }
      if (selected == inliers) break;
      inliers.swap(selected);
    }
    per_pair[u] = truncated / (used[u].sigma * used[u].sigma);
  });
  return per_pair;
}

// The profile's cost: the pairs' parts summed in their order, without the
// jackknife's group `left_out` (-1: none).
double SumWithout(const std::vector<double>& per_pair, int left_out) {
  double sum = 0.0;
  for (std::size_t u = 0; u < per_pair.size(); ++u) {
    if (static_cast<int>(u % kFocalJackknifeGroups) != left_out) sum += per_pair[u];
  }
  return sum;
}

// The pairs' parts of the cost at every point of one estimate's profiles
// that was evaluated, by the point's parameters. A jackknife's profile
// without one group is the full profile's sum without that group's parts:
// its coarse scan visits the full profile's points, whose parts are all
// here, so it costs only its golden-section steps. A point's parts do not
// depend on which group is left out, so the sums, and the estimate, are
// those of evaluating each profile on its own, bit for bit.
class ProfileMemo {
 public:
  template <typename Compute>
  const std::vector<double>& PairCosts(const std::vector<double>& point, Compute compute) {
    auto it = parts_.find(point);
    if (it == parts_.end()) it = parts_.emplace(point, compute()).first;
    return it->second;
  }
  int Evaluations() const { return static_cast<int>(parts_.size()); }

 private:
  std::map<std::vector<double>, std::vector<double>> parts_;
};

// Keypoints of the pinhole camera k undistorted by the one-parameter
// division model.
PointWarp DivisionWarp(const Eigen::Matrix3d& k, double lambda) {
  const Eigen::Matrix3d k_inv = k.inverse();
  return [k, k_inv, lambda](const std::vector<Eigen::Vector2d>& points) {
    std::vector<Eigen::Vector2d> out;
    out.reserve(points.size());
    for (const Eigen::Vector2d& p : points) {
      const Eigen::Vector2d x = (k_inv * p.homogeneous()).hnormalized();
      // Past the model's turning point (a fisheye's corners at the range's
      // end) the points are held where the division still holds.
      const double denominator = std::max(1.0 + lambda * x.squaredNorm(), 0.2);
      out.push_back((k * (x / denominator).homogeneous()).hnormalized());
    }
    return out;
  };
}

// Keypoints undistorted by `lens` with intrinsics `from_k`, as undistorting
// the same raw pixels with `to_k` would have placed them.
PointWarp LensWarp(const CameraIntrinsics& lens, const Eigen::Matrix3d& from_k, const Eigen::Matrix3d& to_k) {
  return [lens, from_k, to_k](const std::vector<Eigen::Vector2d>& points) {
    std::vector<Eigen::Vector2d> out = points;
    RedoUndistortion(lens, from_k, to_k, &out);
    return out;
  };
}

// The minimum of a profile over [centre - range, centre + range]: a coarse
// scan in steps of `step`, then golden-section search in the best cell's
// neighbours. NaN when it lies on the edge of the range. `best_cell`
// (optional) gets the coarse scan's best cell, -cells..cells.
//
// With a `start_cell` (a nearby profile's best cell) the scan walks from it
// instead: the cell and its neighbours, then downhill until the best cell
// has a visited cell on either side. A profile moved a little from one
// whose minimum is known (the principal point moved by its deviation) is
// found at the same cell as by the whole scan in a fraction of its
// evaluations, unless it has a second, deeper minimum further than the walk
// reaches.
constexpr int kScanAll = std::numeric_limits<int>::min();

double MinimiseProfile(const std::function<double(double)>& cost, double centre, double range, double step,
                       int start_cell = kScanAll, int* best_cell = nullptr) {
  const int cells = static_cast<int>(std::ceil(range / step));
  int best = -cells;
  double best_cost = std::numeric_limits<double>::infinity();
  auto visit = [&](int c) {
    const double value = cost(centre + c * step);
    if (value < best_cost) {
      best_cost = value;
      best = c;
    }
  };
  if (start_cell == kScanAll) {
    for (int c = -cells; c <= cells; ++c) visit(c);
  } else {
    int lo = std::clamp(start_cell - 1, -cells, cells), hi = std::clamp(start_cell + 1, -cells, cells);
    for (int c = lo; c <= hi; ++c) visit(c);
    while (std::isfinite(best_cost) && ((best == lo && lo > -cells) || (best == hi && hi < cells))) {
      if (best == lo) visit(--lo);
      else visit(++hi);
    }
  }
  if (best_cell) *best_cell = best;
  if (!std::isfinite(best_cost) || best == -cells || best == cells) return std::numeric_limits<double>::quiet_NaN();
  double lo = centre + (best - 1) * step, hi = centre + (best + 1) * step;
  const double ratio = 0.5 * (std::sqrt(5.0) - 1.0);
  double x1 = hi - ratio * (hi - lo), x2 = lo + ratio * (hi - lo);
  double f1 = cost(x1), f2 = cost(x2);
  while (hi - lo > 1e-4) {
    if (f1 < f2) {
      hi = x2;
      x2 = x1;
      f2 = f1;
      x1 = hi - ratio * (hi - lo);
      f1 = cost(x1);
    } else {
      lo = x1;
      x1 = x2;
      f1 = f2;
      x2 = lo + ratio * (hi - lo);
      f2 = cost(x2);
    }
  }
  return 0.5 * (lo + hi);
}

// Standard deviation of a profile's minimum x: the larger of the chi-square
// profile's curvature (pixel noise alone) and a delete-a-group jackknife
// over the pairs, which also sees how much the pairs disagree on it.
// cost(x, g): the profile without group g (-1: all pairs); minimise(g): its
// minimum. The profile is not smooth at the finest scales (the inliers are
// selected again at every x): where the smallest step gives no positive
// curvature, wider steps (up to max_step) measure it. `centre`: cost(x, -1)
// when the caller has it already (NaN: computed here).
double ProfileDeviation(const std::function<double(double, int)>& cost, const std::function<double(int)>& minimise,
                        double x, int pairs, double first_step, double max_step,
                        double centre = std::numeric_limits<double>::quiet_NaN()) {
  if (std::isnan(centre)) centre = cost(x, -1);
  double deviation = std::numeric_limits<double>::infinity();
  for (double h = first_step; h < max_step && !std::isfinite(deviation); h *= 4.0) {
    const double curvature = (cost(x + h, -1) - 2.0 * centre + cost(x - h, -1)) / (h * h);
    if (curvature > 0.0) deviation = std::sqrt(2.0 / curvature);
  }
  if (pairs >= 2 * kFocalJackknifeGroups) {
    std::vector<double> partial;
    for (int g = 0; g < kFocalJackknifeGroups; ++g) partial.push_back(minimise(g));
    double mean = 0.0;
    for (double p : partial) mean += p / kFocalJackknifeGroups;
    double spread = 0.0;
    for (double p : partial) spread += (p - mean) * (p - mean);
    const double jackknife = std::sqrt((kFocalJackknifeGroups - 1.0) / kFocalJackknifeGroups * spread);
    deviation = std::isfinite(jackknife) ? std::max(deviation, jackknife) : std::numeric_limits<double>::infinity();
  }
  return deviation;
}
}  // namespace

FocalCalibration EstimateFocalScale(const std::vector<FocalPair>& pairs, const Eigen::Matrix3d& k,
                                    const FocalCalibrationOptions& options, const CameraIntrinsics* lens) {
  FocalCalibration out;
  const std::vector<ProfilePair> used = ProfilePairs(pairs, options.min_inliers);
  out.pairs = static_cast<int>(used.size());
  if (out.pairs < std::max(1, options.min_pairs)) return out;
  const int threads = ResolveThreadCount(options.num_threads);
  // The profile over the scale a of the focal length, for intrinsics `base`
  // (k, or k with its principal point moved). A lens's distortion acts on
  // the normalised coordinates K gives: each K tried undistorts the raw
  // keypoints again, as the camera would with it.
  const bool redo = lens != nullptr && lens->HasDistortion();
  ProfileMemo memo;
  auto cost = [&](const Eigen::Matrix3d& base, double a, int left_out) {
    const std::vector<double>& parts = memo.PairCosts({base(0, 2), base(1, 2), a}, [&] {
      Eigen::Matrix3d ka = base;
      ka(0, 0) *= a;
      ka(1, 1) *= a;
      if (!redo) return PairCosts(used, ka, nullptr, options.min_inliers, threads);
      const PointWarp warp = LensWarp(*lens, k, ka);
      return PairCosts(used, ka, &warp, options.min_inliers, threads);
    });
    return SumWithout(parts, left_out);
  };
  const double range = std::clamp(options.search_range, 0.01, 0.5), step = 0.02;
  auto minimise = [&](const Eigen::Matrix3d& base, int left_out, int start_cell = kScanAll, int* best = nullptr) {
    return MinimiseProfile([&](double a) { return cost(base, a, left_out); }, 1.0, range, step, start_cell, best);
  };
  int best_cell = 0;
  out.scale = minimise(k, -1, kScanAll, &best_cell);
  if (!std::isfinite(out.scale)) {
    out.scale = 1.0;
    out.unobservable = true;
    out.evaluations = memo.Evaluations();
    return out;
  }
  out.matches_deviation = ProfileDeviation([&](double a, int g) { return cost(k, a, g); },
                                           [&](int g) { return minimise(k, g); }, out.scale, out.pairs, 1e-3, 0.02);
  // The principal point moved by its standard deviation along x, then y,
  // both ways: half the change of the estimate is its part of the
  // deviation (FocalCalibrationOptions::principal_point_sigma). An estimate
  // that leaves the search range when it is moved has no useful deviation.
  // Each moved profile is searched from the estimate's cell.
  const double shift = std::max(0.0, options.principal_point_sigma) * 2.0 * k(0, 2);
  double principal_point = 0.0;
  if (shift > 0.0) {
    for (int axis = 0; axis < 2; ++axis) {
      Eigen::Matrix3d plus = k, minus = k;
      plus(axis, 2) += shift;
      minus(axis, 2) -= shift;
      const double change = 0.5 * (minimise(plus, -1, best_cell) - minimise(minus, -1, best_cell));
      principal_point = std::isfinite(change) ? std::hypot(principal_point, change)
                                              : std::numeric_limits<double>::infinity();
    }
  }
  out.evaluations = memo.Evaluations();
  out.principal_point_deviation = principal_point;
  out.standard_deviation = std::hypot(out.matches_deviation, principal_point);
  out.estimated = std::isfinite(out.standard_deviation);
  out.unobservable = !out.estimated;
  return out;
}

RadialDistortion EstimateRadialDistortion(const std::vector<FocalPair>& pairs, const Eigen::Matrix3d& k,
                                         const RadialDistortionOptions& options, const FocalCalibration* focal) {
  RadialDistortion out;
  std::vector<FocalPair> with_parallax;
  for (const FocalPair& p : pairs) {
    if (p.pose && p.pose->median_parallax_deg >= options.min_parallax_deg) with_parallax.push_back(p);
  }
  const std::vector<ProfilePair> used = ProfilePairs(with_parallax, options.min_inliers);
  out.pairs = static_cast<int>(used.size());
  if (out.pairs < std::max(1, options.min_pairs)) return out;
  const int threads = ResolveThreadCount(options.num_threads);
  const Eigen::Matrix3d k_inv = k.inverse();
  ProfileMemo memo;
  auto parts = [&](double lambda) -> const std::vector<double>& {
    return memo.PairCosts({lambda}, [&] {
      const PointWarp warp = DivisionWarp(k, lambda);
      return PairCosts(used, k, &warp, options.min_inliers, threads);
    });
  };
  auto cost = [&](double lambda, int left_out) { return SumWithout(parts(lambda), left_out); };
  const double range = std::clamp(options.search_range, 0.05, 1.0), step = 0.04;
  auto minimise = [&](int left_out) {
    return MinimiseProfile([&](double lambda) { return cost(lambda, left_out); }, 0.0, range, step);
  };
  out.lambda = minimise(-1);
  if (!std::isfinite(out.lambda)) {
    out.lambda = 0.0;
    out.unobservable = true;
    out.evaluations = memo.Evaluations();
    return out;
  }
  // With a focal scale to compare with, each pair's cost at lambda is needed
  // too.
  const bool compare = focal != nullptr && focal->estimated;
  const std::vector<double>& with_distortion = parts(out.lambda);
  const double at_lambda = SumWithout(with_distortion, -1);
  out.standard_deviation = ProfileDeviation(cost, minimise, out.lambda, out.pairs, 2e-3, 0.05, at_lambda);
  out.evaluations = memo.Evaluations();
  const Eigen::Vector2d corner = (k_inv * Eigen::Vector3d(0.0, 0.0, 1.0)).hnormalized();
  const double r2 = corner.squaredNorm();
  out.corner_shift_px = std::abs(out.lambda * r2 / (1.0 + out.lambda * r2)) * corner.norm() * k(0, 0);
  out.estimated = std::isfinite(out.standard_deviation);
  out.unobservable = !out.estimated;
  if (out.estimated && compare) {
    // The focal scale as estimated (from every pair, these among them), not
    // minimised again over these pairs: that would cost a second profile.
    Eigen::Matrix3d ka = k;
    ka(0, 0) *= focal->scale;
    ka(1, 1) *= focal->scale;
    out.cost = at_lambda;
    out.focal_only_scale = focal->scale;
    const std::vector<double> with_focal = PairCosts(used, ka, nullptr, options.min_inliers, threads);
    out.focal_only_cost = SumWithout(with_focal, -1);
    // Paired over the pairs: how consistently each pair prefers the
    // distortion. The profile is not smooth (inliers are selected again at
    // every value), so a sum a few units lower is not yet a better
    // explanation; a distortion that is there lowers every pair's cost.
    const double n = static_cast<double>(used.size());
    double mean = 0.0, spread = 0.0;
    for (std::size_t p = 0; p < used.size(); ++p) mean += (with_focal[p] - with_distortion[p]) / n;
    for (std::size_t p = 0; p < used.size(); ++p) {
      const double d = with_focal[p] - with_distortion[p] - mean;
      spread += d * d;
    }
    out.advantage_deviation = n > 1.0 ? std::sqrt(n * spread / (n - 1.0)) : std::numeric_limits<double>::infinity();
  }
  return out;
}

bool DistortionBeyondNoise(const RadialDistortion& distortion, const RadialDistortionOptions& options) {
  return distortion.estimated && distortion.corner_shift_px > options.min_corner_shift_px &&
         std::abs(distortion.lambda) > 3.0 * distortion.standard_deviation;
}

bool DistortionIsUnmodelled(const RadialDistortion& distortion, const RadialDistortionOptions& options) {
  return DistortionBeyondNoise(distortion, options) && !distortion.FocalExplainsAsWell();
}

bool ShouldApplyFocalScale(const FocalCalibration& calibration, const FocalCalibrationOptions& options) {
  const double correction = std::abs(calibration.scale - 1.0);
  return calibration.estimated && correction > options.min_correction &&
         correction > 3.0 * calibration.standard_deviation;
}

std::string FocalCalibration::Report() const {
  std::ostringstream out;
  out << std::setprecision(4);
  if (!estimated) {
    out << "focal length: not estimated (" << pairs << " pairs with enough inliers"
        << (unobservable ? "; the pairs do not determine it within the search range" : "") << ")";
  } else {
    out << "focal length: estimated x" << scale << " (+- " << standard_deviation << ": " << matches_deviation
        << " from the matches of " << pairs << " pairs, " << principal_point_deviation
        << " from the principal point), "
        << (applied ? "applied: pairs estimated again" : "kept as given (too small or too uncertain a correction)");
  }
  return out.str();
}

std::vector<EdgeCorrespondences> CorrespondencesOfEdges(const ImagePipelineResult& result) {
  const double focal = 0.5 * (result.k(0, 0) + result.k(1, 1));
  std::vector<EdgeCorrespondences> out;
  for (const PairReport& p : result.pairs) {
    if (!p.pose.success || p.inlier_points1.empty()) continue;
    out.push_back(MakeEdgeCorrespondences(static_cast<ViewId>(p.image1), static_cast<ViewId>(p.image2),
                                          p.inlier_points1, p.inlier_points2, p.pose.translation, p.pose.sigma_px,
                                          focal));
  }
  return out;
}

ImagePipelineResult BuildViewGraphFromFeatures(const std::vector<ImageFeatures>& features,
                                               const std::vector<std::string>& names, const Eigen::Matrix3d& k,
                                               const ImagePipelineOptions& options, const CameraIntrinsics* lens) {
  ImagePipelineResult result;
  result.k = k;
  const int n = static_cast<int>(features.size());
  for (int i = 0; i < n; ++i) {
    result.graph.AddView(static_cast<ViewId>(i), i < static_cast<int>(names.size()) ? names[i] : "");
    result.features_per_image.push_back(static_cast<int>(features[i].keypoints_px.size()));
  }
  // One nearest-neighbour index per image, reused by every pair it is in.
  const auto index_start = Clock::now();
  std::vector<std::unique_ptr<FeatureIndex>> indices;
  for (const ImageFeatures& f : features) indices.push_back(std::make_unique<FeatureIndex>(f));
  result.matching_s += SecondsSince(index_start);
  // The relative pose of one pair into the graph and the counts.
  auto add_pair = [&](int i, int j, const std::vector<Eigen::Vector2d>& p1, const std::vector<Eigen::Vector2d>& p2,
                      const Eigen::Matrix3d& pair_k, Clock::time_point start) {
    const auto pose_start = Clock::now();
    PairReport report = EstimatePair(i, j, p1, p2, pair_k, options.relative_pose);
    result.relative_pose_s += SecondsSince(pose_start);
    report.milliseconds = 1e3 * SecondsSince(start);
    if (report.pose.success) {
      if (report.pose.homography_inlier_ratio >= options.relative_pose.near_planar_report_ratio) ++result.near_planar_pairs;
      if (report.pose.model == TwoViewModel::kRotation) ++result.rotation_model_pairs;
      std::string why;
      if (result.graph.AddEdge(EdgeFromPair(report), &why) == AddEdgeResult::kRejected) {
        report.pose.success = false;
        report.pose.message = "edge rejected: " + why;
        ++result.failures["edge_rejected"];
      }
    } else {
      ++result.failures[TwoViewFailureName(report.pose.failure)];
    }
    result.pairs.push_back(std::move(report));
  };
  // The matched keypoints of every pair, kept for a second estimation with a
  // corrected focal length.
  struct Matched {
    int i, j;
    std::vector<Eigen::Vector2d> p1, p2;
  };
  std::vector<Matched> matched;
  for (const auto& [i, j] : SelectPairs(n, options.pairs, names, &result.errors)) {
    const auto start = Clock::now();
    const std::vector<std::pair<int, int>> matches =
        MatchFeatures(features[i], *indices[i], features[j], *indices[j], options.matching);
    result.matching_s += SecondsSince(start);
    Matched m{i, j, {}, {}};
    m.p1.reserve(matches.size());
    m.p2.reserve(matches.size());
    for (const auto& [a, b] : matches) {
      m.p1.push_back(features[i].keypoints_px[a]);
      m.p2.push_back(features[j].keypoints_px[b]);
    }
    add_pair(i, j, m.p1, m.p2, k, start);
    if (options.focal.enabled) matched.push_back(std::move(m));
  }
  if (options.focal.enabled) {
    const auto focal_start = Clock::now();
    std::vector<FocalPair> focal_pairs;
    for (std::size_t p = 0; p < matched.size(); ++p) {
      focal_pairs.push_back({&matched[p].p1, &matched[p].p2, &result.pairs[p].pose});
    }
    result.focal = EstimateFocalScale(focal_pairs, k, options.focal, lens);
    if (ShouldApplyFocalScale(result.focal, options.focal)) {
      result.focal.applied = true;
      result.k = k;
      result.k(0, 0) *= result.focal.scale;
      result.k(1, 1) *= result.focal.scale;
      // A raw image's keypoints were undistorted with the old K.
      if (lens != nullptr) {
        for (Matched& m : matched) {
          RedoUndistortion(*lens, k, result.k, &m.p1);
          RedoUndistortion(*lens, k, result.k, &m.p2);
        }
      }
      // Every pair again, from its matches, in the corrected focal length.
      ViewGraph graph;
      for (const View& v : result.graph.Views()) graph.AddView(v.id, v.name);
      result.graph = std::move(graph);
      result.pairs.clear();
      result.failures.clear();
      result.near_planar_pairs = 0;
      result.rotation_model_pairs = 0;
      for (const Matched& m : matched) add_pair(m.i, m.j, m.p1, m.p2, result.k, Clock::now());
    }
    result.focal_s = SecondsSince(focal_start);
  }
  return result;
}

Eigen::Matrix3d FeatureIntrinsics(const CameraIntrinsics& intrinsics, const FeatureOptions& options) {
  return ScaleIntrinsics(intrinsics.k, options.downsample > 0.0 ? options.downsample : 1.0);
}

std::vector<ImageFeatures> ExtractImageFeatures(const std::vector<std::string>& image_paths,
                                                const CameraIntrinsics& intrinsics, const FeatureOptions& options,
                                                std::vector<std::string>* names, std::vector<std::string>* errors) {
  std::vector<ImageFeatures> features(image_paths.size());
  const Eigen::Matrix3d scaled_k = FeatureIntrinsics(intrinsics, options);
  names->clear();
  for (std::size_t i = 0; i < image_paths.size(); ++i) {
    names->push_back(fs::path(image_paths[i]).filename().string());
    const cv::Mat image = cv::imread(image_paths[i], cv::IMREAD_GRAYSCALE);
    if (image.empty()) {
      errors->push_back("cannot read image " + image_paths[i]);
      continue;
    }
    features[i] = ExtractFeatures(image, options);
    UndistortFeatures(intrinsics, scaled_k, &features[i]);
  }
  return features;
}

ImagePipelineResult BuildViewGraphFromImages(const std::vector<std::string>& image_paths,
                                             const CameraIntrinsics& intrinsics, const ImagePipelineOptions& options) {
  std::vector<std::string> names, errors;
  const auto start = Clock::now();
  const std::vector<ImageFeatures> features =
      ExtractImageFeatures(image_paths, intrinsics, options.features, &names, &errors);
  const double features_s = SecondsSince(start);
  ImagePipelineResult result =
      BuildViewGraphFromFeatures(features, names, FeatureIntrinsics(intrinsics, options.features), options, &intrinsics);
  result.features_s = features_s;
  result.errors = std::move(errors);
  return result;
}

std::string ImagePipelineResult::Report() const {
  std::ostringstream out;
  const int n = static_cast<int>(features_per_image.size());
  int ok = 0;
  for (const PairReport& p : pairs) ok += p.pose.success;
  double mean_features = 0.0;
  for (int f : features_per_image) mean_features += f;
  out << std::fixed << std::setprecision(1) << "images: " << n << ", features per image: "
      << (n ? mean_features / n : 0.0) << "\npairs: " << pairs.size() << " tried, " << ok << " with a relative pose";
  for (const auto& [reason, count] : failures) out << "\n  rejected (" << reason << "): " << count;
  if (near_planar_pairs) out << "\n  kept, near-planar (homography explains >= 95% of the inliers): " << near_planar_pairs;
  if (rotation_model_pairs) out << "\n  kept, rotation-only model (no measurable translation): " << rotation_model_pairs;
  out << "\ntime: features " << features_s << " s (" << (n ? 1e3 * features_s / n : 0.0) << " ms/image), matching "
      << matching_s << " s, relative pose + covariance " << relative_pose_s << " s ("
      << (pairs.empty() ? 0.0 : 1e3 * (matching_s + relative_pose_s) / pairs.size()) << " ms/pair)";
  if (focal.pairs > 0 || focal.estimated) out << "\n" << focal.Report() << " (" << focal_s << " s)";
  for (const std::string& e : errors) out << "\nerror: " << e;
  return out.str();
}

}  // namespace rotation_averaging
