// rostest: relative poses with covariances for a synthetic two-camera rig
// (loop closures, 10% outlier edges, and malformed messages) are published to
// two running nodes; the orientations read back from tf2 must match ground
// truth within a tolerance the MAGSAC + covariance solve reaches and the
// squared loss does not. Also: the latched Orientations topic, and the
// save_graph / reset / load_graph / solve services.
#include <gtest/gtest.h>
#include <ros/ros.h>
#include <std_srvs/Trigger.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/transform_listener.h>

#include <filesystem>
#include <limits>
#include <mutex>

#include "common/synthetic_rig.h"
#include <diagnostic_msgs/DiagnosticArray.h>
#include <dynamic_reconfigure/Reconfigure.h>

#include <map>

#include "rotation_averaging/LoadGraph.h"
#include "rotation_averaging/Orientations.h"
#include "rotation_averaging/RelativePoseArray.h"
#include "rotation_averaging/SaveGraph.h"
#include "rotation_averaging/core/eval/rotation_evaluation.h"
#include "rotation_averaging/ros/msg_conversion.h"

namespace rotation_averaging {
namespace {

class NodeTest : public ::testing::Test {
 protected:
  void SetUp() override {
    for (const char* service : {"/averaging_magsac/solve", "/averaging_squared/solve"}) {
      ASSERT_TRUE(ros::service::waitForService(service, ros::Duration(30.0))) << service;
    }
    pub_ = nh_.advertise<RelativePoseArray>("/test/relative_poses", 10);
    single_pub_ = nh_.advertise<RelativePose>("/test/relative_pose", 100);
    const ros::Time deadline = ros::Time::now() + ros::Duration(20.0);
    while ((pub_.getNumSubscribers() < 2 || single_pub_.getNumSubscribers() < 2) && ros::Time::now() < deadline) {
      ros::Duration(0.05).sleep();
    }
    ASSERT_EQ(pub_.getNumSubscribers(), 2u);
  }

  // Orientations (world-to-camera) of every keyframe as read from tf.
  NamedOrientations ReadTf(const std::string& prefix, const RigData& rig) {
    NamedOrientations out;
    for (const auto& [key, truth] : rig.truth) {
      const std::string child = prefix + "/" + key.frame_id + "_kf_" + std::to_string(key.stamp_ns);
      try {
        const auto t = buffer_.lookupTransform("map", child, ros::Time(0), ros::Duration(10.0));
        const auto& q = t.transform.rotation;
        out[OnlineAverager::KeyframeName(key)] = QuaternionToRotation(q.w, q.x, q.y, q.z).transpose();
      } catch (const tf2::TransformException& e) {
        ADD_FAILURE() << "no transform for " << child << ": " << e.what();
        break;
      }
    }
    return out;
  }

  static NamedOrientations Truth(const RigData& rig) {
    NamedOrientations gt;
    for (const auto& [key, r] : rig.truth) gt[OnlineAverager::KeyframeName(key)] = r;
    return gt;
  }

  // Resets the MAGSAC node, sends it the rig's relative poses and solves.
  bool ReplaceMagsacGraph(const RigData& rig) {
    RelativePoseArray batch;
    for (const KeyframeRelativeRotation& m : rig.measurements) batch.poses.push_back(ToMsg(m));
    if (!Call("/averaging_magsac/reset")) return false;
    pub_.publish(batch);
    ros::Duration(0.5).sleep();
    return Call("/averaging_magsac/solve");
  }

  bool Call(const std::string& service) {
    std_srvs::Trigger srv;
    return ros::service::call(service, srv) && srv.response.success;
  }

  ros::NodeHandle nh_;
  ros::Publisher pub_, single_pub_;
  tf2_ros::Buffer buffer_;
  tf2_ros::TransformListener listener_{buffer_};
};

TEST_F(NodeTest, OrientationsOnTfMatchGroundTruthAndBeatTheSquaredLoss) {
  const RigData rig = MakeRig(40, 0.1, 7);
  RelativePoseArray batch;
  for (const KeyframeRelativeRotation& m : rig.measurements) batch.poses.push_back(ToMsg(m));
  pub_.publish(batch);
  // Malformed input on the single topic: must be dropped, not break anything.
  RelativePose bad = ToMsg(rig.measurements.front());
  bad.rotation.w = std::numeric_limits<double>::quiet_NaN();
  single_pub_.publish(bad);
  bad = ToMsg(rig.measurements.front());
  bad.rotation.w *= 3.0;  // non-unit quaternion
  single_pub_.publish(bad);
  bad = ToMsg(rig.measurements.front());
  bad.frame_id_2 = bad.frame_id_1;
  bad.stamp_2 = bad.stamp_1;  // a keyframe related to itself
  single_pub_.publish(bad);
  bad = ToMsg(rig.measurements.front());
  bad.rotation_covariance = {-1, 0, 0, 0, -1, 0, 0, 0, -1};  // not positive definite
  single_pub_.publish(bad);
  ros::Duration(1.0).sleep();  // delivery, then at least one periodic solve
  ASSERT_TRUE(Call("/averaging_magsac/solve"));
  ASSERT_TRUE(Call("/averaging_squared/solve"));

  const NamedOrientations gt = Truth(rig);
  const EvaluationResult magsac = EvaluateOrientations(ReadTf("magsac", rig), gt);
  const EvaluationResult squared = EvaluateOrientations(ReadTf("squared", rig), gt);
  EXPECT_EQ(magsac.views_common, rig.truth.size());
  EXPECT_EQ(squared.views_common, rig.truth.size());
  EXPECT_LT(magsac.median_error_deg, 1.0);
  EXPECT_GT(squared.median_error_deg, 3.0 * magsac.median_error_deg);
}

// Every kind of malformed relative pose is dropped and counted in the
// node's diagnostics, and the node keeps answering.
TEST_F(NodeTest, BadInputIsRejectedAndCountedInDiagnostics) {
  std::mutex mutex;
  std::map<std::string, std::string> values;  // the MAGSAC node's last diagnostic values
  auto sub = nh_.subscribe<diagnostic_msgs::DiagnosticArray>(
      "/diagnostics", 10, [&](const diagnostic_msgs::DiagnosticArray::ConstPtr& m) {
        for (const auto& status : m->status) {
          if (status.name.find("averaging_magsac") == std::string::npos) continue;
          std::lock_guard<std::mutex> lock(mutex);
          for (const auto& kv : status.values) values[kv.key] = kv.value;
        }
      });
  auto rejected = [&]() -> long {
    std::lock_guard<std::mutex> lock(mutex);
    auto it = values.find("rejected messages");
    return it == values.end() ? -1 : std::stol(it->second);
  };
  const ros::Time deadline = ros::Time::now() + ros::Duration(10.0);
  while (rejected() < 0 && ros::Time::now() < deadline) ros::Duration(0.05).sleep();
  const long before = rejected();
  ASSERT_GE(before, 0) << "no diagnostics from averaging_magsac";

  const RigData rig = MakeRig(10, 0.0, 11);
  std::vector<RelativePose> bad(6, ToMsg(rig.measurements.front()));
  bad[0].rotation.w = std::numeric_limits<double>::quiet_NaN();          // NaN quaternion
  bad[1].rotation.w *= 3.0;                                              // non-unit quaternion
  bad[2].frame_id_2 = bad[2].frame_id_1;                                 // a keyframe related to itself
  bad[2].stamp_2 = bad[2].stamp_1;
  bad[3].rotation_covariance = {-1, 0, 0, 0, -1, 0, 0, 0, -1};          // not positive definite
  bad[4].stamp_2 = ros::Time(0);                                         // uninitialised stamp
  bad[5].frame_id_1 = "";                                                // no camera
  for (const RelativePose& m : bad) single_pub_.publish(m);
  const ros::Time until = ros::Time::now() + ros::Duration(10.0);
  while (rejected() < before + 6 && ros::Time::now() < until) ros::Duration(0.05).sleep();
  EXPECT_EQ(rejected(), before + 6);
  // Still answering, and a good batch still solves.
  EXPECT_TRUE(ReplaceMagsacGraph(rig));
}

TEST_F(NodeTest, LatchedOrientationsAndGraphServices) {
  const RigData rig = MakeRig(20, 0.0, 8);
  ASSERT_TRUE(ReplaceMagsacGraph(rig));

  // Callbacks run on the AsyncSpinner's thread.
  std::mutex mutex;
  Orientations::ConstPtr latest;
  auto sub = nh_.subscribe<Orientations>("/averaging_magsac/orientations", 1, [&](const Orientations::ConstPtr& m) {
    std::lock_guard<std::mutex> lock(mutex);
    latest = m;
  });
  auto current = [&]() {
    std::lock_guard<std::mutex> lock(mutex);
    return latest;
  };
  // Waits for a message of `keyframes` keyframes from a solve after `after`.
  auto wait = [&](std::size_t keyframes, std::uint64_t after = 0) {
    auto done = [&]() {
      const Orientations::ConstPtr m = current();
      return m && m->keyframes.size() == keyframes && m->solve_sequence > after;
    };
    const ros::Time deadline = ros::Time::now() + ros::Duration(10.0);
    while (ros::Time::now() < deadline && !done()) ros::Duration(0.02).sleep();
    return done();
  };
  ASSERT_TRUE(wait(rig.truth.size())) << "latest: "
                                      << (current() ? std::to_string(current()->keyframes.size()) + " keyframes, solve " +
                                                          std::to_string(current()->solve_sequence)
                                                    : std::string("none"));
  EXPECT_EQ(current()->header.frame_id, "map");
  const std::uint64_t sequence = current()->solve_sequence;

  const std::string path =
      (std::filesystem::temp_directory_path() / ("rotavg_node_test_" + std::to_string(::getpid()) + ".txt")).string();
  SaveGraph save;
  save.request.path = path;
  ASSERT_TRUE(ros::service::call("/averaging_magsac/save_graph", save));
  ASSERT_TRUE(save.response.success) << save.response.message;
  ASSERT_TRUE(Call("/averaging_magsac/reset"));
  EXPECT_FALSE(Call("/averaging_magsac/solve"));  // empty graph: nothing to solve
  LoadGraph load;
  load.request.path = path;
  ASSERT_TRUE(ros::service::call("/averaging_magsac/load_graph", load));
  ASSERT_TRUE(load.response.success) << load.response.message;
  // The load publishes during the service call: wait for a newer solve.
  ASSERT_TRUE(wait(rig.truth.size(), sequence));
  load.request.path = path + ".missing";
  ASSERT_TRUE(ros::service::call("/averaging_magsac/load_graph", load));
  EXPECT_FALSE(load.response.success);
  // The same map added to itself: every keyframe and edge is held already.
  LoadGraph add;
  add.request.path = path;
  ASSERT_TRUE(ros::service::call("/averaging_magsac/add_map", add));
  ASSERT_TRUE(add.response.success) << add.response.message;
  EXPECT_NE(add.response.message.find("0 views and 0 edges (" + std::to_string(rig.truth.size()) + " views"),
            std::string::npos)
      << add.response.message;
  add.request.path = path + ".missing";
  ASSERT_TRUE(ros::service::call("/averaging_magsac/add_map", add));
  EXPECT_FALSE(add.response.success);
  std::filesystem::remove(path);
}

TEST_F(NodeTest, DynamicReconfigureChangesTheLossAtTheNextSolve) {
  const RigData rig = MakeRig(40, 0.1, 9);
  ASSERT_TRUE(ReplaceMagsacGraph(rig));
  const NamedOrientations gt = Truth(rig);
  const double magsac = EvaluateOrientations(ReadTf("magsac", rig), gt).median_error_deg;

  auto set_loss = [](const std::string& loss) {
    dynamic_reconfigure::Reconfigure srv;
    dynamic_reconfigure::StrParameter p;
    p.name = "loss";
    p.value = loss;
    srv.request.config.strs.push_back(p);
    return ros::service::call("/averaging_magsac/set_parameters", srv) &&
           !srv.response.config.strs.empty();
  };
  // The worker re-solves at once after a reconfiguration; tf then changes.
  auto error_after = [&](const std::string& loss) {
    EXPECT_TRUE(set_loss(loss));
    ros::Duration(1.0).sleep();
    return EvaluateOrientations(ReadTf("magsac", rig), gt).median_error_deg;
  };
  const double squared = error_after("squared");
  EXPECT_GT(squared, 3.0 * magsac) << "the squared loss did not take effect";
  const double back = error_after("magsac");
  EXPECT_LT(back, 1.5 * magsac + 0.05);
  // An unknown loss is refused and the node keeps working.
  EXPECT_TRUE(set_loss("no_such_loss"));
  EXPECT_TRUE(Call("/averaging_magsac/solve"));
}

}  // namespace
}  // namespace rotation_averaging
