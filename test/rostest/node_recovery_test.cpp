// No data lost: a node that autosaves its graph is killed with SIGKILL
// mid-run; restarted with load_graph on the saved file it republishes the
// same orientations. A corrupted save makes it start empty, not with garbage.
// With images, the restarted node relates new keyframes to those before the
// kill (its keyframe database is saved with the graph): one map, not two.
#include <gtest/gtest.h>
#include <ros/ros.h>
#include <signal.h>
#include <std_srvs/Trigger.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <mutex>

#include <cv_bridge/cv_bridge.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>

#include <set>

#include "common/synthetic_rig.h"
#include "common/test_vocabulary.h"
#include "rotation_averaging/sim/rig_scene.h"
#include "rotation_averaging/Orientations.h"
#include "rotation_averaging/RelativePoseArray.h"
#include "rotation_averaging/core/eval/rotation_evaluation.h"
#include "rotation_averaging/ros/msg_conversion.h"

namespace rotation_averaging {
namespace {

pid_t StartNode(const std::vector<std::string>& args) {
  const pid_t pid = fork();
  if (pid == 0) {
    std::vector<char*> argv;
    std::string binary = ROTAVG_NODE_BINARY;
    argv.push_back(binary.data());
    std::vector<std::string> copy = args;
    for (std::string& a : copy) argv.push_back(a.data());
    argv.push_back(nullptr);
    freopen("/dev/null", "w", stdout);
    execv(binary.c_str(), argv.data());
    _exit(127);
  }
  return pid;
}

// Kills the node it holds when it goes out of scope: a failed assertion
// must not leave a node running (it would hold ctest's output pipe open).
struct NodeProcess {
  explicit NodeProcess(pid_t p) : pid(p) {}
  ~NodeProcess() { Stop(SIGKILL); }
  int Stop(int signal) {
    int status = 0;
    if (pid > 0) {
      kill(pid, signal);
      waitpid(pid, &status, 0);
    }
    pid = -1;
    return status;
  }
  pid_t pid;
};

class Recovery : public ::testing::Test {
 protected:
  void Subscribe() {
    sub_ = nh_.subscribe<Orientations>("/crash_node/orientations", 10, [this](const Orientations::ConstPtr& m) {
      std::lock_guard<std::mutex> lock(mutex_);
      latest_ = m;
    });
  }
  // Waits for a solution with `n` keyframes; returns them by name.
  bool WaitFor(std::size_t n, NamedOrientations* out, double seconds = 20.0) {
    const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(seconds);
    while (ros::WallTime::now() < deadline) {
      {
        std::lock_guard<std::mutex> lock(mutex_);
        if (latest_ && latest_->keyframes.size() == n) {
          out->clear();
          for (const KeyframeOrientation& k : latest_->keyframes) {
            (*out)[OnlineAverager::KeyframeName({k.frame_id, ToNanoseconds(k.stamp)})] =
                QuaternionToRotation(k.orientation.w, k.orientation.x, k.orientation.y, k.orientation.z).transpose();
          }
          return true;
        }
      }
      ros::WallDuration(0.05).sleep();
    }
    return false;
  }
  void Forget() {
    std::lock_guard<std::mutex> lock(mutex_);
    latest_.reset();
  }
  // Connected components of the latest solution (0 before any).
  std::size_t Components() {
    std::lock_guard<std::mutex> lock(mutex_);
    std::set<std::uint32_t> components;
    if (latest_) {
      for (const KeyframeOrientation& k : latest_->keyframes) components.insert(k.component);
    }
    return components.size();
  }
  ros::NodeHandle nh_;
  ros::Subscriber sub_;
  std::mutex mutex_;
  Orientations::ConstPtr latest_;
};

TEST_F(Recovery, SigkilledNodeRestartsFromItsAutosave) {
  const std::string save =
      (std::filesystem::temp_directory_path() / ("rotavg_autosave_" + std::to_string(getpid()) + ".txt")).string();
  std::filesystem::remove(save);
  const std::vector<std::string> common = {"__name:=crash_node", "relative_poses:=/crash_test/relative_poses",
                                           "_tf_mode:=none", "_solve_period_s:=0.2"};
  std::vector<std::string> first = common;
  first.push_back("_autosave_path:=" + save);
  first.push_back("_autosave_period:=0.3");
  const pid_t a = StartNode(first);
  ASSERT_GT(a, 0);
  ASSERT_TRUE(ros::service::waitForService("/crash_node/solve", ros::Duration(30.0)));
  Subscribe();
  ros::Publisher pub = nh_.advertise<RelativePoseArray>("/crash_test/relative_poses", 10);
  const ros::WallTime until = ros::WallTime::now() + ros::WallDuration(10.0);
  while (pub.getNumSubscribers() == 0 && ros::WallTime::now() < until) ros::WallDuration(0.05).sleep();
  const RigData rig = MakeRig(30, 0.1, 21);
  RelativePoseArray batch;
  for (const KeyframeRelativeRotation& m : rig.measurements) batch.poses.push_back(ToMsg(m));
  pub.publish(batch);
  NamedOrientations before;
  ASSERT_TRUE(WaitFor(rig.truth.size(), &before));
  ros::WallDuration(1.0).sleep();  // at least one autosave after the solve
  // Compared with what the node holds when it is killed: the first solution
  // with every keyframe may be a local re-solve that the full solves after it
  // refine (under the sanitizers it came 0.55 deg from the restarted node's).
  ASSERT_TRUE(WaitFor(rig.truth.size(), &before));
  ASSERT_TRUE(std::filesystem::exists(save));
  kill(a, SIGKILL);
  int status = 0;
  waitpid(a, &status, 0);
  ASSERT_TRUE(WIFSIGNALED(status));

  // Restart from the save: the same orientations come back.
  Forget();
  std::vector<std::string> second = common;
  second.push_back("_load_graph:=" + save);
  const pid_t b = StartNode(second);
  NamedOrientations after;
  ASSERT_TRUE(WaitFor(rig.truth.size(), &after));
  const EvaluationResult between = EvaluateOrientations(after, before);
  double worst = 0.0;
  for (const auto& [name, e] : between.errors_deg) worst = std::max(worst, e);
  EXPECT_EQ(between.views_common, rig.truth.size());
  EXPECT_LT(worst, 0.01);
  kill(b, SIGTERM);
  waitpid(b, &status, 0);

  // A corrupted save: the node starts empty (nothing to solve) and keeps answering.
  {
    std::fstream f(save, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(200);
    f.write("#####", 5);
  }
  Forget();
  const pid_t c = StartNode(second);
  ASSERT_TRUE(ros::service::waitForService("/crash_node/solve", ros::Duration(30.0)));
  std_srvs::Trigger solve;
  ASSERT_TRUE(ros::service::call("/crash_node/solve", solve));
  EXPECT_FALSE(solve.response.success) << solve.response.message;
  kill(c, SIGTERM);
  waitpid(c, &status, 0);
  std::filesystem::remove(save);
}

// A node fed a camera's keyframes is SIGKILLed after the first lap of the
// room and restarted on its autosave: the second lap's keyframes close loops
// with the first lap's, so the final solution is one component holding both.
TEST_F(Recovery, SigkilledImageNodeContinuesItsMap) {
  const std::string dir = (std::filesystem::temp_directory_path() / ("rotavg_image_recovery_" + std::to_string(getpid())))
                              .string();
  std::filesystem::create_directories(dir);
  const std::string save = dir + "/map.txt", vocabulary = dir + "/test.vocab";
  std::string error;
  ASSERT_TRUE(TestVocabulary()->Save(vocabulary, &error)) << error;
  constexpr int kPerLap = 16;
  RigSceneOptions o;
  o.num_cameras = 1;
  o.laps = 2;
  o.num_captures = 2 * kPerLap;
  o.WithWidth(480);
  const RigScene scene(o);
  const std::vector<std::string> common = {
      "__name:=crash_node", "_image_topics:=[/crash_cam/image_raw]", "_keyframe_selection:=all", "_tf_mode:=none",
      "_solve_period_s:=0.2", "_max_features:=600", "_compact_features:=300", "_vocabulary:=" + vocabulary,
      "_autosave_path:=" + save, "_autosave_period_s:=0.3", "_max_image_queue:=64"};
  ros::Publisher image_pub = nh_.advertise<sensor_msgs::Image>("/crash_cam/image_raw", 2 * kPerLap);
  ros::Publisher info_pub = nh_.advertise<sensor_msgs::CameraInfo>("/crash_cam/camera_info", 2 * kPerLap);
  // Publishes captures [from, to), a tenth of a second apart, into a queue
  // that holds them all (nothing is dropped however long the front end takes).
  auto feed = [&](int from, int to) {
    const ros::WallTime until = ros::WallTime::now() + ros::WallDuration(30.0);
    while ((image_pub.getNumSubscribers() == 0 || info_pub.getNumSubscribers() == 0) && ros::WallTime::now() < until) {
      ros::WallDuration(0.05).sleep();
    }
    ASSERT_GT(image_pub.getNumSubscribers(), 0u);
    for (int c = from; c < to; ++c) {
      std_msgs::Header header;
      header.frame_id = "crash_cam";
      header.stamp = ros::Time(100.0 + c);
      const cv::Mat image = scene.Render(c, 0);
      sensor_msgs::CameraInfo info;
      info.header = header;
      info.width = image.cols;
      info.height = image.rows;
      for (int e = 0; e < 9; ++e) info.K[e] = scene.Intrinsics()(e / 3, e % 3);
      info_pub.publish(info);
      image_pub.publish(cv_bridge::CvImage(header, image.channels() == 1 ? "mono8" : "bgr8", image).toImageMsg());
      ros::WallDuration(0.1).sleep();
    }
  };

  NodeProcess a(StartNode(common));
  ASSERT_GT(a.pid, 0);
  ASSERT_TRUE(ros::service::waitForService("/crash_node/solve", ros::Duration(30.0)));
  Subscribe();
  feed(0, kPerLap);
  if (HasFatalFailure()) return;
  NamedOrientations first_lap;
  ASSERT_TRUE(WaitFor(kPerLap, &first_lap, 120.0)) << "the first lap was not solved";
  ros::WallDuration(1.0).sleep();  // an autosave after the last solve
  ASSERT_TRUE(std::filesystem::exists(save + ".keyframes"));
  ASSERT_TRUE(WIFSIGNALED(a.Stop(SIGKILL)));

  Forget();
  std::vector<std::string> restart = common;
  restart.push_back("_load_graph:=" + save);
  NodeProcess b(StartNode(restart));
  NamedOrientations loaded;
  ASSERT_TRUE(WaitFor(kPerLap, &loaded, 30.0)) << "the restarted node did not publish the saved map";
  feed(kPerLap, 2 * kPerLap);
  if (HasFatalFailure()) return;
  NamedOrientations all;
  ASSERT_TRUE(WaitFor(2 * kPerLap, &all, 120.0)) << "the second lap was not solved with the first";
  // A full solve after the last loop closure: one component.
  std_srvs::Trigger solve;
  ASSERT_TRUE(ros::service::call("/crash_node/solve", solve)) << solve.response.message;
  ros::WallDuration(0.5).sleep();
  EXPECT_EQ(Components(), 1u) << "the keyframes after the restart are not joined to those before it";
  b.Stop(SIGTERM);
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace rotation_averaging
