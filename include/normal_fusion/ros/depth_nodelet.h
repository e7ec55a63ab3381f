// The depth_to_normals nodelet: subscribes (lazily) to a depth image (REP
// 118: 16UC1 millimetres or 32FC1 metres) and its camera_info, pairs them by
// stamp, and computes the normals and their confidence on a worker thread
// (newest frame wins); publishes `normals` (32FC3) and `confidence` (32FC1)
// with the depth's header. A thin adapter around depth::DepthNormalEstimator.
#pragma once

#include <image_transport/image_transport.h>
#include <nodelet/nodelet.h>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>

#include <atomic>
#include <condition_variable>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "normal_fusion/depth.h"
#include "normal_fusion/ros/conversions.h"
#include "normal_fusion/ros/log_throttle.h"
#include "normal_fusion/ros/pipeline.h"
#include "normal_fusion/ros/synchronizer.h"

namespace normal_fusion {
namespace node {

/// The nodelet's start-time settings (private parameters of the same names).
struct DepthNodeSettings {
  depth::DepthNormalSettings normals;
  int queue_size = 5;  ///< per input topic, 1 .. 100
  int max_pixels = kDefaultMaxPixels;
};

/// Reads the private parameters; a value out of range (or of the wrong type)
/// keeps the default and adds a warning that names it.
DepthNodeSettings depthSettingsFromParameters(
    const ros::NodeHandle& pnh, std::vector<std::string>* warnings);

/// Writes the settings in use back to the private parameters.
void writeDepthParameters(const DepthNodeSettings& settings,
                          ros::NodeHandle& pnh);

/// The depth message in metres (NaN = no depth): 16UC1 / mono16 in
/// millimetres, 32FC1 in metres. Throws InputError naming the topic for
/// another encoding or a depth image without any valid pixel.
void depthFromMessage(const sensor_msgs::Image& msg, const std::string& topic,
                      ScalarMap& depth_m);

/// A one-plane map as 32FC1.
void scalarMapToMessage(const ScalarMap& values, const std_msgs::Header& header,
                        sensor_msgs::Image& msg);

class DepthToNormalsNodelet : public nodelet::Nodelet {
 public:
  DepthToNormalsNodelet() = default;
  ~DepthToNormalsNodelet() override;

 private:
  using Synchronizer = StampSynchronizer<QueuedMessage>;
  enum Topic { kDepth = 0, kCameraInfo = 1 };

  void onInit() override;
  void connectCb();
  void onMessage(int topic, const std_msgs::Header& header,
                 const QueuedMessage& message);
  void handleMessage(int topic, const std_msgs::Header& header,
                     const QueuedMessage& message);
  /// A checked pair: the depth image and its intrinsics.
  struct Work {
    sensor_msgs::ImageConstPtr depth;
    CameraIntrinsics K;
  };
  /// The checks of a pair that need no conversion (encoding, frames, K);
  /// throws InputError naming the topic.
  Work checkedWork(const QueuedMessage& depth, const QueuedMessage& info) const;
  void workerLoop();
  void process(const Work& work);
  void logThrottled(const std::string& text);

  DepthNodeSettings settings_;
  MessageLimits limits_;
  std::string topic_names_[2];

  std::mutex connect_mutex_;
  std::unique_ptr<image_transport::ImageTransport> it_;
  image_transport::Publisher pub_normals_;
  image_transport::Publisher pub_confidence_;
  image_transport::Subscriber sub_depth_;
  ros::Subscriber sub_info_;
  bool subscribed_ = false;

  std::mutex sync_mutex_;
  std::unique_ptr<Synchronizer> sync_;

  std::mutex work_mutex_;
  std::condition_variable work_cv_;
  std::optional<Work> pending_;
  bool stop_ = false;
  std::thread worker_;
  depth::DepthNormalEstimator estimator_;  ///< used by the worker only
  ScalarMap depth_m_;                      ///< the worker's buffers
  NormalMap normals_;
  ScalarMap confidence_;

  LogThrottle log_throttle_{5.0};
  std::atomic<std::uint64_t> frames_skipped_{0};
};

}  // namespace node
}  // namespace normal_fusion
