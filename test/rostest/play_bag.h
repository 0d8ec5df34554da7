// Shared by the rostests that play a bag into a live node: rosbag play in
// real time with the bag's clock (the launch file sets use_sim_time), then
// the node's ~orientations once they have settled, and its graph against the
// replay tool's.
#ifndef ROTATION_AVERAGING_TEST_ROSTEST_PLAY_BAG_H_
#define ROTATION_AVERAGING_TEST_ROSTEST_PLAY_BAG_H_

#include <gtest/gtest.h>
#include <ros/ros.h>

#include <algorithm>
#include <cstdlib>
#include <map>
#include <mutex>
#include <string>
#include <tuple>
#include <vector>

#include "rotation_averaging/Orientations.h"
#include "rotation_averaging/SaveGraph.h"
#include "rotation_averaging/core/io/graph_io.h"
#include "rotation_averaging/core/controllers/online_averager.h"
#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/core/io/orientation_io.h"
#include "rotation_averaging/ros/msg_conversion.h"

namespace rotation_averaging {

// Plays `bag` into the node `node` and returns its orientations (world to
// camera, by keyframe name) once a solution holds at least `keyframes` of
// them and nothing was published for eight seconds (the node has the last
// images queued or in its front end when the bag ends, and refines the
// latest solution once no new one came for two seconds, then publishes it
// again), or after 90 s.
inline NamedOrientations PlayIntoNode(const std::string& node, const std::string& bag, std::size_t keyframes) {
  ros::NodeHandle nh;
  std::mutex mutex;
  Orientations::ConstPtr latest;
  std::uint64_t received = 0;
  ros::Subscriber sub = nh.subscribe<Orientations>("/" + node + "/orientations", 10,
                                                   [&](const Orientations::ConstPtr& m) {
                                                     std::lock_guard<std::mutex> lock(mutex);
                                                     latest = m;
                                                     ++received;
                                                   });
  EXPECT_TRUE(ros::service::waitForService("/" + node + "/solve", ros::Duration(30.0)));
  const std::string play = "PATH=/usr/bin:$PATH rosbag play --clock --quiet --delay=1 " + bag + " > /dev/null 2>&1";
  EXPECT_EQ(std::system(play.c_str()), 0) << play;
  std::uint64_t last_received = 0;
  ros::WallTime settled_since = ros::WallTime::now();
  const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(90.0);
  while (ros::WallTime::now() < deadline) {
    ros::WallDuration(0.2).sleep();
    std::lock_guard<std::mutex> lock(mutex);
    if (!latest || latest->keyframes.size() < keyframes) continue;
    if (received != last_received) {
      last_received = received;
      settled_since = ros::WallTime::now();
      continue;
    }
    if ((ros::WallTime::now() - settled_since).toSec() > 8.0) break;
  }
  NamedOrientations live;
  std::lock_guard<std::mutex> lock(mutex);
  if (!latest) return live;
  for (const KeyframeOrientation& k : latest->keyframes) {
    live[OnlineAverager::KeyframeName({k.frame_id, ToNanoseconds(k.stamp)})] =
        QuaternionToRotation(k.orientation.w, k.orientation.x, k.orientation.y, k.orientation.z).transpose();
  }
  return live;
}

// Saves the node's graph to `live_path` (~save_graph) and expects it to be
// the replay's graph at `replay_path` edge for edge: pair, source, inliers,
// rotation. Keyed by the names of the two keyframes and the source; a pair
// may hold several edges (one per camera of a rig), sorted by inliers and
// rotation (the cameras' images of one capture reach the node in either
// order).
inline void ExpectNodeGraphIsTheReplays(const std::string& node, const std::string& live_path,
                                        const std::string& replay_path) {
  SaveGraph save;
  save.request.path = live_path;
  ASSERT_TRUE(ros::service::call("/" + node + "/save_graph", save));
  ASSERT_TRUE(save.response.success) << save.response.message;
  using EdgeKey = std::tuple<std::string, std::string, int>;
  using Edges = std::map<EdgeKey, std::vector<RelativeRotation>>;
  auto edges_of = [](const std::string& path, Edges* edges) {
    ViewGraph graph;
    const ReadReport report = ReadRotavgGraph(path, &graph);
    ASSERT_TRUE(report.ok()) << path << ": " << report.error;
    for (const RelativeRotation& e : graph.Edges()) {
      RelativeRotation named = e;
      std::string a = graph.FindView(e.view1)->name, b = graph.FindView(e.view2)->name;
      if (b < a) {
        std::swap(a, b);
        named = e.Inverted();
      }
      (*edges)[{a, b, static_cast<int>(e.source)}].push_back(named);
    }
    for (auto& [key, list] : *edges) {
      std::sort(list.begin(), list.end(), [](const RelativeRotation& x, const RelativeRotation& y) {
        return std::make_pair(x.num_inliers, x.rotation(0, 1)) < std::make_pair(y.num_inliers, y.rotation(0, 1));
      });
    }
  };
  Edges live_edges, replay_edges;
  edges_of(live_path, &live_edges);
  edges_of(replay_path, &replay_edges);
  ASSERT_FALSE(replay_edges.empty());
  EXPECT_EQ(live_edges.size(), replay_edges.size());
  for (const auto& [key, edges] : replay_edges) {
    const std::string pair = std::get<0>(key) + " - " + std::get<1>(key);
    auto it = live_edges.find(key);
    if (it == live_edges.end()) {
      ADD_FAILURE() << "the node lacks the edge " << pair;
      continue;
    }
    ASSERT_EQ(it->second.size(), edges.size()) << pair;
    for (std::size_t i = 0; i < edges.size(); ++i) {
      EXPECT_EQ(it->second[i].num_inliers, edges[i].num_inliers) << pair;
      EXPECT_LT(RadToDeg(AngularDistanceRad(it->second[i].rotation, edges[i].rotation)), 1e-6) << pair;
    }
  }
}

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_TEST_ROSTEST_PLAY_BAG_H_
