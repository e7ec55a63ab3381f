// The normal_fusion nodelet: subscribes (lazily) to an image, its camera_info
// and N normal maps, synchronizes them by stamp, and solves the newest set on a
// worker thread; publishes the fused map, its colour coding, statistics and
// diagnostics. A thin adapter around FusionPipeline.
#pragma once

#include <diagnostic_updater/diagnostic_updater.h>
#include <diagnostic_updater/update_functions.h>
#include <dynamic_reconfigure/server.h>
#include <image_transport/image_transport.h>
#include <nodelet/nodelet.h>
#include <normal_fusion/NormalFusionConfig.h>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/transform_listener.h>

#include <atomic>
#include <condition_variable>
#include <deque>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "normal_fusion/ros/log_throttle.h"
#include "normal_fusion/ros/parameters.h"
#include "normal_fusion/ros/pipeline.h"
#include "normal_fusion/synchronizer.h"

namespace normal_fusion {
namespace node {

class NormalFusionNodelet : public nodelet::Nodelet {
 public:
  NormalFusionNodelet() = default;
  ~NormalFusionNodelet() override;

 private:
  using Config = normal_fusion::NormalFusionConfig;
  using Synchronizer = StampSynchronizer<QueuedMessage>;

  void onInit() override;

  // Subscriptions only while some output has a subscriber.
  void connectCb();
  /// Ends the input subscriptions; the caller holds connect_mutex_.
  void shutdownInputs();
  void updateTfListener();
  // Every input callback ends here: checks, queues, forms sets.
  void onMessage(int topic, const std_msgs::Header& header,
                 const QueuedMessage& message);
  void handleMessage(int topic, const std_msgs::Header& header,
                     const QueuedMessage& message);
  void configCb(Config& config, uint32_t level);
  /// The parameters' ranges to dynamic_reconfigure clients.
  void publishParameterRanges();
  void workerLoop();
  /// The worker's settings: dynamic_reconfigure's changes handed to the
  /// pipeline; returns the motion lookup they ask for (empty: none).
  CameraMotionLookup applyNewSettings();
  /// On the worker, before the first set: the stream's buffers reserved
  /// for sets of the first camera_info's size (a failure only logged).
  void reserveBuffers(const std::pair<int, int>& size);
  void publishOutputs(const PipelineOutput& output);
  // Diagnostics (src/ros/diagnostics.cpp): the updater, its timer and the
  // warning when no set forms.
  void setupDiagnostics();
  void checkMissingInputs();
  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& status);
  Synchronizer::Options syncOptions(const NodeSettings& settings) const;
  void recordError(const std::string& text);
  /// Logs at most once per 5 s per kind of message (the text without its
  /// numbers), so that each distinct problem shows without flooding.
  void logThrottled(bool is_error, const std::string& text);

  // Start-time settings and the roles they give.
  ParameterMap static_params_;
  NodeSettings settings_;  ///< guarded by settings_mutex_
  std::vector<TopicRole> roles_;
  int num_inputs_ = 1;    ///< fixed at start
  int queue_size_ = 5;    ///< fixed at start
  MessageLimits limits_;  ///< fixed at start

  // Publishers and lazy subscriptions.
  std::mutex connect_mutex_;
  std::unique_ptr<image_transport::ImageTransport> it_;
  image_transport::Publisher pub_fused_;
  image_transport::Publisher pub_vis_;
  ros::Publisher pub_stats_;
  image_transport::Subscriber sub_image_;
  std::vector<ros::Subscriber> subs_;
  bool subscribed_ = false;

  // Synchronization (callbacks may run on several threads).
  std::mutex sync_mutex_;
  std::unique_ptr<Synchronizer> sync_;
  std::vector<ros::WallTime> last_arrival_;  ///< per topic
  ros::WallTime last_set_time_;
  ros::WallTime subscribed_since_;

  // The worker and the one pending set (newest wins).
  std::mutex work_mutex_;
  std::condition_variable work_cv_;
  std::optional<InputSet> pending_;
  ros::WallTime pending_formed_;
  bool stop_ = false;
  /// Time went back: the worker drops the warm start before the next set.
  bool stream_reset_ = false;
  /// The first camera_info's size, for the worker to reserve the stream's
  /// buffers before the first set (FusionPipeline::reserveFor()); asked once.
  std::optional<std::pair<int, int>> reserve_size_;
  bool reserve_asked_ = false;
  std::thread worker_;
  std::unique_ptr<FusionPipeline> pipeline_;  ///< used by the worker only

  // Cancels the solve as soon as roscpp begins to shut down, long before the
  // manager destroys the nodelet: a solve left running holds every core while
  // the rest of the process shuts down.
  void shutdownWatchLoop();
  std::mutex watch_mutex_;
  std::condition_variable watch_cv_;
  bool watch_stop_ = false;
  std::thread shutdown_watch_;

  // Settings from dynamic_reconfigure, picked up by the worker before a set.
  std::mutex settings_mutex_;
  bool settings_changed_ = false;
  std::unique_ptr<dynamic_reconfigure::Server<Config>> reconfigure_server_;
  boost::recursive_mutex reconfigure_mutex_;
  ros::Publisher pub_description_;

  // tf2, for the rotation-compensated warm start.
  std::shared_ptr<tf2_ros::Buffer> tf_buffer_;
  std::unique_ptr<tf2_ros::TransformListener> tf_listener_;

  // Counters and diagnostics.
  std::atomic<std::uint64_t> frames_dropped_{0};
  std::atomic<std::uint64_t> frames_skipped_{0};
  std::atomic<std::uint64_t> frames_processed_{0};
  std::mutex stats_mutex_;
  std::string last_error_;
  LogThrottle log_throttle_{5.0};
  ros::WallTime last_error_time_;
  std::deque<std::pair<ros::WallTime, double>> recent_outputs_;  ///< latency
  std::deque<ros::WallTime> recent_errors_;
  ros::WallTime last_output_time_;
  double last_solve_time_ = 0.0;
  std::unique_ptr<diagnostic_updater::Updater> updater_;
  /// Expected output rate bounds (Hz), fixed at start.
  double rate_min_ = 0.0, rate_max_ = 0.0;
  std::unique_ptr<diagnostic_updater::FrequencyStatus> output_rate_;
  std::string camera_frame_;  ///< the images' frame_id, the hardware_id
  ros::WallTimer timer_;
};

}  // namespace node
}  // namespace normal_fusion
