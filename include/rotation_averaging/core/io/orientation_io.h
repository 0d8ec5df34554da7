// Public header of rotation_averaging::core (docs/embedding.md).
// Orientation files and ground truth. Everything is converted to
// world-to-camera rotations keyed by view name at this boundary.
#ifndef ROTATION_AVERAGING_CORE_IO_ORIENTATION_IO_H_
#define ROTATION_AVERAGING_CORE_IO_ORIENTATION_IO_H_

#include <string>

#include "rotation_averaging/core/estimators/rotation_averaging.h"
#include "rotation_averaging/core/eval/rotation_evaluation.h"
#include "rotation_averaging/core/io/graph_io.h"

namespace rotation_averaging {

// ViewOrientations CSV: one line per view "name,qw,qx,qy,qz", world-to-camera,
// unit quaternion. A first line "name,qw,qx,qy,qz" and lines starting with
// '#' are skipped. Quaternions whose norm is off by more than 1e-3 are errors.
ReadReport ReadOrientationsCsv(const std::string& path, NamedOrientations* orientations);
// Writes the header line and one line per view, sorted by name; names must
// not contain commas or newlines.
bool WriteOrientationsCsv(const std::string& path, const NamedOrientations& orientations, std::string* error);
// Names solved orientations with the graph's view names.
NamedOrientations NameOrientations(const ViewGraph& graph, const ViewOrientations& orientations);

// Strecha folder: <dir>/gt_dense_cameras/<image>.camera as published (or
// gt_cameras/, or .camera files in <dir> itself), lines 5-7 the
// camera-to-world R (world-to-camera is R^T); views named by image file name.
ReadReport ReadStrechaGroundTruth(const std::string& directory, NamedOrientations* orientations);
// COLMAP text model images.txt (or a folder holding it): "IMAGE_ID QW QX QY QZ
// TX TY TZ CAMERA_ID NAME" (world-to-camera) then a line of 2D points.
ReadReport ReadColmapGroundTruth(const std::string& path, NamedOrientations* orientations);
// Ground truth by chaining the (noise-free) edges of a graph file along a
// spanning tree from its lowest id, e.g. sphere2500_groundtruth.txt. Views
// are named by decimal id.
ReadReport ReadChainedGroundTruth(const std::string& graph_path, GraphFormat format, NamedOrientations* orientations);

enum class GroundTruthFormat { kAuto, kCsv, kStrecha, kColmap, kChain };
bool ParseGroundTruthFormat(const std::string& text, GroundTruthFormat* format);
// kAuto: a folder with .camera files (in gt_dense_cameras/, gt_cameras/ or
// itself) is Strecha, images.txt (or a folder with it) is COLMAP, *.csv is
// CSV, EGs.txt (or a folder with it) and any other file a graph to chain. A
// folder with none of these is an error that says what was looked for.
ReadReport ReadGroundTruth(const std::string& path, GroundTruthFormat format, NamedOrientations* orientations);

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_CORE_IO_ORIENTATION_IO_H_
