#include "rotation_averaging/core/io/graph_io.h"

#include <Eigen/Cholesky>
#include <Eigen/LU>
#include <algorithm>
#include <cstdio>
#include <sstream>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <unordered_set>

#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/util/text_lines.h"

namespace rotation_averaging {
namespace {

namespace fs = std::filesystem;

bool ParseDoubles(const std::vector<std::string_view>& tokens, std::size_t first, std::size_t count, double* out) {
  if (tokens.size() < first + count) return false;
  for (std::size_t k = 0; k < count; ++k) {
    if (!ParseDouble(tokens[first + k], &out[k])) return false;
  }
  return true;
}

// 6x6 symmetric matrix from its upper triangle, row-major (21 numbers).
Eigen::Matrix<double, 6, 6> FromUpperTriangle(const double* v) {
  Eigen::Matrix<double, 6, 6> m;
  int k = 0;
  for (int r = 0; r < 6; ++r) {
    for (int c = r; c < 6; ++c) {
      m(r, c) = v[k];
      m(c, r) = v[k];
      ++k;
    }
  }
  return m;
}

// Rotation block (rows/cols 3..5) of the inverse of a 6x6 information matrix,
// i.e. the marginal covariance of the rotation part. False if not invertible.
bool MarginalRotationCovariance(const Eigen::Matrix<double, 6, 6>& information, Eigen::Matrix3d* covariance) {
  if (!information.allFinite()) return false;
  // Usually the inverse of the Schur complement of the translation block,
  // with closed-form 3x3 inverses (several times cheaper than a 6x6 LU, which
  // was a fifth of the time to read a g2o file); the LU below when a block is
  // nearly singular.
  const Eigen::Matrix3d tt = information.topLeftCorner<3, 3>();
  const Eigen::Matrix3d tr = information.topRightCorner<3, 3>();
  const Eigen::Matrix3d rr = information.bottomRightCorner<3, 3>();
  const auto well_conditioned = [](const Eigen::Matrix3d& m) {
    const double scale = m.cwiseAbs().maxCoeff();
    return scale > 0.0 && std::abs(m.determinant()) > 1e-9 * scale * scale * scale;
  };
  if (well_conditioned(tt)) {
    const Eigen::Matrix3d schur = rr - tr.transpose() * tt.inverse() * tr;
    if (well_conditioned(schur)) {
      *covariance = schur.inverse();
      if (covariance->allFinite()) return true;
    }
  }
  Eigen::FullPivLU<Eigen::Matrix<double, 6, 6>> lu(information);
  if (!lu.isInvertible()) return false;
  *covariance = lu.inverse().block<3, 3>(3, 3);
  return covariance->allFinite();
}

void AddEdgeOrWarn(const LineReader& reader, const RelativeRotation& edge, ViewGraph* graph, ReadReport* report) {
  graph->AddView(edge.view1);
  graph->AddView(edge.view2);
  std::string why;
  if (graph->AddEdge(edge, &why, DuplicatePolicy::kKeepBoth) == AddEdgeResult::kRejected) {
    report->warnings.push_back(reader.Where("edge skipped: " + why));
  }
}

bool ParseIds(const std::vector<std::string_view>& tokens, std::size_t first, ViewId* a, ViewId* b) {
  return tokens.size() > first + 1 && ParseUint64(tokens[first], a) && ParseUint64(tokens[first + 1], b);
}

}  // namespace

ReadReport ReadOneDsfm(const std::string& egs_path, const std::string& cc_path, ViewGraph* graph) {
  ReadReport report;
  std::unordered_set<ViewId> keep;
  if (!cc_path.empty()) {
    LineReader cc(cc_path);
    if (!cc.IsOpen()) return {"cannot open " + cc_path};
    std::string_view line;
    std::vector<std::string_view> tokens;
    while (cc.Next(&line)) {
      if (IsBlankOrComment(line)) continue;
      SplitTokens(line, &tokens);
      ViewId id;
      if (tokens.size() != 1 || !ParseUint64(tokens[0], &id)) return {cc.Where("expected one camera index")};
      keep.insert(id);
      graph->AddView(id);
    }
  }
  LineReader reader(egs_path);
  if (!reader.IsOpen()) return {"cannot open " + egs_path};
  std::string_view line;
  std::vector<std::string_view> tokens;
  while (reader.Next(&line)) {
    if (IsBlankOrComment(line)) continue;
    SplitTokens(line, &tokens);
    RelativeRotation edge;
    double r[9];
    if ((tokens.size() != 11 && tokens.size() != 14) || !ParseIds(tokens, 0, &edge.view1, &edge.view2) ||
        !ParseDoubles(tokens, 2, 9, r)) {
      return {reader.Where("expected 'i j R_ij(9) [t_ij(3)]'")};
    }
    if (!cc_path.empty() && (!keep.count(edge.view1) || !keep.count(edge.view2))) continue;
    edge.rotation = Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(r);
    AddEdgeOrWarn(reader, edge, graph, &report);
  }
  report.lines = reader.LineNumber();
  return report;
}

namespace {

// What distinguishes g2o from TORO pose graphs: record names, the pose part
// of an edge (3 translation numbers then the rotation) and how the rotation
// block of its information maps to our right perturbation.
struct PoseGraphDialect {
  const char* format;
  const char* vertex_tag;
  std::size_t vertex_tokens;
  const char* edge_tag;
  const char* edge_usage;
  int pose_numbers;  // translation + rotation numbers before the 21 of the information
  // Rotation from the pose numbers; empty string on success, else why not.
  std::string (*rotation)(const double* pose, Eigen::Matrix3d* r);
  // J such that our covariance is J C J^T, C the marginal covariance of the
  // dialect's rotation parameters.
  Eigen::Matrix3d (*jacobian)(const double* pose);
  const char* ignored_tag;  // records skipped without a word ("" for none)
};

std::string G2oRotation(const double* v, Eigen::Matrix3d* r) {
  if (Eigen::Vector4d(v[3], v[4], v[5], v[6]).norm() < 1e-12) return "zero quaternion";
  *r = QuaternionToRotation(v[6], v[3], v[4], v[5]);
  return "";
}
// g2o's rotation error is the quaternion's vector part, half the angle-axis error.
Eigen::Matrix3d G2oJacobian(const double*) { return 2.0 * Eigen::Matrix3d::Identity(); }

std::string ToroRotation(const double* v, Eigen::Matrix3d* r) {
  *r = RotationFromRollPitchYaw(v[3], v[4], v[5]);
  return "";
}
Eigen::Matrix3d ToroJacobian(const double* v) { return RollPitchYawToRightTangentJacobian(v[3], v[4]); }

const PoseGraphDialect kG2o = {"g2o", "VERTEX_SE3:QUAT", 9, "EDGE_SE3:QUAT",
                               "expected 'EDGE_SE3:QUAT i j x y z qx qy qz qw I(21)'", 7, &G2oRotation, &G2oJacobian,
                               "FIX"};
const PoseGraphDialect kToro = {"TORO", "VERTEX3", 8, "EDGE3", "expected 'EDGE3 i j x y z roll pitch yaw I(21)'", 6,
                                &ToroRotation, &ToroJacobian, ""};

ReadReport ReadPoseGraph(const std::string& path, const PoseGraphDialect& dialect, ViewGraph* graph) {
  ReadReport report;
  LineReader reader(path);
  if (!reader.IsOpen()) return {"cannot open " + path};
  std::string_view line;
  std::vector<std::string_view> tokens;
  const std::size_t numbers = dialect.pose_numbers + 21;
  while (reader.Next(&line)) {
    if (IsBlankOrComment(line)) continue;
    SplitTokens(line, &tokens);
    const std::string_view tag = tokens[0];
    if (tag == dialect.vertex_tag) {
      ViewId id;
      if (tokens.size() != dialect.vertex_tokens || !ParseUint64(tokens[1], &id)) {
        return {reader.Where(std::string("malformed ") + dialect.vertex_tag)};
      }
      graph->AddView(id);
    } else if (tag == dialect.edge_tag) {
      RelativeRotation edge;
      double v[28];
      if (tokens.size() != 3 + numbers || !ParseIds(tokens, 1, &edge.view1, &edge.view2) ||
          !ParseDoubles(tokens, 3, numbers, v)) {
        return {reader.Where(dialect.edge_usage)};
      }
      const std::string why = dialect.rotation(v, &edge.rotation);
      if (!why.empty()) return {reader.Where(why)};
      Eigen::Matrix3d covariance;
      if (MarginalRotationCovariance(FromUpperTriangle(v + dialect.pose_numbers), &covariance)) {
        const Eigen::Matrix3d j = dialect.jacobian(v);
        edge.has_covariance = true;
        edge.covariance = j * covariance * j.transpose();
      } else {
        report.warnings.push_back(reader.Where("information matrix not invertible: edge kept without covariance"));
      }
      AddEdgeOrWarn(reader, edge, graph, &report);
    } else if (tag != dialect.ignored_tag) {
      return {reader.Where("unsupported " + std::string(dialect.format) + " record '" + std::string(tag) + "' (only " +
                           dialect.vertex_tag + " and " + dialect.edge_tag + ")")};
    }
  }
  report.lines = reader.LineNumber();
  return report;
}

}  // namespace

ReadReport ReadG2o(const std::string& path, ViewGraph* graph) { return ReadPoseGraph(path, kG2o, graph); }

ReadReport ReadToro(const std::string& path, ViewGraph* graph) { return ReadPoseGraph(path, kToro, graph); }

ReadReport ReadIRotAvg(const std::string& path, ViewGraph* graph) {
  ReadReport report;
  LineReader reader(path);
  if (!reader.IsOpen()) return {"cannot open " + path};
  std::string_view line;
  std::vector<std::string_view> tokens;
  int m = -1, n = -1, f = -1;
  while (reader.Next(&line)) {
    if (IsBlankOrComment(line)) continue;
    SplitTokens(line, &tokens);
    if (tokens.size() != 3 || !ParseInt(tokens[0], &m) || !ParseInt(tokens[1], &n) || !ParseInt(tokens[2], &f) ||
        m < 0 || n < 0 || f < 0) {
      return {reader.Where("expected header 'num_edges num_views num_fixed'")};
    }
    break;
  }
  if (m < 0) return {path + ": empty file"};
  // Views are created as edges name them (ids 1..n): a header announcing
  // billions of views costs nothing until edges use them (found by fuzzing:
  // "0 38319948 6" ran out of memory).
  int edges_read = 0;
  while (edges_read < m && reader.Next(&line)) {
    if (IsBlankOrComment(line)) continue;
    SplitTokens(line, &tokens);
    RelativeRotation edge;
    double q[4];
    if (tokens.size() != 6 || !ParseIds(tokens, 0, &edge.view1, &edge.view2) || !ParseDoubles(tokens, 2, 4, q)) {
      return {reader.Where("expected 'i j qw qx qy qz'")};
    }
    if (edge.view1 < 1 || edge.view2 < 1 || edge.view1 > static_cast<ViewId>(n) ||
        edge.view2 > static_cast<ViewId>(n)) {
      return {reader.Where("view id outside 1.." + std::to_string(n) + " (the header's view count)")};
    }
    graph->AddView(edge.view1);
    graph->AddView(edge.view2);
    ++edges_read;
    const double norm = Eigen::Vector4d(q[0], q[1], q[2], q[3]).norm();
    if (!(std::abs(norm - 1.0) < 1e-3)) {
      report.warnings.push_back(reader.Where("edge skipped: quaternion is not unit (norm " + std::to_string(norm) + ")"));
      continue;
    }
    edge.rotation = QuaternionToRotation(q[0], q[1], q[2], q[3]);
    AddEdgeOrWarn(reader, edge, graph, &report);
  }
  if (edges_read < m) {
    return {path + ": header announces " + std::to_string(m) + " edges but only " + std::to_string(edges_read) +
            " were found"};
  }
  report.lines = reader.LineNumber();
  return report;
}

namespace {

// v1: VIEW and EDGE records; v2 adds ORIENTATION records. A file is written
// as v1 when it has no orientations, so that earlier readers still read it.
constexpr char kGraphHeader[] = "# rotation_averaging view graph v";
constexpr int kGraphVersion = 2;

}  // namespace

ReadReport ReadRotavgGraph(const std::string& path, ViewGraph* graph, std::map<ViewId, Eigen::Matrix3d>* orientations) {
  ReadReport report;
  std::map<ViewId, Eigen::Matrix3d> read_orientations;
  LineReader reader(path);
  if (!reader.IsOpen()) return {"cannot open " + path};
  std::string_view line;
  std::vector<std::string_view> tokens;
  EndRecordCheck end;
  bool ours = false;
  while (reader.Next(&line)) {
    if (end.ContentLines() == 0 && line.rfind(kGraphHeader, 0) == 0) {
      ours = true;
      int version = 0;
      if (!ParseInt(line.substr(std::string_view(kGraphHeader).size()), &version) || version < 1) {
        return {reader.Where("malformed header '" + std::string(line) + "'")};
      }
      if (version > kGraphVersion) {
        return {reader.Where("written by a newer version of the package (format v" + std::to_string(version) +
                             "); this one reads v1 to v" + std::to_string(kGraphVersion))};
      }
    }
    std::string why;
    const EndRecordCheck::Line kind = end.Take(line, &why);
    if (kind == EndRecordCheck::Line::kError) return {reader.Where(why)};
    if (kind != EndRecordCheck::Line::kContent || IsBlankOrComment(line)) continue;
    SplitTokens(line, &tokens);
    if (tokens[0] == "VIEW") {
      ViewId id;
      if (tokens.size() != 3 || !ParseUint64(tokens[1], &id)) return {reader.Where("expected 'VIEW id name'")};
      const std::string name(tokens[2]);
      if (!graph->AddView(id, name) && graph->FindView(id)->name != name) {
        return {reader.Where("view " + std::string(tokens[1]) + " declared twice with different names")};
      }
    } else if (tokens[0] == "EDGE") {
      RelativeRotation edge;
      double q[4];
      if ((tokens.size() != 10 && tokens.size() != 15) || !ParseIds(tokens, 1, &edge.view1, &edge.view2) ||
          !ParseEdgeSource(std::string(tokens[3]), &edge.source) || !ParseDoubles(tokens, 4, 4, q) ||
          !ParseInt(tokens[8], &edge.num_inliers)) {
        return {reader.Where("expected 'EDGE id1 id2 source qw qx qy qz num_inliers (c00 c01 c02 c11 c12 c22 | -)'")};
      }
      if (tokens.size() == 15) {
        double c[6];
        if (!ParseDoubles(tokens, 9, 6, c)) return {reader.Where("malformed covariance")};
        edge.has_covariance = true;
        edge.covariance << c[0], c[1], c[2], c[1], c[3], c[4], c[2], c[4], c[5];
      } else if (tokens[9] != "-") {
        return {reader.Where("covariance must be six numbers or '-'")};
      }
      const double norm = Eigen::Vector4d(q[0], q[1], q[2], q[3]).norm();
      if (!(std::abs(norm - 1.0) < 1e-3)) {
        report.warnings.push_back(reader.Where("edge skipped: quaternion is not unit (norm " + std::to_string(norm) + ")"));
        continue;
      }
      edge.rotation = QuaternionToRotation(q[0], q[1], q[2], q[3]);
      if (!graph->HasView(edge.view1) || !graph->HasView(edge.view2)) {
        return {reader.Where("edge uses a view that no VIEW line declared")};
      }
      std::string why;
      if (graph->AddEdge(edge, &why, DuplicatePolicy::kKeepBoth) == AddEdgeResult::kRejected) {
        report.warnings.push_back(reader.Where("edge skipped: " + why));
      }
    } else if (tokens[0] == "ORIENTATION") {
      ViewId id;
      double q[4];
      if (tokens.size() != 6 || !ParseUint64(tokens[1], &id) || !ParseDoubles(tokens, 2, 4, q)) {
        return {reader.Where("expected 'ORIENTATION id qw qx qy qz'")};
      }
      if (!graph->HasView(id)) return {reader.Where("orientation of a view that no VIEW line declared")};
      const double norm = Eigen::Vector4d(q[0], q[1], q[2], q[3]).norm();
      if (!(std::abs(norm - 1.0) < 1e-3)) {
        report.warnings.push_back(reader.Where("orientation skipped: quaternion is not unit (norm " +
                                               std::to_string(norm) + ")"));
        continue;
      }
      read_orientations[id] = QuaternionToRotation(q[0], q[1], q[2], q[3]);
    } else {
      return {reader.Where("unknown record '" + std::string(tokens[0]) + "' (VIEW, EDGE or ORIENTATION)")};
    }
  }
  // A file we wrote always ends with END: without it, it was cut short.
  if (ours && !end.Ended()) return {path + ": no END record: the file is truncated (a save that was interrupted?)"};
  report.lines = reader.LineNumber();
  if (orientations) *orientations = std::move(read_orientations);
  return report;
}

bool WriteRotavgGraph(const std::string& path, const ViewGraph& graph, std::string* error,
                      const std::map<ViewId, Eigen::Matrix3d>* orientations) {
  const bool with_orientations = orientations && !orientations->empty();
  return WriteFileAtomically(path, [&graph, orientations, with_orientations](std::ostream& file) -> std::string {
    std::ostringstream out;
    out << kGraphHeader << (with_orientations ? kGraphVersion : 1) << "\n"
        << "# VIEW id name | EDGE id1 id2 source qw qx qy qz num_inliers (c00 c01 c02 c11 c12 c22 | -)"
        << (with_orientations ? " | ORIENTATION id qw qx qy qz" : "") << "\n"
        << "# R_12 = R_1 R_2^T (world-to-camera R); covariance of a right perturbation, rad^2\n"
        << std::setprecision(17);
    std::vector<View> views = graph.Views();
    std::sort(views.begin(), views.end(), [](const View& a, const View& b) { return a.id < b.id; });
    for (const View& v : views) {
      if (v.name.empty() || v.name.find_first_of(" \t\r\n") != std::string::npos) {
        return "view name '" + v.name + "' is empty or contains whitespace";
      }
      out << "VIEW " << v.id << ' ' << v.name << '\n';
    }
    std::string line;
    for (const RelativeRotation& e : graph.Edges()) {
      const Eigen::Vector4d q = RotationToQuaternion(e.rotation);
      line = "EDGE " + std::to_string(e.view1) + ' ' + std::to_string(e.view2) + ' ' + EdgeSourceName(e.source);
      for (int k = 0; k < 4; ++k) {
        line += ' ';
        AppendDouble(&line, q[k]);
      }
      line += ' ' + std::to_string(e.num_inliers);
      if (e.has_covariance) {
        const Eigen::Matrix3d& c = e.covariance;
        for (const double v : {c(0, 0), c(0, 1), c(0, 2), c(1, 1), c(1, 2), c(2, 2)}) {
          line += ' ';
          AppendDouble(&line, v);
        }
      } else {
        line += " -";
      }
      out << line << '\n';
    }
    if (with_orientations) {
      for (const auto& [id, r] : *orientations) {
        if (!graph.HasView(id)) return "orientation of view " + std::to_string(id) + ", which is not in the graph";
        const Eigen::Vector4d q = RotationToQuaternion(r);
        line = "ORIENTATION " + std::to_string(id);
        for (int k = 0; k < 4; ++k) {
          line += ' ';
          AppendDouble(&line, q[k]);
        }
        out << line << '\n';
      }
    }
    const std::string body = out.str();
    file << body << EndRecord(body);
    return "";
  }, error);
}

const char* GraphFormatName(GraphFormat format) {
  switch (format) {
    case GraphFormat::kAuto: return "auto";
    case GraphFormat::kOneDsfm: return "1dsfm";
    case GraphFormat::kG2o: return "g2o";
    case GraphFormat::kToro: return "toro";
    case GraphFormat::kIRotAvg: return "irotavg";
    case GraphFormat::kRotavg: return "rotavg";
  }
  return "?";
}

bool ParseGraphFormat(const std::string& text, GraphFormat* format) {
  for (GraphFormat f : {GraphFormat::kAuto, GraphFormat::kOneDsfm, GraphFormat::kG2o, GraphFormat::kToro,
                        GraphFormat::kIRotAvg, GraphFormat::kRotavg}) {
    if (text == GraphFormatName(f)) {
      *format = f;
      return true;
    }
  }
  return false;
}

GraphFormat DetectGraphFormat(const std::string& path) {
  std::error_code ec;
  if (fs::is_directory(path, ec) || fs::path(path).filename() == "EGs.txt") return GraphFormat::kOneDsfm;
  if (fs::path(path).extension() == ".g2o") return GraphFormat::kG2o;
  LineReader reader(path);
  std::string_view line;
  std::vector<std::string_view> tokens;
  while (reader.Next(&line)) {
    if (IsBlankOrComment(line)) continue;
    SplitTokens(line, &tokens);
    const std::string_view tag = tokens[0];
    if (tag == "VERTEX_SE3:QUAT" || tag == "EDGE_SE3:QUAT") return GraphFormat::kG2o;
    if (tag == "VERTEX3" || tag == "EDGE3") return GraphFormat::kToro;
    if (tag == "VIEW" || tag == "EDGE") return GraphFormat::kRotavg;
    if (tokens.size() == 3) return GraphFormat::kIRotAvg;
    if (tokens.size() == 11 || tokens.size() == 14) return GraphFormat::kOneDsfm;
    break;
  }
  return GraphFormat::kAuto;
}

ReadReport ReadViewGraph(const std::string& path, GraphFormat format, ViewGraph* graph) {
  if (format == GraphFormat::kAuto) format = DetectGraphFormat(path);
  switch (format) {
    case GraphFormat::kOneDsfm: {
      std::error_code ec;
      fs::path egs = path, cc;
      if (fs::is_directory(path, ec)) egs = fs::path(path) / "EGs.txt";
      if (fs::exists(egs.parent_path() / "cc.txt", ec)) cc = egs.parent_path() / "cc.txt";
      return ReadOneDsfm(egs.string(), cc.string(), graph);
    }
    case GraphFormat::kG2o: return ReadG2o(path, graph);
    case GraphFormat::kToro: return ReadToro(path, graph);
    case GraphFormat::kIRotAvg: return ReadIRotAvg(path, graph);
    case GraphFormat::kRotavg: return ReadRotavgGraph(path, graph);
    case GraphFormat::kAuto: break;
  }
  std::error_code ec;
  if (!fs::exists(path, ec)) return {"cannot open " + path};
  return {path + ": unknown graph format (use --format 1dsfm|g2o|toro|irotavg|rotavg)"};
}

}  // namespace rotation_averaging
