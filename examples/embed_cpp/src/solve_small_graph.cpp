// Embeds the averager: a loop of four views whose relative rotations (each
// with its 3x3 covariance) disagree slightly, plus one wrong edge, solved with
// the defaults (MAGSAC++ loss, covariance weighting). Prints the orientations
// and which edges the robust loss rejected.
#include <cmath>
#include <cstdio>

#include "rotation_averaging/core/estimators/rotation_averaging.h"
#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/core/scene/view_graph.h"

namespace ra = rotation_averaging;

int main() {
  // Ground truth, world-to-camera: 30 degrees apart about the vertical axis.
  const auto yaw = [](double degrees) { return ra::ExpSO3(Eigen::Vector3d(0.0, degrees * M_PI / 180.0, 0.0)); };
  const Eigen::Matrix3d truth[4] = {yaw(0), yaw(30), yaw(60), yaw(90)};

  ra::ViewGraph graph;
  for (ra::ViewId id = 0; id < 4; ++id) graph.AddView(id, "view" + std::to_string(id));
  const auto add = [&](ra::ViewId i, ra::ViewId j, const Eigen::Vector3d& noise_rad, double sigma_rad) {
    ra::RelativeRotation edge;
    edge.view1 = i;
    edge.view2 = j;
    edge.rotation = truth[i] * truth[j].transpose() * ra::ExpSO3(noise_rad);  // R_ij = R_i R_j^T, perturbed
    edge.has_covariance = true;
    edge.covariance = sigma_rad * sigma_rad * Eigen::Matrix3d::Identity();
    edge.num_inliers = 200;
    std::string why;
    if (graph.AddEdge(edge, &why) == ra::AddEdgeResult::kRejected) std::printf("edge rejected: %s\n", why.c_str());
  };
  const double s = 0.002;  // about 0.1 degree
  add(0, 1, {0.001, -0.002, 0.0}, s);
  add(1, 2, {-0.002, 0.001, 0.001}, s);
  add(2, 3, {0.0, 0.002, -0.001}, s);
  add(3, 0, {0.001, 0.0, 0.002}, s);
  add(0, 2, {0.0, -0.001, 0.001}, s);
  add(1, 3, {0.0, 0.5, 0.0}, s);  // an outlier: 29 degrees off

  ra::RotationAveragingOptions options;  // defaults: MAGSAC++ and covariance weighting
  ra::ViewOrientations orientations;
  ra::RotationAveragingSummary summary;
  if (!ra::SolveRotationAveraging(graph, options, &orientations, &summary)) {
    std::printf("solve failed:\n%s\n", summary.Report().c_str());
    return 1;
  }
  // The solution is defined up to one global rotation: compare relative to view 0.
  double worst_deg = 0.0;
  for (ra::ViewId id = 0; id < 4; ++id) {
    const Eigen::Matrix3d estimate = orientations.at(id) * orientations.at(0).transpose();
    const double error_deg = ra::LogSO3(estimate.transpose() * truth[id]).norm() * 180.0 / M_PI;
    worst_deg = std::max(worst_deg, error_deg);
    std::printf("%s: yaw %.3f deg, error %.3f deg\n", graph.FindView(id)->name.c_str(),
                ra::LogSO3(estimate)[1] * 180.0 / M_PI, error_deg);
  }
  for (std::size_t k = 0; k < graph.NumEdges(); ++k) {
    const ra::RelativeRotation& e = graph.Edges()[k];
    std::printf("edge %llu-%llu: residual %.3f deg, weight %.3f\n", static_cast<unsigned long long>(e.view1),
                static_cast<unsigned long long>(e.view2), summary.edges[k].residual_rad * 180.0 / M_PI,
                summary.edges[k].robust_weight);
  }
  std::printf("outlier edges: %zu; largest error %.3f deg\n", summary.num_outlier_edges, worst_deg);
  return summary.num_outlier_edges == 1 && worst_deg < 0.5 ? 0 : 1;
}
