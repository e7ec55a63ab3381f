#include "normal_fusion/ros/depth_nodelet.h"

#include <tf2/LinearMath/Matrix3x3.h>
#include <tf2/LinearMath/Quaternion.h>
#include <tf2/exceptions.h>
#include <pluginlib/class_list_macros.hpp>

#include <cstring>
#include <functional>
#include <sstream>

#include "normal_fusion/errors.h"

namespace normal_fusion {
namespace node {
namespace {

using WarnFn = std::function<void(const std::string&, const std::string&)>;

/// The registration's private parameters (register_to_rgb, tf_timeout,
/// registration_splat); a bad value keeps the default and warns.
void readRegistrationParameters(const ros::NodeHandle& pnh,
                                DepthNodeSettings* s, const WarnFn& warn) {
  bool register_to_rgb;
  if (pnh.getParam("register_to_rgb", register_to_rgb)) {
    s->register_to_rgb = register_to_rgb;
  } else if (pnh.hasParam("register_to_rgb")) {
    warn("register_to_rgb", "expected a boolean");
  }
  if (pnh.hasParam("tf_timeout")) {
    double timeout = -1.0;
    int timeout_int;
    if (!pnh.getParam("tf_timeout", timeout) &&
        pnh.getParam("tf_timeout", timeout_int)) {
      timeout = timeout_int;
    }
    if (timeout >= 0.0 && timeout <= 10.0) {
      s->tf_timeout = timeout;
    } else {
      warn("tf_timeout", "expected a number of seconds in [0, 10]");
    }
  }
  std::string splat;
  if (pnh.getParam("registration_splat", splat)) {
    try {
      s->registration.splat = depth::splatFromString(splat);
    } catch (const Error& e) {
      warn("registration_splat", e.what());
    }
  } else if (pnh.hasParam("registration_splat")) {
    warn("registration_splat", "expected a string (2x2 or nearest)");
  }
}

/// R and t of a tf2 transform (p_target = R p_source + t).
depth::RigidTransform rigidTransformOf(const geometry_msgs::Transform& T) {
  const tf2::Matrix3x3 R(
      tf2::Quaternion(T.rotation.x, T.rotation.y, T.rotation.z, T.rotation.w));
  depth::RigidTransform out;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) out.R[3 * r + c] = R[r][c];
  }
  out.t = {T.translation.x, T.translation.y, T.translation.z};
  return out;
}

}  // namespace

DepthNodeSettings depthSettingsFromParameters(
    const ros::NodeHandle& pnh, std::vector<std::string>* warnings) {
  DepthNodeSettings s;
  depth::DepthNormalSettings& n = s.normals;
  const auto warn = [&](const std::string& name, const std::string& why) {
    std::ostringstream text;
    text << "parameter '" << name << "': " << why << "; the default is used";
    warnings->push_back(text.str());
  };
  std::string method;
  if (pnh.getParam("method", method)) {
    try {
      n.method = depth::normalMethodFromString(method);
    } catch (const Error& e) {
      warn("method", e.what());
    }
  } else if (pnh.hasParam("method")) {
    warn("method", "expected a string (central_difference or plane_fit)");
  }
  // Each number on its own: a value out of range keeps the default.
  const auto number = [&](const char* name, double* field) {
    double value;
    if (!pnh.getParam(name, value)) {
      int integer;
      if (!pnh.getParam(name, integer)) {
        if (pnh.hasParam(name)) warn(name, "expected a number");
        return;
      }
      value = integer;
    }
    const double old = *field;
    *field = value;
    try {
      n.validate();
    } catch (const Error& e) {
      *field = old;
      warn(name, e.what());
    }
  };
  const auto integer = [&](const char* name, int* field, int lo, int hi) {
    int value;
    if (!pnh.getParam(name, value)) {
      if (pnh.hasParam(name)) warn(name, "expected an integer");
      return;
    }
    if (value < lo || value > hi) {
      warn(name, "expected a value in [" + std::to_string(lo) + ", " +
                     std::to_string(hi) + "], got " + std::to_string(value));
      return;
    }
    *field = value;
  };
  integer("window_radius", &n.window_radius, 1, 10);
  number("discontinuity_ratio", &n.discontinuity_ratio);
  number("discontinuity_noise_sigmas", &n.discontinuity_noise_sigmas);
  number("noise_coefficient", &n.noise_coefficient);
  number("normal_sigma_scale", &n.normal_sigma_scale);
  number("edge_distance", &n.edge_distance);
  integer("num_threads", &n.num_threads, 1, 256);
  integer("queue_size", &s.queue_size, 1, 100);
  integer("max_pixels", &s.max_pixels, 0, 2000000000);
  readRegistrationParameters(pnh, &s, warn);
  return s;
}

void writeDepthParameters(const DepthNodeSettings& s, ros::NodeHandle& pnh) {
  const depth::DepthNormalSettings& n = s.normals;
  pnh.setParam("method", depth::toString(n.method));
  pnh.setParam("window_radius", n.window_radius);
  pnh.setParam("discontinuity_ratio", n.discontinuity_ratio);
  pnh.setParam("discontinuity_noise_sigmas", n.discontinuity_noise_sigmas);
  pnh.setParam("noise_coefficient", n.noise_coefficient);
  pnh.setParam("normal_sigma_scale", n.normal_sigma_scale);
  pnh.setParam("edge_distance", n.edge_distance);
  pnh.setParam("num_threads", n.num_threads);
  pnh.setParam("queue_size", s.queue_size);
  pnh.setParam("max_pixels", s.max_pixels);
  pnh.setParam("register_to_rgb", s.register_to_rgb);
  pnh.setParam("tf_timeout", s.tf_timeout);
  pnh.setParam("registration_splat", depth::toString(s.registration.splat));
}

void depthFromMessage(const sensor_msgs::Image& msg, const std::string& topic,
                      ScalarMap& depth_m) {
  std::size_t valid = 0;
  if (msg.encoding == "16UC1" || msg.encoding == "mono16") {
    valid = depth::depthFromMillimetres(msg.data.data(), msg.width, msg.height,
                                        msg.step, depth_m);
  } else if (msg.encoding == "32FC1") {
    valid = depth::depthFromMetres(msg.data.data(), msg.width, msg.height,
                                   msg.step, depth_m);
  } else {
    throw InputError(topic + ": unsupported depth encoding '" + msg.encoding +
                     "'; expected 16UC1 (millimetres) or 32FC1 (metres), "
                     "REP 118");
  }
  if (valid == 0) {
    throw InputError(topic + ": no valid depth in the " + msg.encoding + " " +
                     std::to_string(msg.width) + "x" +
                     std::to_string(msg.height) +
                     " image (all 0 or NaN); expected at least one");
  }
}

void scalarMapToMessage(const ScalarMap& values, const std_msgs::Header& header,
                        sensor_msgs::Image& msg) {
  msg.header = header;
  msg.width = values.width();
  msg.height = values.height();
  msg.encoding = "32FC1";
  msg.is_bigendian = 0;
  msg.step = static_cast<std::uint32_t>(values.width() * sizeof(float));
  msg.data.resize(static_cast<std::size_t>(msg.step) * msg.height);
  std::memcpy(msg.data.data(), values.plane(0), msg.data.size());
}

DepthToNormalsNodelet::~DepthToNormalsNodelet() {
  // Unsubscribed first: shutdown() waits for a callback under way, so that
  // none runs on the members destroyed after this body.
  {
    std::lock_guard<std::mutex> lock(connect_mutex_);
    shutdownInputs();
  }
  {
    std::lock_guard<std::mutex> lock(work_mutex_);
    stop_ = true;
  }
  work_cv_.notify_all();
  if (worker_.joinable()) worker_.join();
}

void DepthToNormalsNodelet::onInit() {
  ros::NodeHandle& nh = getNodeHandle();
  ros::NodeHandle& pnh = getPrivateNodeHandle();
  std::vector<std::string> warnings;
  settings_ = depthSettingsFromParameters(pnh, &warnings);
  for (const std::string& w : warnings) NODELET_WARN("%s", w.c_str());
  // The values in use, for anyone who asks the parameter server.
  writeDepthParameters(settings_, pnh);
  estimator_.setSettings(settings_.normals);
  limits_.max_pixels = static_cast<std::uint64_t>(settings_.max_pixels);
  topic_names_[kDepth] = nh.resolveName("depth");
  topic_names_[kCameraInfo] = nh.resolveName("camera_info");
  topic_names_[kRgbCameraInfo] = nh.resolveName("rgb/camera_info");
  registration_.setSettings(settings_.registration);
  if (settings_.register_to_rgb) {
    tf_buffer_ = std::make_unique<tf2_ros::Buffer>();
    tf_listener_ = std::make_unique<tf2_ros::TransformListener>(*tf_buffer_);
  }
  Synchronizer::Options options;
  options.approximate = false;  // a depth image and its camera_info
  options.queue_size = settings_.queue_size;
  sync_ =
      std::make_unique<Synchronizer>(std::vector<bool>{true, true}, options);
  worker_ = std::thread([this] { workerLoop(); });

  // Publishers; the lock keeps connectCb from running before both exist.
  std::lock_guard<std::mutex> lock(connect_mutex_);
  it_ = std::make_unique<image_transport::ImageTransport>(nh);
  image_transport::SubscriberStatusCallback cb =
      [this](const image_transport::SingleSubscriberPublisher&) {
        connectCb();
      };
  pub_normals_ = it_->advertise("normals", 1, cb, cb);
  pub_confidence_ = it_->advertise("confidence", 1, cb, cb);
  if (settings_.register_to_rgb) {
    pub_depth_registered_ =
        it_->advertise("depth_registered/image_rect", 1, cb, cb);
  }
  const depth::DepthNormalSettings& n = settings_.normals;
  NODELET_INFO(
      "depth_to_normals: %s (window radius %d), noise coefficient %g /m; "
      "inputs %s %s%s%s",
      depth::toString(n.method).c_str(), n.window_radius, n.noise_coefficient,
      topic_names_[kDepth].c_str(), topic_names_[kCameraInfo].c_str(),
      settings_.register_to_rgb ? "; registered into the colour camera of "
                                : "",
      settings_.register_to_rgb ? topic_names_[kRgbCameraInfo].c_str() : "");
}

void DepthToNormalsNodelet::shutdownInputs() {
  sub_depth_.shutdown();
  sub_info_.shutdown();
  sub_rgb_info_.shutdown();
}

void DepthToNormalsNodelet::connectCb() {
  std::lock_guard<std::mutex> lock(connect_mutex_);
  const bool wanted = pub_normals_.getNumSubscribers() > 0 ||
                      pub_confidence_.getNumSubscribers() > 0 ||
                      pub_depth_registered_.getNumSubscribers() > 0;
  if (!wanted && subscribed_) {
    shutdownInputs();
    subscribed_ = false;
    std::lock_guard<std::mutex> sync_lock(sync_mutex_);
    sync_->reset();
    rgb_info_.reset();
    NODELET_DEBUG("no subscribers: inputs unsubscribed");
    return;
  }
  if (!wanted || subscribed_) return;
  image_transport::TransportHints hints("raw", ros::TransportHints(),
                                        getPrivateNodeHandle());
  sub_depth_ = it_->subscribe(
      "depth", settings_.queue_size,
      boost::function<void(const sensor_msgs::ImageConstPtr&)>(
          [this](const sensor_msgs::ImageConstPtr& msg) {
            onMessage(kDepth, msg->header, QueuedMessage{msg, nullptr});
          }),
      ros::VoidPtr(), hints);
  boost::function<void(const sensor_msgs::CameraInfoConstPtr&)> info_cb =
      [this](const sensor_msgs::CameraInfoConstPtr& msg) {
        onMessage(kCameraInfo, msg->header, QueuedMessage{nullptr, msg});
      };
  sub_info_ =
      getNodeHandle().subscribe("camera_info", settings_.queue_size, info_cb);
  if (settings_.register_to_rgb) {
    sub_rgb_info_ = getNodeHandle().subscribe(
        "rgb/camera_info", 1, &DepthToNormalsNodelet::onRgbInfo, this);
  }
  subscribed_ = true;
}

void DepthToNormalsNodelet::onRgbInfo(
    const sensor_msgs::CameraInfoConstPtr& msg) {
  try {
    precheckMessage(topic_names_[kRgbCameraInfo], msg->header, nullptr,
                    limits_);
  } catch (const std::exception& e) {
    ++frames_skipped_;
    logThrottled(std::string(e.what()) + "; message skipped");
    return;
  }
  std::lock_guard<std::mutex> lock(sync_mutex_);
  rgb_info_ = msg;  // the newest colour camera
}

void DepthToNormalsNodelet::onMessage(int topic, const std_msgs::Header& header,
                                      const QueuedMessage& message) {
  try {
    handleMessage(topic, header, message);
  } catch (const std::exception& e) {
    // Whatever a message does, the callback thread survives it.
    ++frames_skipped_;
    logThrottled(topic_names_[topic] + ": " + e.what() + "; message skipped");
  } catch (...) {
    ++frames_skipped_;
    logThrottled(topic_names_[topic] + ": unknown error; message skipped");
  }
}

void DepthToNormalsNodelet::handleMessage(int topic,
                                          const std_msgs::Header& header,
                                          const QueuedMessage& message) {
  const std::string& name = topic_names_[topic];
  try {
    precheckMessage(name, header, message.image.get(), limits_);
  } catch (const Error& e) {
    ++frames_skipped_;
    logThrottled(std::string(e.what()) + "; message skipped");
    return;
  }
  std::vector<Synchronizer::Set> sets;
  std::vector<Synchronizer::Discard> discards;
  sensor_msgs::CameraInfoConstPtr rgb_info;
  {
    std::lock_guard<std::mutex> lock(sync_mutex_);
    rgb_info = rgb_info_;
    const auto result = sync_->add(topic, header.stamp.toNSec(), message);
    if (result == Synchronizer::AddResult::kOutOfOrder) {
      std::ostringstream text;
      text << name << ": stamp " << header.stamp
           << " repeats the previous one on this topic (a duplicate); "
              "message skipped";
      ++frames_skipped_;
      logThrottled(text.str());
      return;
    }
    if (result == Synchronizer::AddResult::kTimeReset) {
      NODELET_INFO("%s: time went back: synchronizer reset", name.c_str());
    }
    sets = sync_->poll();
    discards = sync_->takeDiscards();
  }
  for (const auto& discard : discards) {
    if (discard.missing_topic != kCameraInfo) continue;
    std::ostringstream text;
    text << topic_names_[kCameraInfo] << ": no camera_info for the depth image "
         << "stamped " << ros::Time().fromNSec(discard.stamp_ns)
         << "; expected one with the depth's stamp; frame skipped";
    ++frames_skipped_;
    logThrottled(text.str());
  }
  // The checks of a pair come before the worker's newest-wins slot, so that
  // every bad pair is reported even when the worker is busy.
  std::optional<Work> newest;
  for (const Synchronizer::Set& set : sets) {
    try {
      Work work = checkedWork(set.messages[kDepth], set.messages[kCameraInfo]);
      addColourCamera(work, rgb_info);
      newest = std::move(work);
    } catch (const Error& e) {
      ++frames_skipped_;
      logThrottled(std::string(e.what()) + "; frame skipped");
    }
  }
  if (!newest) return;
  {
    std::lock_guard<std::mutex> lock(work_mutex_);
    pending_ = std::move(newest);  // newest wins
  }
  work_cv_.notify_one();
}

DepthToNormalsNodelet::Work DepthToNormalsNodelet::checkedWork(
    const QueuedMessage& depth, const QueuedMessage& info) const {
  const sensor_msgs::Image& msg = *depth.image;
  const sensor_msgs::CameraInfo& info_msg = *info.info;
  if (msg.encoding != "16UC1" && msg.encoding != "mono16" &&
      msg.encoding != "32FC1") {
    throw InputError(topic_names_[kDepth] + ": unsupported depth encoding '" +
                     msg.encoding +
                     "'; expected 16UC1 (millimetres) or 32FC1 (metres), "
                     "REP 118");
  }
  if (!info_msg.header.frame_id.empty() && !msg.header.frame_id.empty() &&
      info_msg.header.frame_id != msg.header.frame_id) {
    throw InputError(topic_names_[kCameraInfo] + ": frame_id '" +
                     info_msg.header.frame_id + "' differs from the depth's '" +
                     msg.header.frame_id + "'; expected the same frame");
  }
  Work work;
  work.depth = depth.image;
  work.K = intrinsicsFromCameraInfo(info_msg, topic_names_[kCameraInfo],
                                    static_cast<int>(msg.width),
                                    static_cast<int>(msg.height));
  if (settings_.register_to_rgb) {
    work.depth_distortion = LensDistortion::fromCameraInfo(
        info_msg.distortion_model, info_msg.D, topic_names_[kCameraInfo]);
  }
  return work;
}

void DepthToNormalsNodelet::workerLoop() {
  while (true) {
    Work work;
    {
      std::unique_lock<std::mutex> lock(work_mutex_);
      work_cv_.wait(lock, [this] { return stop_ || pending_.has_value(); });
      if (stop_) return;
      work = std::move(*pending_);
      pending_.reset();
    }
    try {
      process(work);
    } catch (const std::exception& e) {
      ++frames_skipped_;
      logThrottled(std::string(e.what()) + "; frame skipped");
    } catch (...) {
      ++frames_skipped_;
      logThrottled(topic_names_[kDepth] + ": unknown error; frame skipped");
    }
  }
}

void DepthToNormalsNodelet::addColourCamera(
    Work& work, const sensor_msgs::CameraInfoConstPtr& rgb_info) const {
  if (!settings_.register_to_rgb) return;
  const std::string& name = topic_names_[kRgbCameraInfo];
  if (!rgb_info) {
    throw InputError(name +
                     ": no colour camera_info received yet; expected one "
                     "before a depth image can be registered");
  }
  const sensor_msgs::CameraInfo& info = *rgb_info;
  if (info.width == 0 || info.height == 0) {
    throw InputError(name + ": size " + std::to_string(info.width) + "x" +
                     std::to_string(info.height) +
                     "; expected the colour image's size");
  }
  if (!limits_.allows(info.width, info.height)) {
    const std::uint64_t pixels =
        static_cast<std::uint64_t>(info.width) * info.height;
    throw InputError(name + ": " + std::to_string(pixels) +
                     " pixels; expected at most max_pixels = " +
                     std::to_string(limits_.max_pixels));
  }
  const int width = static_cast<int>(info.width);
  const int height = static_cast<int>(info.height);
  const CameraIntrinsics K_rgb =
      intrinsicsFromCameraInfo(info, name, width, height);
  const std::string& depth_frame = work.depth->header.frame_id;
  if (info.header.frame_id == depth_frame && info.width == work.depth->width &&
      info.height == work.depth->height) {
    return;  // already aligned: the depth lives in the colour image's pixels
  }
  if (info.header.frame_id.empty() || depth_frame.empty()) {
    throw InputError(name + ": frame_id '" + info.header.frame_id +
                     "', depth frame_id '" + depth_frame +
                     "'; expected both optical frames for the registration");
  }
  work.rgb_info = rgb_info;
  work.rgb = depth::TargetCamera{
      K_rgb, width, height,
      LensDistortion::fromCameraInfo(info.distortion_model, info.D, name)};
}

depth::RigidTransform DepthToNormalsNodelet::lookupRgbFromDepth(
    const Work& work) const {
  const std::string& rgb_frame = work.rgb_info->header.frame_id;
  const std::string& depth_frame = work.depth->header.frame_id;
  if (rgb_frame == depth_frame) return depth::RigidTransform();
  try {
    const geometry_msgs::TransformStamped T = tf_buffer_->lookupTransform(
        rgb_frame, depth_frame, work.depth->header.stamp,
        ros::Duration(settings_.tf_timeout));
    return rigidTransformOf(T.transform);
  } catch (const tf2::TransformException& e) {
    std::ostringstream text;
    text << "tf: no transform to the colour frame '" << rgb_frame
         << "' from the depth frame '" << depth_frame
         << "' at the depth's stamp " << work.depth->header.stamp
         << " within tf_timeout " << settings_.tf_timeout << " s (" << e.what()
         << ")";
    throw InputError(text.str());
  }
}

void DepthToNormalsNodelet::process(const Work& work) {
  const sensor_msgs::Image& msg = *work.depth;
  const CameraIntrinsics& K = work.K;
  depthFromMessage(msg, topic_names_[kDepth], depth_m_);
  const bool want_normals = pub_normals_.getNumSubscribers() > 0;
  const bool want_confidence = pub_confidence_.getNumSubscribers() > 0;
  const bool want_depth = pub_depth_registered_.getNumSubscribers() > 0;
  if (!want_normals && !want_confidence && !want_depth) return;
  // The transform first: without it the frame is skipped before any work.
  const depth::RigidTransform T_rgb_depth =
      work.rgb_info ? lookupRgbFromDepth(work) : depth::RigidTransform();
  try {
    estimator_.compute(depth_m_, K, normals_,
                       want_confidence ? &confidence_ : nullptr);
  } catch (const Error& e) {
    throw InputError(topic_names_[kDepth] + ": " + e.what());
  }
  if (work.rgb_info) {
    publishRegistered(work, T_rgb_depth, want_normals, want_confidence,
                      want_depth);
    return;
  }
  if (want_normals) {
    auto out = boost::make_shared<sensor_msgs::Image>();
    normalsToMessage(normals_, msg.header, *out);
    pub_normals_.publish(out);
  }
  if (want_confidence) {
    auto out = boost::make_shared<sensor_msgs::Image>();
    scalarMapToMessage(confidence_, msg.header, *out);
    pub_confidence_.publish(out);
  }
  if (want_depth) {  // aligned: the depth is the registered depth
    auto out = boost::make_shared<sensor_msgs::Image>();
    scalarMapToMessage(depth_m_, msg.header, *out);
    pub_depth_registered_.publish(out);
  }
}

void DepthToNormalsNodelet::publishRegistered(
    const Work& work, const depth::RigidTransform& T_rgb_depth,
    bool want_normals, bool want_confidence, bool want_depth) {
  try {
    const depth::TargetCamera depth_camera{
        work.K, depth_m_.width(), depth_m_.height(), work.depth_distortion};
    registration_.registerNormals(
        depth_m_, normals_, want_confidence ? &confidence_ : nullptr,
        depth_camera, work.rgb, T_rgb_depth, normals_rgb_,
        want_confidence ? &confidence_rgb_ : nullptr,
        want_depth ? &depth_rgb_ : nullptr);
  } catch (const Error& e) {
    throw InputError(topic_names_[kDepth] + ": registration: " + e.what());
  }
  // The colour camera's frame and pixels, the depth's time.
  std_msgs::Header header = work.depth->header;
  header.frame_id = work.rgb_info->header.frame_id;
  if (want_normals) {
    auto out = boost::make_shared<sensor_msgs::Image>();
    normalsToMessage(normals_rgb_, header, *out);
    pub_normals_.publish(out);
  }
  if (want_confidence) {
    auto out = boost::make_shared<sensor_msgs::Image>();
    scalarMapToMessage(confidence_rgb_, header, *out);
    pub_confidence_.publish(out);
  }
  if (want_depth) {
    auto out = boost::make_shared<sensor_msgs::Image>();
    scalarMapToMessage(depth_rgb_, header, *out);
    pub_depth_registered_.publish(out);
  }
}

void DepthToNormalsNodelet::logThrottled(const std::string& text) {
  if (!log_throttle_.admit(text)) return;
  NODELET_ERROR("%s", text.c_str());
}

}  // namespace node
}  // namespace normal_fusion

PLUGINLIB_EXPORT_CLASS(normal_fusion::node::DepthToNormalsNodelet,
                       nodelet::Nodelet)
