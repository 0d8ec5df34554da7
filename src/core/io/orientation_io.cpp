#include "rotation_averaging/core/io/orientation_io.h"

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iomanip>

#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/util/text_lines.h"

namespace rotation_averaging {
namespace {

namespace fs = std::filesystem;

bool ParseQuaternion(const std::vector<std::string>& tokens, std::size_t first, Eigen::Matrix3d* rotation,
                     std::string* why) {
  double q[4];
  for (int k = 0; k < 4; ++k) {
    if (!ParseDouble(tokens[first + k], &q[k])) {
      *why = "'" + tokens[first + k] + "' is not a number";
      return false;
    }
  }
  const double norm = Eigen::Vector4d(q[0], q[1], q[2], q[3]).norm();
  if (!std::isfinite(norm) || std::abs(norm - 1.0) > 1e-3) {
    *why = "quaternion is not unit (norm " + std::to_string(norm) + ")";
    return false;
  }
  *rotation = QuaternionToRotation(q[0], q[1], q[2], q[3]);
  return true;
}

}  // namespace

ReadReport ReadOrientationsCsv(const std::string& path, NamedOrientations* orientations) {
  LineReader reader(path);
  if (!reader.IsOpen()) return {"cannot open " + path};
  std::string line;
  while (reader.Next(&line)) {
    if (IsBlankOrComment(line)) continue;
    const std::vector<std::string> tokens = SplitTokens(line, /*comma=*/true);
    if (reader.LineNumber() == 1 && !tokens.empty() && tokens[0] == "name") continue;
    if (tokens.size() != 5) return {reader.Where("expected 'name,qw,qx,qy,qz'")};
    Eigen::Matrix3d r;
    std::string why;
    if (!ParseQuaternion(tokens, 1, &r, &why)) return {reader.Where(why)};
    if (!orientations->emplace(tokens[0], r).second) return {reader.Where("duplicate view '" + tokens[0] + "'")};
  }
  return {};
}

bool WriteOrientationsCsv(const std::string& path, const NamedOrientations& orientations, std::string* error) {
  return WriteFileAtomically(path, [&orientations](std::ostream& out) -> std::string {
    std::string text = "name,qw,qx,qy,qz\n";
    text.reserve(80 * (orientations.size() + 1));
    for (const auto& [name, r] : orientations) {
      if (name.find_first_of(",\n\r") != std::string::npos) return "view name '" + name + "' contains a comma or newline";
      const Eigen::Vector4d q = RotationToQuaternion(r);
      text += name;
      for (int k = 0; k < 4; ++k) {
        text += ',';
        AppendDouble(&text, q[k]);
      }
      text += '\n';
    }
    out << text;
    return "";
  }, error);
}

NamedOrientations NameOrientations(const ViewGraph& graph, const ViewOrientations& orientations) {
  NamedOrientations named;
  for (const auto& [id, r] : orientations) {
    const View* view = graph.FindView(id);
    named[view ? view->name : std::to_string(id)] = r;
  }
  return named;
}

namespace {

// Where a Strecha scene keeps its cameras: gt_dense_cameras/ as published,
// gt_cameras/ as some copies name it, or the folder itself.
constexpr const char* kStrechaCameraFolders[] = {"gt_dense_cameras", "gt_cameras"};

// The .camera files of a Strecha scene, sorted: those of the first of
// kStrechaCameraFolders that has any, else the folder's own; empty if none.
std::vector<fs::path> StrechaCameraFiles(const fs::path& directory) {
  std::error_code ec;
  std::vector<fs::path> candidates;
  for (const char* name : kStrechaCameraFolders) candidates.push_back(directory / name);
  candidates.push_back(directory);
  for (const fs::path& folder : candidates) {
    std::vector<fs::path> files;
    for (const auto& entry : fs::directory_iterator(folder, ec)) {
      if (entry.path().extension() == ".camera") files.push_back(entry.path());
    }
    if (!files.empty()) {
      std::sort(files.begin(), files.end());
      return files;
    }
  }
  return {};
}

}  // namespace

ReadReport ReadStrechaGroundTruth(const std::string& directory, NamedOrientations* orientations) {
  std::error_code ec;
  if (!fs::is_directory(directory, ec)) return {directory + ": not a folder (Strecha ground truth is a folder)"};
  const std::vector<fs::path> files = StrechaCameraFiles(directory);
  if (files.empty()) return {directory + ": no .camera files in gt_dense_cameras/, gt_cameras/ or the folder itself"};
  for (const fs::path& file : files) {
    LineReader reader(file.string());
    if (!reader.IsOpen()) return {"cannot open " + file.string()};
    std::vector<std::vector<double>> rows;
    std::string line;
    while (reader.Next(&line)) {
      const std::vector<std::string> tokens = SplitTokens(line);
      if (tokens.empty()) continue;
      std::vector<double> row;
      for (const std::string& t : tokens) {
        double v;
        if (!ParseDouble(t, &v)) return {reader.Where("'" + t + "' is not a number")};
        row.push_back(v);
      }
      rows.push_back(row);
    }
    if (rows.size() < 7 || rows[4].size() != 3 || rows[5].size() != 3 || rows[6].size() != 3) {
      return {file.string() + ": expected K (3 lines), distortion, R (3 lines of 3), C, size"};
    }
    Eigen::Matrix3d camera_to_world;
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) camera_to_world(r, c) = rows[4 + r][c];
    if (!IsRotationMatrix(camera_to_world, 1e-4)) return {file.string() + ": R is not a rotation"};
    (*orientations)[file.stem().string()] = ProjectToSO3(camera_to_world).transpose();
  }
  return {};
}

ReadReport ReadColmapGroundTruth(const std::string& path, NamedOrientations* orientations) {
  std::error_code ec;
  const std::string file = fs::is_directory(path, ec) ? (fs::path(path) / "images.txt").string() : path;
  LineReader reader(file);
  if (!reader.IsOpen()) return {"cannot open " + file};
  std::string line;
  bool expect_image = true;
  while (reader.Next(&line)) {
    if (line.rfind('#', 0) == 0) continue;
    if (!expect_image) {  // the 2D points line (may be empty)
      expect_image = true;
      continue;
    }
    const std::vector<std::string> tokens = SplitTokens(line);
    if (tokens.empty()) continue;
    if (tokens.size() < 10) return {reader.Where("expected 'IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME'")};
    Eigen::Matrix3d r;
    std::string why;
    if (!ParseQuaternion(tokens, 1, &r, &why)) return {reader.Where(why)};
    (*orientations)[tokens[9]] = r;
    expect_image = false;
  }
  if (orientations->empty()) return {file + ": no images"};
  return {};
}

ReadReport ReadChainedGroundTruth(const std::string& graph_path, GraphFormat format, NamedOrientations* orientations) {
  ViewGraph graph;
  ReadReport report = ReadViewGraph(graph_path, format, &graph);
  if (!report.ok()) return report;
  // A spanning tree with no noise reproduces the poses; solve nothing.
  RotationAveragingOptions options;
  options.max_iterations = 0;
  options.robust_start.gnc_initial_scale_factor = 1.0;
  options.weighting = EdgeWeighting::kNone;
  ViewOrientations solved;
  RotationAveragingSummary summary;
  SolveRotationAveraging(graph, options, &solved, &summary);
  // Express in the frame of the lowest id of each component.
  for (const std::vector<ViewId>& component : graph.ConnectedComponents()) {
    if (component.size() < 2) continue;
    const Eigen::Matrix3d anchor = solved.at(component.front());
    for (ViewId id : component) (*orientations)[graph.FindView(id)->name] = solved.at(id) * anchor.transpose();
  }
  return report;
}

bool ParseGroundTruthFormat(const std::string& text, GroundTruthFormat* format) {
  static const std::pair<const char*, GroundTruthFormat> kNames[] = {{"auto", GroundTruthFormat::kAuto},
                                                                      {"csv", GroundTruthFormat::kCsv},
                                                                      {"strecha", GroundTruthFormat::kStrecha},
                                                                      {"colmap", GroundTruthFormat::kColmap},
                                                                      {"chain", GroundTruthFormat::kChain}};
  for (const auto& [name, f] : kNames) {
    if (text == name) {
      *format = f;
      return true;
    }
  }
  return false;
}

ReadReport ReadGroundTruth(const std::string& path, GroundTruthFormat format, NamedOrientations* orientations) {
  std::error_code ec;
  if (format == GroundTruthFormat::kAuto) {
    const fs::path p(path);
    if (fs::is_directory(p, ec)) {
      if (!StrechaCameraFiles(p).empty()) format = GroundTruthFormat::kStrecha;
      else if (fs::exists(p / "images.txt", ec)) format = GroundTruthFormat::kColmap;
      else if (fs::exists(p / "EGs.txt", ec)) format = GroundTruthFormat::kChain;
      else {
        return {path + ": a folder without ground truth: looked for *.camera files in gt_dense_cameras/, "
                       "gt_cameras/ or the folder (Strecha), images.txt (COLMAP) and EGs.txt (a graph to chain)"};
      }
    } else if (!fs::exists(p, ec)) {
      return {"cannot open " + path};
    } else if (p.filename() == "images.txt") {
      format = GroundTruthFormat::kColmap;
    } else if (p.extension() == ".csv") {
      format = GroundTruthFormat::kCsv;
    } else {
      format = GroundTruthFormat::kChain;
    }
  }
  switch (format) {
    case GroundTruthFormat::kCsv: return ReadOrientationsCsv(path, orientations);
    case GroundTruthFormat::kStrecha: return ReadStrechaGroundTruth(path, orientations);
    case GroundTruthFormat::kColmap: return ReadColmapGroundTruth(path, orientations);
    case GroundTruthFormat::kChain:
    case GroundTruthFormat::kAuto: return ReadChainedGroundTruth(path, GraphFormat::kAuto, orientations);
  }
  return {"unknown ground-truth format"};
}

}  // namespace rotation_averaging
