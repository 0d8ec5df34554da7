#include "rotation_averaging/core/io/graph_io.h"

#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>

#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/core/io/orientation_io.h"
#include "rotation_averaging/util/text_lines.h"
#include "common/kill_during_writes.h"

namespace rotation_averaging {
namespace {

namespace fs = std::filesystem;

class TempDir {
 public:
  TempDir() : path_(fs::temp_directory_path() / ("rotavg_io_" + std::to_string(::getpid()) + "_" + std::to_string(counter_++))) {
    fs::create_directories(path_);
  }
  ~TempDir() { fs::remove_all(path_); }
  std::string Write(const std::string& name, const std::string& text) const {
    const fs::path p = path_ / name;
    std::ofstream(p) << text;
    return p.string();
  }
  std::string Path() const { return path_.string(); }

 private:
  static inline int counter_ = 0;
  fs::path path_;
};

TEST(GraphIo, OneDsfmReadsRowMajorRotationsAndFiltersByCc) {
  TempDir dir;
  const Eigen::Matrix3d r = ExpSO3(Eigen::Vector3d(0.1, 0.2, 0.3));
  std::ostringstream egs;
  egs.precision(17);
  for (int k = 0; k < 9; ++k) egs << (k ? " " : "0 1 ") << r(k / 3, k % 3);
  egs << " 0 0 1\n2 3 1 0 0 0 1 0 0 0 1 0 0 1\n";
  const std::string egs_path = dir.Write("EGs.txt", egs.str());
  dir.Write("cc.txt", "0\n1\n");
  ViewGraph g;
  ASSERT_TRUE(ReadViewGraph(dir.Path(), GraphFormat::kAuto, &g).ok());
  ASSERT_EQ(g.NumEdges(), 1u);  // edge 2-3 is outside cc.txt
  EXPECT_LT((g.Edges()[0].rotation - r).norm(), 1e-12);
}

TEST(GraphIo, MalformedLinesNameFileAndLine) {
  TempDir dir;
  const std::string p = dir.Write("bad.g2o", "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nEDGE_SE3:QUAT 0 1 0 0 0 0 0 0 1 oops\n");
  ViewGraph g;
  const ReadReport r = ReadG2o(p, &g);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error.find("bad.g2o:2:"), std::string::npos) << r.error;
  const std::string csv = dir.Write("o.csv", "name,qw,qx,qy,qz\na,1,0,0,0\nb,1,0,0\n");
  NamedOrientations o;
  const ReadReport rc = ReadOrientationsCsv(csv, &o);
  ASSERT_FALSE(rc.ok());
  EXPECT_NE(rc.error.find("o.csv:3:"), std::string::npos) << rc.error;
  const std::string irot = dir.Write("ravg.txt", "3 3 1\n1 2 1 0 0 0\n");
  EXPECT_NE(ReadIRotAvg(irot, &g).error.find("announces 3 edges"), std::string::npos);
  // Found by fuzzing: a header announcing 38 million views ran out of memory.
  ViewGraph huge;
  const std::string big = dir.Write("big.txt", "0\r38319948\r6");
  EXPECT_TRUE(ReadViewGraph(big, GraphFormat::kIRotAvg, &huge).ok());
  EXPECT_EQ(huge.NumViews(), 0u);
  ViewGraph outside;
  EXPECT_NE(ReadIRotAvg(dir.Write("out.txt", "1 2 0\n1 5 1 0 0 0\n"), &outside).error.find("outside 1..2"),
            std::string::npos);
}

TEST(GraphIo, G2oCovarianceIsTheMarginalRotationBlockInAngleAxisUnits) {
  TempDir dir;
  // Diagonal information: translation 10, rotation 400 (quaternion-vector units)
  // -> angle-axis variance 4 / 400 = 0.01 rad^2.
  const std::string p = dir.Write(
      "a.g2o", "EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 1 10 0 0 0 0 0 10 0 0 0 0 10 0 0 0 400 0 0 400 0 400\n");
  ViewGraph g;
  ASSERT_TRUE(ReadG2o(p, &g).ok());
  ASSERT_EQ(g.NumEdges(), 1u);
  EXPECT_TRUE(g.Edges()[0].has_covariance);
  EXPECT_LT((g.Edges()[0].covariance - 0.01 * Eigen::Matrix3d::Identity()).norm(), 1e-12);
}

TEST(GraphIo, InvalidEdgesAreSkippedWithAWarning) {
  TempDir dir;
  const std::string p = dir.Write("r.txt", "3 3 0\n1 2 1 0 0 0\n2 2 1 0 0 0\n2 3 0.5 0 0 0\n");
  ViewGraph g;
  const ReadReport r = ReadIRotAvg(p, &g);
  ASSERT_TRUE(r.ok()) << r.error;
  EXPECT_EQ(g.NumEdges(), 1u);
  ASSERT_EQ(r.warnings.size(), 2u);
  EXPECT_NE(r.warnings[0].find("r.txt:3:"), std::string::npos);
  EXPECT_NE(r.warnings[1].find("not unit"), std::string::npos);
}

TEST(GraphIo, NativeGraphFormatRoundTripsEveryField) {
  TempDir dir;
  ViewGraph g;
  g.AddView(3, "img_003.jpg");
  g.AddView(7, "img_007.jpg");
  g.AddView(9, "img_009.jpg");
  RelativeRotation e;
  e.view1 = 3;
  e.view2 = 7;
  e.rotation = ExpSO3(Eigen::Vector3d(0.1, -0.2, 0.3));
  e.has_covariance = true;
  e.covariance << 4e-6, 1e-7, 0, 1e-7, 2e-6, -3e-8, 0, -3e-8, 9e-6;
  e.num_inliers = 812;
  e.source = EdgeSource::kLoopClosure;
  g.AddEdge(e);
  e.view2 = 9;
  e.has_covariance = false;
  e.source = EdgeSource::kSequential;
  g.AddEdge(e);
  const std::string p = dir.Path() + "/graph.txt";
  std::string error;
  ASSERT_TRUE(WriteRotavgGraph(p, g, &error)) << error;
  ViewGraph back;
  ASSERT_TRUE(ReadViewGraph(p, GraphFormat::kAuto, &back).ok());
  ASSERT_EQ(back.NumViews(), 3u);
  ASSERT_EQ(back.NumEdges(), 2u);
  EXPECT_EQ(back.FindView(7)->name, "img_007.jpg");
  const RelativeRotation& a = back.Edges()[0];
  EXPECT_EQ(a.source, EdgeSource::kLoopClosure);
  EXPECT_EQ(a.num_inliers, 812);
  EXPECT_TRUE(a.has_covariance);
  EXPECT_LT((a.covariance - g.Edges()[0].covariance).norm(), 1e-20);
  EXPECT_LT((a.rotation - g.Edges()[0].rotation).norm(), 1e-14);
  EXPECT_FALSE(back.Edges()[1].has_covariance);
  // Names with whitespace cannot be written.
  g.AddView(11, "bad name");
  EXPECT_FALSE(WriteRotavgGraph(p, g, &error));
  // An edge before its views is an error naming the line.
  const std::string bad = dir.Write("bad.txt", "VIEW 1 a\nEDGE 1 2 other 1 0 0 0 5 -\n");
  ViewGraph h;
  EXPECT_NE(ReadViewGraph(bad, GraphFormat::kAuto, &h).error.find("bad.txt:2:"), std::string::npos);
}

// Orientations saved with the graph (v2) come back with it; a file of a
// newer format and an orientation of an undeclared view are refused.
TEST(GraphIo, OrientationsSavedWithTheGraphComeBack) {
  TempDir dir;
  ViewGraph g;
  g.AddView(0, "a");
  g.AddView(1, "b");
  RelativeRotation e;
  e.view1 = 0;
  e.view2 = 1;
  e.rotation = ExpSO3(Eigen::Vector3d(0.1, -0.2, 0.3));
  g.AddEdge(e);
  std::map<ViewId, Eigen::Matrix3d> orientations{{0, ExpSO3(Eigen::Vector3d(0.5, 0.1, -0.4))},
                                                 {1, ExpSO3(Eigen::Vector3d(-1.0, 2.0, 0.2))}};
  const std::string p = dir.Path() + "/graph.txt";
  std::string error;
  ASSERT_TRUE(WriteRotavgGraph(p, g, &error, &orientations)) << error;
  ViewGraph back;
  std::map<ViewId, Eigen::Matrix3d> read;
  const ReadReport report = ReadRotavgGraph(p, &back, &read);
  ASSERT_TRUE(report.ok()) << report.error;
  ASSERT_EQ(read.size(), 2u);
  for (const auto& [id, r] : orientations) EXPECT_LT((read.at(id) - r).norm(), 1e-14);
  // Readers that do not ask for them still read the graph.
  ViewGraph graph_only;
  EXPECT_TRUE(ReadViewGraph(p, GraphFormat::kAuto, &graph_only).ok());
  EXPECT_EQ(graph_only.NumEdges(), 1u);
  // Without orientations the file stays v1, which earlier readers read.
  ASSERT_TRUE(WriteRotavgGraph(p, g, &error)) << error;
  std::ifstream in(p);
  std::string header;
  std::getline(in, header);
  EXPECT_EQ(header, "# rotation_averaging view graph v1");
  // An orientation of a view not in the graph cannot be written.
  orientations[5] = Eigen::Matrix3d::Identity();
  EXPECT_FALSE(WriteRotavgGraph(p, g, &error, &orientations));

  ViewGraph h;
  const std::string newer = dir.Write("newer.txt", "# rotation_averaging view graph v3\nVIEW 0 a\n");
  EXPECT_NE(ReadRotavgGraph(newer, &h).error.find("newer version"), std::string::npos);
  const std::string undeclared = dir.Write("undeclared.txt", "VIEW 0 a\nORIENTATION 4 1 0 0 0\n");
  EXPECT_NE(ReadRotavgGraph(undeclared, &h).error.find("undeclared.txt:2:"), std::string::npos);
}

// Saved graphs end with a checksum record: a save cut short or corrupted is
// refused with a clear error instead of loading a partial graph.
TEST(GraphIo, TruncatedOrCorruptedSavesAreDetected) {
  TempDir dir;
  ViewGraph g;
  for (ViewId v = 0; v < 20; ++v) g.AddView(v, "kf" + std::to_string(v));
  for (ViewId v = 1; v < 20; ++v) {
    RelativeRotation e;
    e.view1 = v - 1;
    e.view2 = v;
    e.rotation = ExpSO3(Eigen::Vector3d(0.01 * v, 0.0, 0.02));
    g.AddEdge(e);
  }
  const std::string p = dir.Path() + "/saved.txt";
  std::string error;
  ASSERT_TRUE(WriteRotavgGraph(p, g, &error)) << error;
  std::ifstream in(p);
  const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  ViewGraph ok;
  ASSERT_TRUE(ReadViewGraph(p, GraphFormat::kRotavg, &ok).ok());
  EXPECT_EQ(ok.NumEdges(), 19u);

  // Cut at a line boundary (the END record lost) and mid-line.
  const std::string cut_line = dir.Write("cut_line.txt", text.substr(0, text.rfind("EDGE")));
  ViewGraph a;
  EXPECT_NE(ReadViewGraph(cut_line, GraphFormat::kRotavg, &a).error.find("truncated"), std::string::npos);
  const std::string cut_mid = dir.Write("cut_mid.txt", text.substr(0, text.size() / 2));
  ViewGraph b;
  EXPECT_FALSE(ReadViewGraph(cut_mid, GraphFormat::kRotavg, &b).ok());
  // One digit changed in a quaternion: the checksum catches it.
  std::string corrupted = text;
  const std::size_t at = corrupted.find("EDGE 5 6");
  ASSERT_NE(at, std::string::npos);
  const std::size_t digit = corrupted.find_first_of("123456789", at + 20);
  corrupted[digit] = corrupted[digit] == '9' ? '8' : static_cast<char>(corrupted[digit] + 1);
  ViewGraph c;
  EXPECT_NE(ReadViewGraph(dir.Write("corrupted.txt", corrupted), GraphFormat::kRotavg, &c).error.find("checksum"),
            std::string::npos);
  // Records after END are refused; hand-written files without our header
  // and END still load.
  ViewGraph d;
  EXPECT_FALSE(ReadViewGraph(dir.Write("after.txt", text + "VIEW 99 x\n"), GraphFormat::kRotavg, &d).ok());
  ViewGraph e;
  EXPECT_TRUE(ReadViewGraph(dir.Write("hand.txt", "VIEW 1 a\nVIEW 2 b\nEDGE 1 2 other 1 0 0 0 5 -\n"),
                            GraphFormat::kRotavg, &e).ok());
}

// A process killed while it saves (a SIGKILLed node during autosave) leaves
// the graph saved before, or the new one, whole: never a partial file.
TEST(GraphIo, ASaveKilledMidWriteLeavesTheFormerFileWhole) {
  TempDir dir;
  ViewGraph a, b;
  std::map<ViewId, Eigen::Matrix3d> orientations;
  for (ViewId v = 0; v < 3000; ++v) {
    a.AddView(v, "cam@" + std::to_string(1'000'000'000LL + 50'000'000LL * v));
    orientations[v] = ExpSO3(Eigen::Vector3d(0.001 * v, 0.2, -0.1));
  }
  b = a;
  for (ViewId v = 1; v < 3000; ++v) {
    RelativeRotation e;
    e.view1 = v - 1;
    e.view2 = v;
    e.rotation = ExpSO3(Eigen::Vector3d(0.01, 0.002 * (v % 7), 0.0));
    e.has_covariance = true;
    e.covariance = 1e-6 * Eigen::Matrix3d::Identity();
    a.AddEdge(e);
    if (v % 2 == 0) b.AddEdge(e);
  }
  const std::string path = dir.Path() + "/autosave.txt";
  bool next_is_a = true;
  std::string error;
  int interrupted = 0;
  const int killed = KillDuringWrites(
      [&] {
        const bool ok = WriteRotavgGraph(path, next_is_a ? a : b, &error, &orientations);
        next_is_a = !next_is_a;
        return ok;
      },
      [&](int round) {
        interrupted += fs::exists(path + ".tmp");
        ViewGraph back;
        const ReadReport report = ReadRotavgGraph(path, &back);
        ASSERT_TRUE(report.ok()) << "round " << round << ": " << report.error;
        EXPECT_TRUE(back.NumEdges() == a.NumEdges() || back.NumEdges() == b.NumEdges()) << back.NumEdges();
        fs::remove(path + ".tmp");
      },
      24);
  EXPECT_EQ(killed, 24);
  // Some kills came while a temporary was being written.
  EXPECT_GT(interrupted, 0);
}

TEST(OrientationIo, CsvRoundTripIsExact) {
  TempDir dir;
  NamedOrientations o;
  o["img_0001.jpg"] = ExpSO3(Eigen::Vector3d(0.3, -0.2, 2.9));
  o["7"] = ExpSO3(Eigen::Vector3d(-1.0, 0.5, 0.1));
  const std::string p = dir.Path() + "/o.csv";
  std::string error;
  ASSERT_TRUE(WriteOrientationsCsv(p, o, &error)) << error;
  NamedOrientations back;
  ASSERT_TRUE(ReadOrientationsCsv(p, &back).ok());
  ASSERT_EQ(back.size(), 2u);
  for (const auto& [name, r] : o) EXPECT_LT((back.at(name) - r).norm(), 1e-14);
  EXPECT_FALSE(fs::exists(p + ".tmp"));
}

TEST(OrientationIo, ColmapAndStrechaConventions) {
  TempDir dir;
  const Eigen::Matrix3d world_to_camera = ExpSO3(Eigen::Vector3d(0.2, 0.4, -0.1));
  const Eigen::Vector4d q = RotationToQuaternion(world_to_camera);
  std::ostringstream images;
  images.precision(17);
  images << "# comment\n1 " << q[0] << " " << q[1] << " " << q[2] << " " << q[3] << " 0 0 0 1 a.jpg\n10 20 -1\n";
  dir.Write("images.txt", images.str());
  NamedOrientations colmap;
  ASSERT_TRUE(ReadGroundTruth(dir.Path(), GroundTruthFormat::kAuto, &colmap).ok());
  EXPECT_LT((colmap.at("a.jpg") - world_to_camera).norm(), 1e-12);

  fs::create_directories(dir.Path() + "/s/gt_cameras");
  std::ostringstream cam;
  cam.precision(17);
  const Eigen::Matrix3d c2w = world_to_camera.transpose();
  cam << "1 0 0\n0 1 0\n0 0 1\n0 0 0\n";
  for (int r = 0; r < 3; ++r) cam << c2w(r, 0) << " " << c2w(r, 1) << " " << c2w(r, 2) << "\n";
  cam << "1 2 3\n100 100\n";
  std::ofstream(dir.Path() + "/s/gt_cameras/0000.jpg.camera") << cam.str();
  NamedOrientations strecha;
  ASSERT_TRUE(ReadGroundTruth(dir.Path() + "/s", GroundTruthFormat::kAuto, &strecha).ok());
  EXPECT_LT((strecha.at("0000.jpg") - world_to_camera).norm(), 1e-12);
}

TEST(OrientationIo, StrechaAsPublishedAndUnreadableFoldersSayWhatWasLookedFor) {
  TempDir dir;
  const Eigen::Matrix3d world_to_camera = ExpSO3(Eigen::Vector3d(-0.3, 0.1, 0.7));
  std::ostringstream cam;
  cam.precision(17);
  cam << "1 0 0\n0 1 0\n0 0 1\n0 0 0\n";
  const Eigen::Matrix3d c2w = world_to_camera.transpose();
  for (int r = 0; r < 3; ++r) cam << c2w(r, 0) << " " << c2w(r, 1) << " " << c2w(r, 2) << "\n";
  cam << "1 2 3\n100 100\n";
  // The published layout: gt_dense_cameras/.
  fs::create_directories(dir.Path() + "/published/gt_dense_cameras");
  std::ofstream(dir.Path() + "/published/gt_dense_cameras/0003.png.camera") << cam.str();
  NamedOrientations published;
  ASSERT_TRUE(ReadGroundTruth(dir.Path() + "/published", GroundTruthFormat::kAuto, &published).ok());
  EXPECT_LT((published.at("0003.png") - world_to_camera).norm(), 1e-12);
  // The camera folder itself.
  NamedOrientations direct;
  ASSERT_TRUE(ReadGroundTruth(dir.Path() + "/published/gt_dense_cameras", GroundTruthFormat::kAuto, &direct).ok());
  EXPECT_EQ(direct.size(), 1u);
  // A folder with no ground truth in it: the error lists what was looked for.
  fs::create_directories(dir.Path() + "/empty/images");
  NamedOrientations none;
  const ReadReport report = ReadGroundTruth(dir.Path() + "/empty", GroundTruthFormat::kAuto, &none);
  ASSERT_FALSE(report.ok());
  EXPECT_NE(report.error.find("gt_dense_cameras"), std::string::npos) << report.error;
  EXPECT_NE(report.error.find("images.txt"), std::string::npos) << report.error;
  EXPECT_EQ(report.error.find("EGs.txt: "), std::string::npos) << report.error;
  const ReadReport strecha = ReadGroundTruth(dir.Path() + "/empty", GroundTruthFormat::kStrecha, &none);
  ASSERT_FALSE(strecha.ok());
  EXPECT_NE(strecha.error.find("no .camera files"), std::string::npos) << strecha.error;
}

TEST(TextLines, NumbersAreParsedStrictly) {
  double v = 0.0;
  EXPECT_TRUE(ParseDouble("+1.5", &v));
  EXPECT_EQ(v, 1.5);
  EXPECT_TRUE(ParseDouble("-2.5e-3", &v));
  EXPECT_EQ(v, -2.5e-3);
  EXPECT_TRUE(ParseDouble("0.1", &v));
  EXPECT_EQ(v, 0.1);  // correctly rounded, like strtod
  for (const char* bad : {"", "+", "1.5x", "--1", "+-1", "1e-400", "1e400", "1,5", " 1"}) {
    EXPECT_FALSE(ParseDouble(bad, &v)) << bad;
  }
  std::uint64_t u = 0;
  EXPECT_TRUE(ParseUint64("18446744073709551615", &u));
  EXPECT_EQ(u, 18446744073709551615ULL);
  for (const char* bad : {"-1", "+1", "18446744073709551616", "1.0", ""}) EXPECT_FALSE(ParseUint64(bad, &u)) << bad;
  int i = 0;
  EXPECT_TRUE(ParseInt("-42", &i));
  EXPECT_EQ(i, -42);
  EXPECT_FALSE(ParseInt("2147483648", &i));
  std::string text;
  for (const double x : {0.1, 1.0 / 3.0, -2.5e-300, 6.02214076e23}) {
    text.clear();
    AppendDouble(&text, x);
    ASSERT_TRUE(ParseDouble(text, &v)) << text;
    EXPECT_EQ(v, x) << text;  // exact round trip
  }
}

TEST(TextLines, LinesAcrossBlocksLongLinesCrlfAndNoFinalNewline) {
  TempDir dir;
  // Lines of varying length spanning several 1 MiB blocks, one line longer
  // than a block, CRLF endings, and a last line without a newline.
  std::string text;
  std::vector<std::string> expected;
  for (int k = 0; k < 60000; ++k) {
    expected.push_back(std::string(k % 97, 'a' + k % 26) + std::to_string(k));
    text += expected.back() + (k % 3 == 0 ? "\r\n" : "\n");
    if (k % 3 == 0) expected.back() += '\r';
    if (k == 30000) {
      expected.push_back(std::string(3 << 20, 'x'));
      text += expected.back() + "\n";
    }
  }
  expected.push_back("last");
  text += "last";
  const std::string path = dir.Write("lines.txt", text);
  LineReader reader(path);
  ASSERT_TRUE(reader.IsOpen());
  std::string_view line;
  std::size_t n = 0;
  while (reader.Next(&line)) {
    ASSERT_LT(n, expected.size());
    ASSERT_EQ(line, expected[n]) << "line " << n + 1;
    ++n;
  }
  EXPECT_EQ(n, expected.size());
  EXPECT_EQ(reader.LineNumber(), static_cast<int>(expected.size()));
  EXPECT_FALSE(LineReader(dir.Path()).IsOpen());  // a folder is not a file
  std::vector<std::string_view> tokens;
  SplitTokens(" a,b\tc  d\r", &tokens, true);
  EXPECT_EQ(tokens, (std::vector<std::string_view>{"a", "b", "c", "d"}));
  SplitTokens(" a,b\tc  d\r", &tokens);
  EXPECT_EQ(tokens, (std::vector<std::string_view>{"a,b", "c", "d"}));
}

}  // namespace
}  // namespace rotation_averaging
