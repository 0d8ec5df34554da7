// rotavg_node_benchmark: measures a running rotation_averaging_node (see
// scripts/benchmark_node.sh, which starts a private master and the node).
//
//  * latency from publishing a relative pose that adds a keyframe to the
//    moment that keyframe's frame can be looked up in tf2, with N keyframes
//    already in the graph;
//  * the relative-pose message rate the node takes in without dropping
//    (messages received, from its diagnostics, against messages sent).
#include <diagnostic_msgs/DiagnosticArray.h>
#include <ros/ros.h>
#include <std_srvs/Trigger.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/transform_listener.h>

#include <algorithm>
#include <atomic>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <mutex>
#include <random>
#include <sstream>

#include "rotation_averaging/Orientations.h"
#include "rotation_averaging/RelativePoseArray.h"
#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/ros/msg_conversion.h"
#include "rotation_averaging/util/random_draws.h"
#include "rotation_averaging/util/freed_memory.h"

namespace ra = rotation_averaging;

namespace {

std::mutex g_mutex;
std::size_t g_keyframes = 0;
double g_received = -1.0;

// A single-camera trajectory: world-to-camera rotations and relative poses.
struct Trajectory {
  std::vector<Eigen::Matrix3d> rotations;
  std::mt19937 rng{5};
  Eigen::Matrix3d Next() {
    std::normal_distribution<double> step(0.0, 0.02);
    Eigen::Matrix3d r = Eigen::Matrix3d::Identity();
    if (!rotations.empty()) r = ra::ExpSO3(ra::DrawVector3(rng, step)) * rotations.back();
    rotations.push_back(r);
    return r;
  }
  ra::RelativePose Edge(int a, int b, std::uint8_t source) const {
    ra::KeyframeRelativeRotation m;
    m.keyframe1 = {"bench_cam", 1'000'000'000LL + a * 10'000'000LL};
    m.keyframe2 = {"bench_cam", 1'000'000'000LL + b * 10'000'000LL};
    m.rotation = rotations[a] * rotations[b].transpose();
    m.has_covariance = true;
    m.covariance = Eigen::Matrix3d::Identity() * 1e-6;
    m.num_inliers = 100;
    m.source = static_cast<ra::EdgeSource>(source);
    return ra::ToMsg(m);
  }
};

void OnOrientations(const ra::Orientations::ConstPtr& m) {
  std::lock_guard<std::mutex> lock(g_mutex);
  g_keyframes = m->keyframes.size();
}

void OnDiagnostics(const diagnostic_msgs::DiagnosticArray::ConstPtr& m) {
  for (const auto& status : m->status) {
    for (const auto& kv : status.values) {
      if (kv.key == "messages received") {
        std::lock_guard<std::mutex> lock(g_mutex);
        g_received = std::stod(kv.value);
      }
    }
  }
}

double Percentile(std::vector<double> v, double q) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0.0 : v[std::min(v.size() - 1, static_cast<std::size_t>(q * v.size()))];
}

bool WaitFor(const std::function<bool()>& done, double timeout_s) {
  const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(timeout_s);
  while (!done() && ros::WallTime::now() < deadline) ros::WallDuration(0.001).sleep();
  return done();
}

}  // namespace

int main(int argc, char** argv) {
  rotation_averaging::KeepFreedMemoryForReuse();  // util/freed_memory.h: buffers of each image reused, not faulted in again
  ros::init(argc, argv, "rotavg_node_benchmark");
  ros::NodeHandle nh, pnh("~");
  const std::string output = pnh.param<std::string>("output", "results/node_benchmark.md");
  const std::string command = pnh.param<std::string>("command", "bash scripts/benchmark_node.sh");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  ros::Publisher array_pub = nh.advertise<ra::RelativePoseArray>("relative_poses", 10);
  ros::Publisher single_pub = nh.advertise<ra::RelativePose>("relative_pose", 100000);
  ros::Subscriber orientations = nh.subscribe("/rotation_averaging/orientations", 1, &OnOrientations);
  ros::Subscriber diagnostics = nh.subscribe("/diagnostics", 10, &OnDiagnostics);
  if (!ros::service::waitForService("/rotation_averaging/reset", ros::Duration(30.0))) {
    std::cerr << "no rotation_averaging node\n";
    return 1;
  }
  WaitFor([&] { return array_pub.getNumSubscribers() > 0 && single_pub.getNumSubscribers() > 0; }, 10.0);
  tf2_ros::Buffer buffer(ros::Duration(100000.0));
  tf2_ros::TransformListener listener(buffer);
  auto keyframes = [] {
    std::lock_guard<std::mutex> lock(g_mutex);
    return g_keyframes;
  };

  std::ostringstream md;
  md << "# Node benchmark\n\nReproduce with: `" << command
     << "`. A private master, one rotation_averaging_node (solve_period_s "
     << pnh.param("solve_period_s", 0.0) << " s, tf_mode all_keyframes) and this client on the same 2-core machine; "
        "synthetic single-camera graphs with sequential edges and a loop closure every 50 keyframes.\n\n"
     << "## Latency: relative pose in -> keyframe frame in tf2\n\n"
     << "| keyframes in the graph | trials | median (ms) | 95th percentile (ms) | max (ms) |\n|---|---|---|---|---|\n";

  for (int n : {1000, 10000}) {
    std_srvs::Trigger reset;
    ros::service::call("/rotation_averaging/reset", reset);
    Trajectory t;
    for (int i = 0; i < n + 40; ++i) t.Next();
    ra::RelativePoseArray batch;
    for (int i = 1; i < n; ++i) {
      batch.poses.push_back(t.Edge(i - 1, i, ra::RelativePose::SOURCE_SEQUENTIAL));
      if (i % 50 == 0 && i >= 100) batch.poses.push_back(t.Edge(i - 100, i, ra::RelativePose::SOURCE_OTHER));
    }
    array_pub.publish(batch);
    std_srvs::Trigger solve;
    WaitFor([&] { return ros::service::call("/rotation_averaging/solve", solve) && keyframes() >= std::size_t(n); }, 120.0);
    std::vector<double> latencies;
    for (int k = 0; k < 30; ++k) {
      const int id = n + k;
      const std::string frame = "bench_cam_kf_" + std::to_string(1'000'000'000LL + id * 10'000'000LL);
      const ros::WallTime start = ros::WallTime::now();
      single_pub.publish(t.Edge(id - 1, id, ra::RelativePose::SOURCE_SEQUENTIAL));
      if (!WaitFor([&] { return buffer.canTransform("map", frame, ros::Time(0)); }, 30.0)) {
        std::cerr << "keyframe " << id << " never appeared on tf\n";
        break;
      }
      latencies.push_back((ros::WallTime::now() - start).toSec() * 1e3);
    }
    md << "| " << n << " | " << latencies.size() << " | " << std::fixed << std::setprecision(1)
       << Percentile(latencies, 0.5) << " | " << Percentile(latencies, 0.95) << " | "
       << Percentile(latencies, 1.0) << " |\n";
    std::cerr << n << " keyframes: median latency " << Percentile(latencies, 0.5) << " ms\n";
  }

  md << "\n## Relative-pose message rate\n\nSingle RelativePose messages published for 3 s at each rate; received is "
        "the node's own counter (diagnostics), so drops anywhere between the publisher and the node's queue show.\n\n"
     << "| rate sent (msg/s) | sent | received | received / sent |\n|---|---|---|---|\n";
  std_srvs::Trigger reset;
  ros::service::call("/rotation_averaging/reset", reset);
  Trajectory t;
  int next = 0;
  t.Next();
  for (int rate : {1000, 5000, 20000}) {
    ros::WallDuration(2.5).sleep();  // let the 1 Hz diagnostics catch up with everything sent so far
    double before = -1.0;
    WaitFor([&] {
      std::lock_guard<std::mutex> lock(g_mutex);
      before = g_received;
      return before >= 0.0;
    }, 10.0);
    const int count = rate * 3;
    ros::WallRate r(rate);
    for (int k = 0; k < count; ++k) {
      t.Next();
      single_pub.publish(t.Edge(next, next + 1, ra::RelativePose::SOURCE_SEQUENTIAL));
      ++next;
      r.sleep();
    }
    ros::WallDuration(3.0).sleep();  // diagnostics update at 1 Hz
    double after = 0.0;
    {
      std::lock_guard<std::mutex> lock(g_mutex);
      after = g_received;
    }
    const double received = after - before;
    md << "| " << rate << " | " << count << " | " << std::setprecision(0) << received << " | " << std::setprecision(3)
       << received / count << " |\n";
    std::cerr << rate << " msg/s: " << received << " of " << count << " received\n";
  }
  std::cout << md.str();
  std::ofstream(output) << md.str();
  std::cerr << "wrote " << output << "\n";
  return 0;
}
