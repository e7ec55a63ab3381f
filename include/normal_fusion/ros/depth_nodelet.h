// The depth_to_normals nodelet: subscribes (lazily) to a depth image (REP
// 118: 16UC1 millimetres or 32FC1 metres) and its camera_info, pairs them by
// stamp, and computes the normals and their confidence on a worker thread
// (newest frame wins); publishes `normals` (32FC3) and `confidence` (32FC1)
// with the depth's header. A thin adapter around depth::DepthNormalEstimator.
//
// With `register_to_rgb` it also keeps the newest `rgb/camera_info` (the
// colour camera's) and registers the normals into the colour image
// (depth::DepthRegistration) with T_rgb_depth from tf2 at the depth's stamp;
// the outputs then carry the colour camera's frame_id and size (and the
// depth's stamp), and `depth_registered/image_rect` (32FC1, metres) the depth
// of the surface shown. A colour camera_info with the depth's frame_id and
// size means the depth is already aligned: nothing is registered.
#pragma once

#include <image_transport/image_transport.h>
#include <nodelet/nodelet.h>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/transform_listener.h>

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
#include "normal_fusion/registration.h"
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
  /// Register into the colour camera of `rgb/camera_info`.
  bool register_to_rgb = false;
  /// How long to wait for T_rgb_depth at a depth stamp (s), 0 .. 10.
  double tf_timeout = 0.1;
  depth::RegistrationSettings registration;
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
  enum Topic { kDepth = 0, kCameraInfo = 1, kRgbCameraInfo = 2 };

  void onInit() override;
  void connectCb();
  /// Ends the input subscriptions; the caller holds connect_mutex_.
  void shutdownInputs();
  void onMessage(int topic, const std_msgs::Header& header,
                 const QueuedMessage& message);
  void handleMessage(int topic, const std_msgs::Header& header,
                     const QueuedMessage& message);
  /// A checked pair: the depth image and its intrinsics, and the colour
  /// camera to register into (null rgb_info: none, already aligned).
  struct Work {
    sensor_msgs::ImageConstPtr depth;
    CameraIntrinsics K;
    /// The depth camera's distortion (read when registering).
    LensDistortion depth_distortion;
    sensor_msgs::CameraInfoConstPtr rgb_info;
    depth::TargetCamera rgb;
  };
  /// The checks of a pair that need no conversion (encoding, frames, K);
  /// throws InputError naming the topic.
  Work checkedWork(const QueuedMessage& depth, const QueuedMessage& info) const;
  /// Adds the colour camera to a checked pair when registering; throws
  /// InputError naming the topic.
  void addColourCamera(Work& work,
                       const sensor_msgs::CameraInfoConstPtr& rgb_info) const;
  void onRgbInfo(const sensor_msgs::CameraInfoConstPtr& msg);
  void workerLoop();
  void process(const Work& work);
  /// T_rgb_depth from tf2 at the depth's stamp; throws InputError naming
  /// both frames when it is not there within tf_timeout.
  depth::RigidTransform lookupRgbFromDepth(const Work& work) const;
  void publishRegistered(const Work& work,
                         const depth::RigidTransform& T_rgb_depth,
                         bool want_normals, bool want_confidence,
                         bool want_depth);
  void logThrottled(const std::string& text);

  DepthNodeSettings settings_;
  MessageLimits limits_;
  std::string topic_names_[3];

  std::mutex connect_mutex_;
  std::unique_ptr<image_transport::ImageTransport> it_;
  image_transport::Publisher pub_normals_;
  image_transport::Publisher pub_confidence_;
  image_transport::Publisher pub_depth_registered_;  ///< register_to_rgb only
  image_transport::Subscriber sub_depth_;
  ros::Subscriber sub_info_;
  ros::Subscriber sub_rgb_info_;
  bool subscribed_ = false;

  std::mutex sync_mutex_;
  std::unique_ptr<Synchronizer> sync_;
  sensor_msgs::CameraInfoConstPtr rgb_info_;  ///< newest; under sync_mutex_

  std::unique_ptr<tf2_ros::Buffer> tf_buffer_;  ///< register_to_rgb only
  std::unique_ptr<tf2_ros::TransformListener> tf_listener_;

  std::mutex work_mutex_;
  std::condition_variable work_cv_;
  std::optional<Work> pending_;
  bool stop_ = false;
  std::thread worker_;
  depth::DepthNormalEstimator estimator_;  ///< used by the worker only
  ScalarMap depth_m_;                      ///< the worker's buffers
  NormalMap normals_;
  ScalarMap confidence_;
  depth::DepthRegistration registration_;  ///< used by the worker only
  NormalMap normals_rgb_;
  ScalarMap confidence_rgb_;
  ScalarMap depth_rgb_;

  LogThrottle log_throttle_{5.0};
  std::atomic<std::uint64_t> frames_skipped_{0};
};

}  // namespace node
}  // namespace normal_fusion
