// Public header of rotation_averaging::core (docs/embedding.md).
// Readers for view graphs and pose graphs. Each converts to the conventions
// of core/geometry/so3.h at the boundary: edges R_ij = R_i R_j^T (world-to-camera),
// covariances of a right perturbation in rad^2.
//
// Malformed lines are errors that name the file and line ("file:12: ...").
// Lines that parse but whose edge the ViewGraph rejects (self-loops, NaN,
// invalid covariances) are skipped and reported in `warnings`.
#ifndef ROTATION_AVERAGING_CORE_IO_GRAPH_IO_H_
#define ROTATION_AVERAGING_CORE_IO_GRAPH_IO_H_

#include <map>
#include <string>
#include <utility>
#include <vector>

#include "rotation_averaging/core/scene/view_graph.h"

namespace rotation_averaging {

struct ReadReport {
  ReadReport() = default;
  ReadReport(std::string failure) : error(std::move(failure)) {}  // NOLINT: implicit, for `return {"..."}`
  std::string error;                  // empty on success
  std::vector<std::string> warnings;  // edges skipped, with file:line
  std::size_t lines = 0;
  bool ok() const { return error.empty(); }
};

// 1DSfM EGs.txt: "i j R_ij(9, row-major) [t_ij(3)]" with R_ij = R_i R_j^T.
// If `cc_path` is not empty, only edges between views listed there are kept.
ReadReport ReadOneDsfm(const std::string& egs_path, const std::string& cc_path, ViewGraph* graph);

// g2o "EDGE_SE3:QUAT i j x y z qx qy qz qw I(21)": measurement = pose of j in
// the frame of i, so its rotation is R_i R_j^T for world-to-camera R. The
// rotation covariance is the rotation block of the inverse of the 6x6
// information (marginal over translation), times 4: g2o's rotation error is
// the quaternion's vector part, half the angle-axis error. g2o's error is a
// right perturbation of the measurement, so no frame change is needed.
// VERTEX_SE3:QUAT lines only declare views.
ReadReport ReadG2o(const std::string& path, ViewGraph* graph);

// TORO "EDGE3 i j x y z roll pitch yaw I(21)", R = Rz(yaw) Ry(pitch) Rx(roll):
// the roll/pitch/yaw covariance (marginal) is mapped to a right perturbation
// by the Jacobian of the Euler parameterisation at the measurement.
ReadReport ReadToro(const std::string& path, ViewGraph* graph);

// iRotAvg "m n f" then m lines "i j qw qx qy qz" (1-based ids kept as they
// are; the quaternion is R_ij = R_i R_j^T), then f fixed absolute rotations
// (ignored). No covariances.
ReadReport ReadIRotAvg(const std::string& path, ViewGraph* graph);

// The package's own view-graph text format (written by `rotavg images`, read
// by `rotavg solve`); conventions of core/geometry/so3.h, one record per line:
//
//   # rotation_averaging view graph v2
//   VIEW <id> <name>
//   EDGE <id1> <id2> <source> <qw> <qx> <qy> <qz> <num_inliers> <covariance>
//   ORIENTATION <id> <qw> <qx> <qy> <qz>
//
// <source> is rig | sequential | loop_closure | other; the quaternion is
// R_12 = R_1 R_2^T; <covariance> is the upper triangle c00 c01 c02 c11 c12 c22
// of the right-perturbation covariance in rad^2, or a single '-' when there is
// none. Names contain no whitespace. VIEW lines come before the EDGE lines
// that use them. Edges are kept as listed (repeated pairs are kept).
// ORIENTATION (v2, optional) is a view's world-to-camera orientation when the
// file was saved: the node starts from them after a restart, so that the
// keyframes it published keep their frames (the gauge). A file without them
// is written as v1. The last line is "END <lines> <checksum>" (FNV-1a of the
// lines before it): a file without it, or whose checksum differs, is refused.
ReadReport ReadRotavgGraph(const std::string& path, ViewGraph* graph,
                           std::map<ViewId, Eigen::Matrix3d>* orientations = nullptr);
bool WriteRotavgGraph(const std::string& path, const ViewGraph& graph, std::string* error,
                      const std::map<ViewId, Eigen::Matrix3d>* orientations = nullptr);

enum class GraphFormat { kAuto, kOneDsfm, kG2o, kToro, kIRotAvg, kRotavg };
const char* GraphFormatName(GraphFormat format);
bool ParseGraphFormat(const std::string& text, GraphFormat* format);
// Guesses the format from the file name and first record: a directory or a
// file named EGs.txt is 1DSfM (cc.txt beside it is used), *.g2o or a file
// starting with VERTEX_SE3:QUAT/EDGE_SE3:QUAT is g2o, EDGE3/VERTEX3 is TORO,
// a first line of three integers is iRotAvg, and VIEW/EDGE records are the
// package's own format.
GraphFormat DetectGraphFormat(const std::string& path);
ReadReport ReadViewGraph(const std::string& path, GraphFormat format, ViewGraph* graph);

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_CORE_IO_GRAPH_IO_H_
