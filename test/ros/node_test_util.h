// The client side of the node's rostests (test/ros/test_node*.cpp, one gtest
// node): publishers of the inputs, collectors of the outputs and of /rosout,
// the stamps of the frames sent (one sequence for all tests) and the node's
// process.
#pragma once

#include <normal_fusion/FusionStats.h>
#include <ros/master.h>
#include <ros/network.h>
#include <ros/ros.h>
#include <rosgraph_msgs/Log.h>
#include <xmlrpcpp/XmlRpc.h>

#include <cstdint>
#include <functional>
#include <map>
#include <mutex>
#include <string>
#include <vector>

#include "eval/synthetic.h"
#include "ros_test_util.h"

namespace nf = normal_fusion;

namespace normal_fusion {
namespace node_test {

using test::cameraInfoMessage;
using test::imageMessage;
using test::makeHeader;
using test::normalsMessage;

inline constexpr int kWidth = 96, kHeight = 72;

/// Polls `done` until it holds or `seconds` pass.
inline bool waitFor(const std::function<bool()>& done, double seconds) {
  const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(seconds);
  while (ros::WallTime::now() < end) {
    if (done()) return true;
    ros::WallDuration(0.01).sleep();
  }
  return done();
}

/// Publishers of one node's inputs and collectors of its outputs.
class NodeClient {
 public:
  explicit NodeClient(const std::string& ns) : nh_(ns) {
    image_ = nh_.advertise<sensor_msgs::Image>("image", 10);
    info_ = nh_.advertise<sensor_msgs::CameraInfo>("camera_info", 10);
    normals_[0] = nh_.advertise<sensor_msgs::Image>("normals_0", 10);
    normals_[1] = nh_.advertise<sensor_msgs::Image>("normals_1", 10);
  }

  void listen(bool fused, bool vis, bool stats) {
    if (fused) {
      fused_sub_ = nh_.subscribe<sensor_msgs::Image>(
          "fused_normals", 20, [this](const sensor_msgs::ImageConstPtr& m) {
            std::lock_guard<std::mutex> lock(mutex_);
            fused_[m->header.stamp] = m;
          });
    }
    if (vis) {
      vis_sub_ = nh_.subscribe<sensor_msgs::Image>(
          "fused_normals_vis", 20, [this](const sensor_msgs::ImageConstPtr& m) {
            std::lock_guard<std::mutex> lock(mutex_);
            vis_[m->header.stamp] = m;
          });
    }
    if (stats) {
      stats_sub_ = nh_.subscribe<nf::FusionStats>(
          "fusion_stats", 20, [this](const nf::FusionStatsConstPtr& m) {
            std::lock_guard<std::mutex> lock(mutex_);
            stats_[m->header.stamp] = m;
          });
    }
  }

  void stopListening() {
    fused_sub_.shutdown();
    vis_sub_.shutdown();
    stats_sub_.shutdown();
  }

  int inputSubscribers() const {
    return image_.getNumSubscribers() + info_.getNumSubscribers() +
           normals_[0].getNumSubscribers() + normals_[1].getNumSubscribers();
  }

  /// Publishes one frame's messages; `mutate` may spoil them first.
  struct FrameMessages {
    sensor_msgs::ImagePtr image, normals[2];
    sensor_msgs::CameraInfoPtr info;
  };
  FrameMessages messagesFor(const nf::test::NoisyFrame& f, double stamp) const {
    const std_msgs::Header header = makeHeader(stamp);
    FrameMessages m;
    m.image = imageMessage(f.frame.image, header);
    m.info = cameraInfoMessage(f.frame.K, kWidth, kHeight, header);
    m.normals[0] = normalsMessage(f.noisy, header);
    m.normals[1] = normalsMessage(f.from_depth, header);
    return m;
  }
  void publish(const FrameMessages& m) {
    if (m.info) info_.publish(m.info);
    if (m.normals[0]) normals_[0].publish(m.normals[0]);
    if (m.normals[1]) normals_[1].publish(m.normals[1]);
    if (m.image) image_.publish(m.image);
  }

  sensor_msgs::ImageConstPtr fused(const ros::Time& stamp) {
    std::lock_guard<std::mutex> lock(mutex_);
    auto it = fused_.find(stamp);
    return it == fused_.end() ? nullptr : it->second;
  }
  sensor_msgs::ImageConstPtr vis(const ros::Time& stamp) {
    std::lock_guard<std::mutex> lock(mutex_);
    auto it = vis_.find(stamp);
    return it == vis_.end() ? nullptr : it->second;
  }
  nf::FusionStatsConstPtr stats(const ros::Time& stamp) {
    std::lock_guard<std::mutex> lock(mutex_);
    auto it = stats_.find(stamp);
    return it == stats_.end() ? nullptr : it->second;
  }
  std::size_t statsCount() {
    std::lock_guard<std::mutex> lock(mutex_);
    return stats_.size();
  }

  ros::NodeHandle nh_;

 private:
  ros::Publisher image_, info_, normals_[2];
  std::mutex mutex_;
  std::map<ros::Time, sensor_msgs::ImageConstPtr> fused_, vis_;
  std::map<ros::Time, nf::FusionStatsConstPtr> stats_;
  // Declared last so that they are destroyed first: a callback still arriving
  // on the spinner's threads never finds the data it writes to destroyed.
  ros::Subscriber fused_sub_, vis_sub_, stats_sub_;
};

/// Collects /rosout so that tests can check what the node logged.
class LogCollector {
 public:
  LogCollector() {
    ros::NodeHandle nh;
    sub_ = nh.subscribe<rosgraph_msgs::Log>(
        "/rosout", 100, [this](const rosgraph_msgs::LogConstPtr& m) {
          std::lock_guard<std::mutex> lock(mutex_);
          logs_.push_back(*m);
        });
  }
  /// True once a message at `level` or above contains every part.
  bool seen(std::uint8_t level, const std::vector<std::string>& parts) {
    std::lock_guard<std::mutex> lock(mutex_);
    for (const auto& log : logs_) {
      if (log.level < level) continue;
      bool all = true;
      for (const auto& p : parts) {
        all = all && log.msg.find(p) != std::string::npos;
      }
      if (all) return true;
    }
    return false;
  }

 private:
  std::mutex mutex_;
  std::vector<rosgraph_msgs::Log> logs_;
  // Declared last so that it is destroyed first: a callback still arriving
  // on the spinner's threads never finds the data it writes to destroyed.
  ros::Subscriber sub_;
};

inline std::string nodeName() {
  std::string name = "/normal_fusion";
  ros::NodeHandle("~").getParam("node_name", name);
  return name;
}

inline const nf::test::NoisyFrame& sceneFrame() {
  static const nf::test::NoisyFrame frame =
      nf::test::noisyFrame(nf::synthetic::renderScene(0, kWidth, kHeight), 17);
  return frame;
}

/// Publishes `m` and waits for the outputs with its stamp.
inline bool answered(NodeClient& client, const NodeClient::FrameMessages& m,
                     double seconds = 5.0) {
  client.publish(m);
  const ros::Time stamp = m.image->header.stamp;
  return waitFor([&] { return client.stats(stamp) != nullptr; }, seconds);
}

/// The stamp of the latest frame sent, one for all the source files, so that
/// stamps keep increasing from test to test.
inline double next_stamp = 100.0;
inline double newStamp(double step = 0.1) { return next_stamp += step; }

inline bool compareMode() {
  std::string namespaces;
  return ros::NodeHandle("~").getParam("compare_namespaces", namespaces) &&
         !namespaces.empty();
}

/// The pid of the process that runs a node, from its XML-RPC API (-1 when
/// unknown).
inline int pidOfNode(const std::string& node) {
  XmlRpc::XmlRpcValue args, result, payload;
  args[0] = ros::this_node::getName();
  args[1] = node;
  if (!ros::master::execute("lookupNode", args, result, payload, true)) {
    return -1;
  }
  std::string host, uri = static_cast<std::string>(payload);
  std::uint32_t port = 0;
  if (!ros::network::splitURI(uri, host, port)) return -1;
  XmlRpc::XmlRpcClient client(host.c_str(), static_cast<int>(port), "/");
  XmlRpc::XmlRpcValue pid_args, pid_result;
  pid_args[0] = ros::this_node::getName();
  if (!client.execute("getPid", pid_args, pid_result) ||
      static_cast<int>(pid_result[0]) != 1) {
    return -1;
  }
  return static_cast<int>(pid_result[2]);
}

}  // namespace node_test
}  // namespace normal_fusion
