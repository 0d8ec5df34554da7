#include "rotation_averaging/core/controllers/rig_model.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <fstream>
#include <iterator>
#include <memory>

#include "rotation_averaging/core/geometry/so3.h"

namespace rotation_averaging {
namespace {

// Two cameras on a rig through a two-level static tree
// (base_link -> mount -> cam_a, base_link -> cam_b), one camera without.
struct Fixture {
  Eigen::Matrix3d mount_in_base = ExpSO3(Eigen::Vector3d(0.0, 0.0, 0.3));
  Eigen::Matrix3d a_in_mount = ExpSO3(Eigen::Vector3d(0.2, -0.1, 0.05));
  Eigen::Matrix3d b_in_base = ExpSO3(Eigen::Vector3d(-0.3, 0.4, 1.2));
  Eigen::Matrix3d a_from_rig() const { return (mount_in_base * a_in_mount).transpose(); }
  Eigen::Matrix3d b_from_rig() const { return b_in_base.transpose(); }
  std::unique_ptr<RigModel> Model(RigModelOptions options = {}) const {
    options.stamp_tolerance_s = 0.005;
    auto rig = std::make_unique<RigModel>(options);
    rig->AddStaticTransform("base_link", "mount", mount_in_base);
    rig->AddStaticTransform("mount", "cam_a", a_in_mount);
    rig->AddStaticTransform("base_link", "cam_b", b_in_base);
    return rig;
  }
};

KeyframeRelativeRotation Measure(const KeyframeKey& k1, const Eigen::Matrix3d& r1, const KeyframeKey& k2,
                                 const Eigen::Matrix3d& r2) {
  KeyframeRelativeRotation m;
  m.keyframe1 = k1;
  m.keyframe2 = k2;
  m.rotation = r1 * r2.transpose();
  m.has_covariance = true;
  m.covariance = Eigen::Vector3d(1e-4, 4e-4, 9e-4).asDiagonal();
  return m;
}

TEST(RigModel, ResolvesCamerasThroughTheStaticTree) {
  Fixture f;
  const std::unique_ptr<RigModel> owned = f.Model();
  RigModel& rig = *owned;
  EXPECT_TRUE(rig.IsRigCamera("cam_a"));
  EXPECT_TRUE(rig.IsRigCamera("cam_b"));
  EXPECT_FALSE(rig.IsRigCamera("cam_loose"));
  const auto cameras = rig.RigCameras();
  ASSERT_EQ(cameras.size(), 2u);
  EXPECT_EQ(cameras.at("cam_a").first, "base_link");
  EXPECT_TRUE(cameras.at("cam_a").second.isApprox(f.a_from_rig(), 1e-12));
  EXPECT_TRUE(cameras.at("cam_b").second.isApprox(f.b_from_rig(), 1e-12));
  // A rig frame that only cam_a reaches.
  RigModelOptions mount;
  mount.rig_frame = "mount";
  const auto mounted = f.Model(mount);
  EXPECT_TRUE(mounted->IsRigCamera("cam_a"));
  EXPECT_FALSE(mounted->IsRigCamera("cam_b"));
  // Disabled: nothing is a rig camera.
  RigModelOptions off;
  off.enabled = false;
  EXPECT_FALSE(f.Model(off)->IsRigCamera("cam_a"));
}

TEST(RigModel, MeasurementsBecomeCaptureLevelAndExpandBack) {
  Fixture f;
  const std::unique_ptr<RigModel> owned = f.Model();
  RigModel& rig = *owned;
  // Rig orientations (world-to-rig) at two captures; cam_b fires 2 ms late.
  const Eigen::Matrix3d rig0 = ExpSO3(Eigen::Vector3d(0.1, 0.2, 0.3));
  const Eigen::Matrix3d rig1 = ExpSO3(Eigen::Vector3d(0.15, 0.1, 0.6));
  const KeyframeKey a0{"cam_a", 1000000000}, b0{"cam_b", 1002000000}, a1{"cam_a", 2000000000};
  const Eigen::Matrix3d ra0 = f.a_from_rig() * rig0, rb0 = f.b_from_rig() * rig0, ra1 = f.a_from_rig() * rig1;

  // Within one capture: absorbed.
  KeyframeRelativeRotation v;
  EXPECT_FALSE(rig.ToVariables(Measure(a0, ra0, b0, rb0), &v));
  EXPECT_EQ(rig.NumAbsorbed(), 1u);
  // Across captures: R_A R_B^T of the rig, covariance rotated into B's rig frame.
  const KeyframeRelativeRotation m = Measure(b0, rb0, a1, ra1);
  ASSERT_TRUE(rig.ToVariables(m, &v));
  EXPECT_EQ(v.keyframe1.frame_id, "base_link");
  EXPECT_EQ(v.keyframe1.stamp_ns, 1000000000);  // the capture founded by cam_a
  EXPECT_EQ(v.keyframe2.stamp_ns, 2000000000);
  EXPECT_LT(AngularDistanceRad(v.rotation, rig0 * rig1.transpose()), 1e-12);
  EXPECT_TRUE(v.covariance.isApprox(f.a_from_rig().transpose() * m.covariance * f.a_from_rig(), 1e-12));
  // A camera-level right perturbation of the measurement equals the
  // rig-level perturbation with the rotated vector.
  const Eigen::Vector3d e(0.01, -0.02, 0.005);
  KeyframeRelativeRotation perturbed = m;
  perturbed.rotation = m.rotation * ExpSO3(e);
  KeyframeRelativeRotation pv;
  ASSERT_TRUE(rig.ToVariables(perturbed, &pv));
  EXPECT_LT(AngularDistanceRad(pv.rotation, v.rotation * ExpSO3(f.a_from_rig().transpose() * e)), 1e-12);
  // PerturbationToVariables gives that vector (the identity for a camera
  // without extrinsics).
  EXPECT_LT(AngularDistanceRad(pv.rotation, v.rotation * ExpSO3(rig.PerturbationToVariables(a1.frame_id, e))), 1e-12);
  EXPECT_TRUE(rig.PerturbationToVariables("cam_loose", e).isApprox(e, 1e-15));
  // Different camera pairs of the same two captures are told apart.
  KeyframeRelativeRotation other;
  ASSERT_TRUE(rig.ToVariables(Measure(a0, ra0, a1, ra1), &other));
  EXPECT_NE(other.channel, v.channel);

  // Expansion: every camera keyframe seen gets E_c R_rig, with its own stamp.
  OnlineSolution capture_level;
  capture_level.orientations[v.keyframe1] = rig0;
  capture_level.orientations[v.keyframe2] = rig1;
  capture_level.component[v.keyframe1] = 0;
  const OnlineSolution cameras = rig.ToCameraKeyframes(capture_level);
  ASSERT_EQ(cameras.orientations.size(), 3u);
  EXPECT_LT(AngularDistanceRad(cameras.orientations.at(a0), ra0), 1e-12);
  EXPECT_LT(AngularDistanceRad(cameras.orientations.at(b0), rb0), 1e-12);
  EXPECT_LT(AngularDistanceRad(cameras.orientations.at(a1), ra1), 1e-12);
  EXPECT_EQ(cameras.component.at(b0), 0);
}

TEST(RigModel, CamerasWithoutExtrinsicsStayKeyframes) {
  Fixture f;
  const std::unique_ptr<RigModel> owned = f.Model();
  RigModel& rig = *owned;
  const KeyframeKey loose0{"cam_loose", 1000000000}, a0{"cam_a", 1000000000};
  KeyframeRelativeRotation v;
  const Eigen::Matrix3d r = ExpSO3(Eigen::Vector3d(0.3, 0.0, 0.0));
  ASSERT_TRUE(rig.ToVariables(Measure(loose0, r, a0, Eigen::Matrix3d::Identity()), &v));
  EXPECT_EQ(v.keyframe1.frame_id, "cam_loose");
  EXPECT_EQ(v.keyframe2.frame_id, "base_link");
  // Extrinsics that arrive after a camera was first seen do not move it.
  rig.AddStaticTransform("base_link", "cam_loose", Eigen::Matrix3d::Identity());
  EXPECT_FALSE(rig.IsRigCamera("cam_loose"));
}

// A saved rig model restores, in a model that has seen no static transform
// (a restarted node), the same captures and the same camera keyframes in
// them: a solution over the saved captures expands to the same cameras, and
// a new measurement to an old keyframe maps to its old capture. A camera
// without extrinsics stays on its own. Damaged files are refused with the
// reason and change nothing.
TEST(RigModel, SavedCapturesComeBackWithoutTheStaticTransforms) {
  Fixture f;
  const std::unique_ptr<RigModel> owned = f.Model();
  RigModel& rig = *owned;
  const KeyframeKey a0{"cam_a", 1000000000}, b0{"cam_b", 1002000000}, a1{"cam_a", 2000000000},
      loose{"cam_loose", 1500000000};
  const Eigen::Matrix3d r = ExpSO3(Eigen::Vector3d(0.3, 0.1, 0.0));
  KeyframeRelativeRotation v;
  ASSERT_TRUE(rig.ToVariables(Measure(b0, r, a1, Eigen::Matrix3d::Identity()), &v));
  ASSERT_TRUE(rig.ToVariables(Measure(a0, r, loose, Eigen::Matrix3d::Identity()), &v));
  const std::string path = ::testing::TempDir() + "/rig_model_test.rig";
  std::string error;
  ASSERT_TRUE(rig.Save(path, &error)) << error;

  RigModel restored(RigModelOptions{});  // no static transform at all
  ASSERT_TRUE(restored.Load(path, &error)) << error;
  EXPECT_EQ(restored.NumCaptures(), 2u);
  EXPECT_TRUE(restored.IsRigCamera("cam_a"));
  EXPECT_FALSE(restored.IsRigCamera("cam_loose"));
  OnlineSolution capture_level;
  const KeyframeKey first_capture = rig.VariableOfKnown(a0), second_capture = rig.VariableOfKnown(a1);
  EXPECT_EQ(first_capture.stamp_ns, b0.stamp_ns);  // founded by cam_b, whose keyframe came first
  EXPECT_EQ(restored.VariableOfKnown(a0).stamp_ns, first_capture.stamp_ns);
  capture_level.orientations[first_capture] = Eigen::Matrix3d::Identity();
  capture_level.orientations[second_capture] = r;
  capture_level.orientations[loose] = r;
  const OnlineSolution before = rig.ToCameraKeyframes(capture_level);
  const OnlineSolution after = restored.ToCameraKeyframes(capture_level);
  ASSERT_EQ(after.orientations.size(), 4u);  // a0, b0, a1 and the loose camera's keyframe
  for (const auto& [key, orientation] : before.orientations) {
    ASSERT_TRUE(after.orientations.count(key)) << key.frame_id << "@" << key.stamp_ns;
    EXPECT_LT(AngularDistanceRad(after.orientations.at(key), orientation), 1e-9);
  }
  KeyframeRelativeRotation old_end;
  ASSERT_TRUE(restored.ToVariables(Measure(b0, r, KeyframeKey{"cam_a", 3000000000}, r), &old_end));
  EXPECT_EQ(old_end.keyframe1.frame_id, "base_link");
  EXPECT_EQ(old_end.keyframe1.stamp_ns, first_capture.stamp_ns);

  std::ifstream in(path);
  const std::string good((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const std::size_t held = restored.NumCaptures();  // the two loaded and the new one at 3 s
  EXPECT_EQ(held, 3u);
  auto refused = [&](const std::string& text, const std::string& reason) {
    const std::string damaged = ::testing::TempDir() + "/rig_model_test_damaged.rig";
    std::ofstream(damaged) << text;
    std::string why;
    EXPECT_FALSE(restored.Load(damaged, &why)) << reason;
    EXPECT_NE(why.find(reason), std::string::npos) << why;
    EXPECT_EQ(restored.NumCaptures(), held);
  };
  refused(good.substr(0, good.rfind("END")), "truncated");
  std::string changed = good;
  changed[changed.find("MEMBER cam_b 100") + 14] = '7';
  refused(changed, "checksum mismatch");
  refused("# rotation_averaging rig v9\nEND 1 0\n", "not a rig file of this version");

  // Adding a map's rig file (another session's) to a model: its captures
  // come in beside those held, and a capture held already stays as it is.
  const std::string continued = ::testing::TempDir() + "/rig_model_test_continued.rig";
  ASSERT_TRUE(restored.Save(continued, &error)) << error;
  RigModel merged(RigModelOptions{});
  ASSERT_TRUE(merged.Load(path, &error)) << error;
  ASSERT_TRUE(merged.Add(continued, &error)) << error;
  EXPECT_EQ(merged.NumCaptures(), 3u);
  EXPECT_EQ(merged.VariableOfKnown(KeyframeKey{"cam_a", 3000000000}).stamp_ns, 3000000000);
  EXPECT_EQ(merged.VariableOfKnown(a0).stamp_ns, first_capture.stamp_ns);
  EXPECT_FALSE(merged.Add(::testing::TempDir() + "/rig_model_test_damaged.rig", &error));
  EXPECT_EQ(merged.NumCaptures(), 3u);
}

}  // namespace
}  // namespace rotation_averaging
