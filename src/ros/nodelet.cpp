#include "normal_fusion/ros/nodelet.h"

#include <dynamic_reconfigure/Config.h>
#include <dynamic_reconfigure/ConfigDescription.h>
#include <pluginlib/class_list_macros.hpp>

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <sstream>
#include <type_traits>

#include "normal_fusion/errors.h"
#include "normal_fusion/ros/conversions.h"

namespace normal_fusion {
namespace node {
namespace {

/// Every known parameter present under the private namespace, typed as the
/// parameter server holds it, plus any other scalar there (reported as
/// unknown by settingsFromParameters).
ParameterMap readParameterServer(const ros::NodeHandle& pnh,
                                 std::vector<std::string>* warnings) {
  ParameterMap params;
  std::vector<std::string> names;
  pnh.getParamNames(names);
  const std::string prefix = pnh.getNamespace() + "/";
  // Parameters that belong to other parts of ROS, not to the solver.
  static const char* const kForeign[] = {"image_transport",
                                         "diagnostic_period"};
  for (const std::string& full : names) {
    if (full.compare(0, prefix.size(), prefix) != 0) continue;
    const std::string name = full.substr(prefix.size());
    if (name.find('/') != std::string::npos) continue;  // nested namespaces
    if (std::find(std::begin(kForeign), std::end(kForeign), name) !=
        std::end(kForeign)) {
      continue;
    }
    XmlRpc::XmlRpcValue value;
    if (!pnh.getParam(name, value)) continue;
    switch (value.getType()) {
      case XmlRpc::XmlRpcValue::TypeBoolean:
        params[name] = static_cast<bool>(value);
        break;
      case XmlRpc::XmlRpcValue::TypeInt:
        params[name] = static_cast<int>(value);
        break;
      case XmlRpc::XmlRpcValue::TypeDouble:
        params[name] = static_cast<double>(value);
        break;
      case XmlRpc::XmlRpcValue::TypeString:
        params[name] = static_cast<std::string>(value);
        break;
      default:
        warnings->push_back("parameter '" + name +
                            "' is not a scalar (ignored)");
    }
  }
  return params;
}

void setParameter(const ros::NodeHandle& pnh, const std::string& name,
                  const ParameterValue& value) {
  if (const bool* b = std::get_if<bool>(&value)) {
    pnh.setParam(name, *b);
  } else if (const int* n = std::get_if<int>(&value)) {
    pnh.setParam(name, *n);
  } else if (const double* d = std::get_if<double>(&value)) {
    pnh.setParam(name, *d);
  } else {
    pnh.setParam(name, std::get<std::string>(value));
  }
}

/// dynamic_reconfigure's message <-> the parameter map.
void mergeConfigMessage(const dynamic_reconfigure::Config& msg,
                        ParameterMap* params) {
  for (const auto& p : msg.bools)
    (*params)[p.name] = static_cast<bool>(p.value);
  for (const auto& p : msg.ints) (*params)[p.name] = static_cast<int>(p.value);
  for (const auto& p : msg.doubles) (*params)[p.name] = p.value;
  for (const auto& p : msg.strs) (*params)[p.name] = p.value;
}

void writeConfigMessage(const ParameterMap& params,
                        dynamic_reconfigure::Config* msg) {
  for (auto& p : msg->bools) {
    auto it = params.find(p.name);
    if (it != params.end() && std::holds_alternative<bool>(it->second)) {
      p.value = std::get<bool>(it->second);
    }
  }
  for (auto& p : msg->ints) {
    auto it = params.find(p.name);
    if (it != params.end() && std::holds_alternative<int>(it->second)) {
      p.value = std::get<int>(it->second);
    }
  }
  for (auto& p : msg->doubles) {
    auto it = params.find(p.name);
    if (it != params.end() && std::holds_alternative<double>(it->second)) {
      p.value = std::get<double>(it->second);
    }
  }
  for (auto& p : msg->strs) {
    auto it = params.find(p.name);
    if (it != params.end() && std::holds_alternative<std::string>(it->second)) {
      p.value = std::get<std::string>(it->second);
    }
  }
}

}  // namespace

NormalFusionNodelet::~NormalFusionNodelet() {
  {
    std::lock_guard<std::mutex> lock(watch_mutex_);
    watch_stop_ = true;
  }
  watch_cv_.notify_all();
  if (shutdown_watch_.joinable()) shutdown_watch_.join();
  // Unsubscribed first: shutdown() waits for a callback under way, so that
  // none runs on the members destroyed after this body.
  timer_.stop();
  {
    std::lock_guard<std::mutex> lock(connect_mutex_);
    shutdownInputs();
  }
  {
    std::lock_guard<std::mutex> lock(work_mutex_);
    stop_ = true;
  }
  // A solve under way stops within an inner iteration block, so that the
  // process ends before roslaunch escalates to SIGTERM and SIGKILL.
  if (pipeline_) pipeline_->requestCancel();
  work_cv_.notify_all();
  if (worker_.joinable()) worker_.join();
}

void NormalFusionNodelet::onInit() {
  ros::NodeHandle& nh = getNodeHandle();
  ros::NodeHandle& pnh = getPrivateNodeHandle();

  // Parameters: read, corrected in one function, written back so that
  // dynamic_reconfigure starts from the corrected values and the library's
  // defaults.
  std::vector<std::string> warnings;
  ParameterMap params = readParameterServer(pnh, &warnings);
  settings_ = settingsFromParameters(params, &warnings);
  for (const std::string& w : warnings) NODELET_WARN("%s", w.c_str());
  const ParameterMap known = parametersFromSettings(settings_);
  for (const auto& entry : known) {
    setParameter(pnh, entry.first, params.at(entry.first));
  }
  static_params_ = known;
  num_inputs_ = settings_.num_inputs;
  queue_size_ = settings_.queue_size;
  limits_.max_pixels = static_cast<std::uint64_t>(settings_.max_pixels);
  rate_min_ = settings_.expected_rate_min;
  rate_max_ = settings_.expected_rate_max;

  roles_ = topicRoles(settings_);
  for (TopicRole& role : roles_) role.name = nh.resolveName(role.name);
  TopicNames names = topicNamesOf(roles_, settings_.num_inputs);
  for (std::string& name : names.confidence) name = nh.resolveName(name);
  const std::vector<bool> required = requiredTopics(roles_, settings_);
  pipeline_ = std::make_unique<FusionPipeline>(settings_, names);
  sync_ = std::make_unique<Synchronizer>(required, syncOptions(settings_));
  last_arrival_.assign(roles_.size(), ros::WallTime());
  tf_buffer_ = std::make_shared<tf2_ros::Buffer>();

  // dynamic_reconfigure: its defaults are the library's.
  reconfigure_server_ = std::make_unique<dynamic_reconfigure::Server<Config>>(
      reconfigure_mutex_, pnh);
  {
    dynamic_reconfigure::Config msg;
    Config defaults = Config::__getDefault__();
    defaults.__toMessage__(msg);
    writeConfigMessage(parametersFromSettings(NodeSettings()), &msg);
    defaults.__fromMessage__(msg);
    reconfigure_server_->setConfigDefault(defaults);
  }
  reconfigure_server_->setCallback(
      [this](Config& config, uint32_t level) { configCb(config, level); });
  publishParameterRanges();

  worker_ = std::thread([this] { workerLoop(); });
  shutdown_watch_ = std::thread([this] { shutdownWatchLoop(); });

  setupDiagnostics();

  // Publishers; the lock keeps connectCb from running before all exist.
  std::lock_guard<std::mutex> lock(connect_mutex_);
  it_ = std::make_unique<image_transport::ImageTransport>(nh);
  image_transport::SubscriberStatusCallback image_cb =
      [this](const image_transport::SingleSubscriberPublisher&) {
        connectCb();
      };
  ros::SubscriberStatusCallback stats_cb =
      [this](const ros::SingleSubscriberPublisher&) { connectCb(); };
  pub_fused_ = it_->advertise("fused_normals", 1, image_cb, image_cb);
  pub_vis_ = it_->advertise("fused_normals_vis", 1, image_cb, image_cb);
  pub_stats_ = nh.advertise<normal_fusion::FusionStats>("fusion_stats", 10,
                                                        stats_cb, stats_cb);
  std::string inputs;
  for (const TopicRole& role : roles_) inputs += " " + role.name;
  // How the solver's threads wait (set before the process starts, e.g. by
  // the launch files' omp_wait_policy).
  const char* wait_policy = std::getenv("OMP_WAIT_POLICY");
  NODELET_INFO(
      "normal_fusion: %d input(s), %s sync; inputs:%s; OMP_WAIT_POLICY %s",
      settings_.num_inputs,
      settings_.approximate_sync ? "approximate" : "exact", inputs.c_str(),
      wait_policy != nullptr && *wait_policy != '\0' ? wait_policy : "unset");
}

void NormalFusionNodelet::publishParameterRanges() {
  // The .cfg declares no bounds, since dynamic_reconfigure would clamp to
  // them silently before the node can refuse a value with a warning; the
  // clients (rqt_reconfigure) get the node's own ranges in the description,
  // which replaces the server's on the same latched topic.
  dynamic_reconfigure::ConfigDescription description =
      Config::__getDescriptionMessage__();
  std::map<std::string, ParameterRange> ranges;
  for (const ParameterRange& r : numericParameterRanges()) ranges[r.name] = r;
  auto bound = [&](auto& values, bool is_max) {
    for (auto& p : values) {
      auto it = ranges.find(p.name);
      if (it == ranges.end()) continue;
      // An open lower bound of 0 shows as 0.
      const double v = is_max ? it->second.max
                              : (it->second.min > 0.0 && it->second.min < 1e-300
                                     ? 0.0
                                     : it->second.min);
      p.value = static_cast<std::decay_t<decltype(p.value)>>(v);
    }
  };
  bound(description.min.doubles, false);
  bound(description.max.doubles, true);
  bound(description.min.ints, false);
  bound(description.max.ints, true);
  pub_description_ =
      getPrivateNodeHandle().advertise<dynamic_reconfigure::ConfigDescription>(
          "parameter_descriptions", 1, true);
  pub_description_.publish(description);
}

NormalFusionNodelet::Synchronizer::Options NormalFusionNodelet::syncOptions(
    const NodeSettings& settings) const {
  Synchronizer::Options options;
  options.approximate = settings.approximate_sync;
  options.queue_size = settings.queue_size;
  options.max_interval_ns =
      static_cast<std::int64_t>(settings.max_interval * 1e9 + 0.5);
  return options;
}

void NormalFusionNodelet::shutdownInputs() {
  sub_image_.shutdown();
  for (ros::Subscriber& sub : subs_) sub.shutdown();
  subs_.clear();
}

void NormalFusionNodelet::connectCb() {
  std::lock_guard<std::mutex> lock(connect_mutex_);
  const bool wanted = pub_fused_.getNumSubscribers() > 0 ||
                      pub_vis_.getNumSubscribers() > 0 ||
                      pub_stats_.getNumSubscribers() > 0;
  if (!wanted && subscribed_) {
    shutdownInputs();
    subscribed_ = false;
    updateTfListener();
    std::lock_guard<std::mutex> sync_lock(sync_mutex_);
    sync_->reset();
    NODELET_DEBUG("no subscribers: inputs unsubscribed");
    return;
  }
  if (!wanted || subscribed_) return;

  ros::NodeHandle& nh = getNodeHandle();
  const int queue = queue_size_;
  {
    std::lock_guard<std::mutex> sync_lock(sync_mutex_);
    subscribed_since_ = ros::WallTime::now();
    last_set_time_ = ros::WallTime();
  }
  image_transport::TransportHints hints("raw", ros::TransportHints(),
                                        getPrivateNodeHandle());
  for (std::size_t j = 0; j < roles_.size(); ++j) {
    const int topic = static_cast<int>(j);
    const TopicRole& role = roles_[j];
    if (role.kind == TopicRole::kImage) {
      sub_image_ = it_->subscribe(
          role.name, queue,
          boost::function<void(const sensor_msgs::ImageConstPtr&)>(
              [this, topic](const sensor_msgs::ImageConstPtr& msg) {
                onMessage(topic, msg->header, QueuedMessage{msg, nullptr});
              }),
          ros::VoidPtr(), hints);
    } else if (role.kind == TopicRole::kCameraInfo) {
      boost::function<void(const sensor_msgs::CameraInfoConstPtr&)> cb =
          [this, topic](const sensor_msgs::CameraInfoConstPtr& msg) {
            onMessage(topic, msg->header, QueuedMessage{nullptr, msg});
          };
      subs_.push_back(nh.subscribe(role.name, queue, cb));
    } else {
      boost::function<void(const sensor_msgs::ImageConstPtr&)> cb =
          [this, topic](const sensor_msgs::ImageConstPtr& msg) {
            onMessage(topic, msg->header, QueuedMessage{msg, nullptr});
          };
      subs_.push_back(nh.subscribe(role.name, queue, cb));
    }
  }
  subscribed_ = true;
  updateTfListener();
  NODELET_DEBUG("subscribed to %zu input topics", roles_.size());
}

void NormalFusionNodelet::updateTfListener() {
  // Called with connect_mutex_ held: a listener only while subscribed and
  // while a fixed frame asks for rotation compensation.
  std::string fixed_frame;
  {
    std::lock_guard<std::mutex> lock(settings_mutex_);
    fixed_frame = settings_.fixed_frame;
  }
  const bool wanted = subscribed_ && !fixed_frame.empty();
  if (wanted && !tf_listener_) {
    tf_listener_ = std::make_unique<tf2_ros::TransformListener>(
        *tf_buffer_, getNodeHandle());
  } else if (!wanted && tf_listener_) {
    tf_listener_.reset();
  }
}

void NormalFusionNodelet::onMessage(int topic, const std_msgs::Header& header,
                                    const QueuedMessage& message) {
  const TopicRole& role = roles_[topic];
  try {
    handleMessage(topic, header, message);
  } catch (const std::exception& e) {
    // Whatever a message does, the callback thread (and with it the node or
    // the nodelet manager) survives it.
    ++frames_skipped_;
    const std::string text = role.name + ": " + e.what() + "; message skipped";
    recordError(text);
    logThrottled(true, text);
  }
}

void NormalFusionNodelet::handleMessage(int topic,
                                        const std_msgs::Header& header,
                                        const QueuedMessage& message) {
  const TopicRole& role = roles_[topic];
  try {
    precheckMessage(role.name, header, message.image.get(), limits_);
  } catch (const Error& e) {
    ++frames_skipped_;
    recordError(e.what());
    logThrottled(true, std::string(e.what()) + "; message skipped");
    return;
  }
  if (role.kind == TopicRole::kCameraInfo && message.info) {
    // The first camera_info gives the size before the first set: the worker
    // reserves the stream's buffers meanwhile.
    std::lock_guard<std::mutex> lock(work_mutex_);
    if (!reserve_asked_) {
      reserve_asked_ = true;
      reserve_size_.emplace(static_cast<int>(message.info->width),
                            static_cast<int>(message.info->height));
      work_cv_.notify_one();
    }
  }
  std::vector<Synchronizer::Set> sets;
  std::vector<Synchronizer::Discard> discards;
  {
    std::lock_guard<std::mutex> lock(sync_mutex_);
    last_arrival_[topic] = ros::WallTime::now();
    const std::int64_t newest = sync_->newestStamp(topic);
    const auto result = sync_->add(topic, header.stamp.toNSec(), message);
    if (result == Synchronizer::AddResult::kOutOfOrder) {
      std::ostringstream text;
      text << role.name << ": stamp " << header.stamp
           << " repeats the previous one on this topic (a duplicate); "
              "message skipped";
      ++frames_skipped_;
      recordError(text.str());
      logThrottled(true, text.str());
      return;
    }
    if (result == Synchronizer::AddResult::kTimeReset) {
      NODELET_INFO(
          "%s: time went back by %.3f s (a bag loop or a restarted player): "
          "synchronizer and stream reset",
          role.name.c_str(),
          1e-9 * static_cast<double>(newest - static_cast<std::int64_t>(
                                                  header.stamp.toNSec())));
      std::lock_guard<std::mutex> work_lock(work_mutex_);
      pending_.reset();  // a set of the old timeline
      stream_reset_ = true;
    }
    sets = sync_->poll();
    if (!sets.empty()) last_set_time_ = ros::WallTime::now();
    discards = sync_->takeDiscards();
  }
  // A camera_info must come with every image: its absence is an error. Other
  // inputs may come at a lower rate, so images without them are expected.
  for (const auto& discard : discards) {
    if (discard.missing_topic < 0 ||
        roles_[discard.missing_topic].kind != TopicRole::kCameraInfo) {
      continue;
    }
    std::ostringstream text;
    text << roles_[discard.missing_topic].name
         << ": no camera_info for the image stamped "
         << ros::Time().fromNSec(discard.stamp_ns) << " (nearest: ";
    if (discard.nearest_ns == Synchronizer::kNone) {
      text << "none queued";
    } else {
      text << ros::Time().fromNSec(discard.nearest_ns);
    }
    text << "); expected one with the image's stamp; frame skipped";
    ++frames_skipped_;
    recordError(text.str());
    logThrottled(true, text.str());
  }
  if (sets.empty()) return;
  // Newest wins: only the last set is handed over; a set still waiting for
  // the busy worker is replaced and counted as dropped.
  InputSet set = inputSetFrom(roles_, sets.back().messages, sets.back().present,
                              num_inputs_);
  {
    std::lock_guard<std::mutex> lock(work_mutex_);
    std::uint64_t dropped = sets.size() - 1;
    if (pending_) ++dropped;
    frames_dropped_ += dropped;
    pending_ = std::move(set);
    pending_formed_ = ros::WallTime::now();
  }
  work_cv_.notify_one();
}

void NormalFusionNodelet::configCb(Config& config, uint32_t /*level*/) {
  dynamic_reconfigure::Config msg;
  config.__toMessage__(msg);
  ParameterMap params = static_params_;
  mergeConfigMessage(msg, &params);
  std::vector<std::string> warnings;
  NodeSettings current;
  {
    std::lock_guard<std::mutex> lock(settings_mutex_);
    current = settings_;
  }
  // A refused value keeps the value in use, and every other setting stays.
  NodeSettings settings = settingsFromParameters(params, &warnings, current);
  // The start-time parameters keep their start values.
  {
    std::lock_guard<std::mutex> lock(settings_mutex_);
    settings.num_inputs = settings_.num_inputs;
    settings.approximate_sync = settings_.approximate_sync;
    settings.queue_size = settings_.queue_size;
    settings.use_depth = settings_.use_depth;
    for (int i = 0; i < kMaxInputs; ++i) {
      settings.inputs[i].use_confidence = settings_.inputs[i].use_confidence;
      settings.inputs[i].optional = settings_.inputs[i].optional;
    }
  }
  for (const std::string& w : warnings) NODELET_WARN("%s", w.c_str());
  writeConfigMessage(params, &msg);
  config.__fromMessage__(msg);
  {
    std::lock_guard<std::mutex> lock(settings_mutex_);
    settings_ = settings;
    settings_changed_ = true;
  }
  if (sync_) {
    std::lock_guard<std::mutex> lock(sync_mutex_);
    sync_->setOptions(syncOptions(settings));
  }
  if (it_) {  // after onInit: the subscriptions may need a tf listener now
    std::lock_guard<std::mutex> lock(connect_mutex_);
    updateTfListener();
  }
}

CameraMotionLookup NormalFusionNodelet::applyNewSettings() {
  std::string fixed_frame;
  double tf_timeout = 0.0;
  {
    std::lock_guard<std::mutex> lock(settings_mutex_);
    if (settings_changed_) {
      try {
        pipeline_->setSettings(settings_);
      } catch (const std::exception& e) {
        recordError(e.what());
        logThrottled(true, std::string("settings not applied: ") + e.what());
      }
      settings_changed_ = false;
    }
    fixed_frame = settings_.fixed_frame;
    tf_timeout = settings_.tf_timeout;
  }
  if (fixed_frame.empty()) return CameraMotionLookup();
  // The full motion: without a depth the stream uses its rotation alone.
  const MotionLookup lookup = motionLookupFromBuffer(*tf_buffer_, fixed_frame);
  return MotionLookup([this, lookup, fixed_frame, tf_timeout](
                          const std::string& frame, const ros::Time& previous,
                          const ros::Time& current, Pose* T_cur_prev,
                          std::string* reason) {
    // Wait up to tf_timeout for both ends of the transform.
    tf_buffer_->canTransform(frame, current, frame, previous, fixed_frame,
                             ros::Duration(tf_timeout));
    return lookup(frame, previous, current, T_cur_prev, reason);
  });
}

void NormalFusionNodelet::shutdownWatchLoop() {
  // roscpp offers no shutdown callback; a 10 ms poll costs nothing and keeps
  // the delay well below the time roslaunch gives a node to end.
  std::unique_lock<std::mutex> lock(watch_mutex_);
  while (!watch_cv_.wait_for(lock, std::chrono::milliseconds(10),
                             [this] { return watch_stop_; })) {
    if (ros::isShuttingDown() || !ros::ok()) {
      {
        std::lock_guard<std::mutex> work_lock(work_mutex_);
        stop_ = true;
      }
      work_cv_.notify_all();
      pipeline_->requestCancel();
      return;
    }
  }
}

void NormalFusionNodelet::workerLoop() {
  PipelineOutput output;
  while (true) {
    InputSet set;
    ros::WallTime formed;
    bool reset = false;
    {
      std::unique_lock<std::mutex> lock(work_mutex_);
      work_cv_.wait(lock, [this] {
        return stop_ || pending_.has_value() || reserve_size_.has_value();
      });
      if (stop_) return;
      // Before the first set only: a set already waiting is the first frame.
      std::optional<std::pair<int, int>> reserve;
      reserve.swap(reserve_size_);
      if (!pending_) {
        lock.unlock();
        if (reserve && frames_processed_ == 0) reserveBuffers(*reserve);
        continue;
      }
      set = std::move(*pending_);
      pending_.reset();
      formed = pending_formed_;
      reset = stream_reset_;
      stream_reset_ = false;
    }
    const ros::WallTime started = ros::WallTime::now();
    if (reset) pipeline_->resetWarmStart();
    const CameraMotionLookup motion = applyNewSettings();
    try {
      pipeline_->process(set, motion, pub_vis_.getNumSubscribers() > 0,
                         &output);
    } catch (const std::bad_alloc&) {
      pipeline_->resetWarmStart();
      ++frames_skipped_;
      std::ostringstream text;
      text << roles_[0].name << ": out of memory for a "
           << (set.image ? set.image->width : 0u) << "x"
           << (set.image ? set.image->height : 0u)
           << " frame (std::bad_alloc); frame skipped (max_pixels bounds the "
              "frame size)";
      recordError(text.str());
      logThrottled(true, text.str());
      continue;
    } catch (const Cancelled&) {
      return;  // shutting down
    } catch (const std::exception& e) {
      ++frames_skipped_;
      recordError(e.what());
      logThrottled(true, std::string(e.what()) + "; frame skipped");
      continue;
    }
    if (!output.warning.empty()) logThrottled(false, output.warning);
    if (!output.error.empty()) {
      recordError(output.error);
      logThrottled(true, output.error);
    }
    if (!output.note.empty()) NODELET_INFO("%s", output.note.c_str());
    ++frames_processed_;
    const ros::WallTime done = ros::WallTime::now();
    const double latency = (done - formed).toSec();
    output.stats->queue_time = (started - formed).toSec();
    output.stats->latency = latency;
    output.stats->frames_dropped = frames_dropped_;
    output.stats->frames_skipped = frames_skipped_;
    {
      std::lock_guard<std::mutex> lock(stats_mutex_);
      if (set.image && !set.image->header.frame_id.empty()) {
        camera_frame_ = set.image->header.frame_id;
      }
      recent_outputs_.emplace_back(done, latency);
      while (recent_outputs_.size() > 100) recent_outputs_.pop_front();
      last_solve_time_ = output.stats->solve_time;
      last_output_time_ = done;
    }
    publishOutputs(output);
  }
}

void NormalFusionNodelet::reserveBuffers(const std::pair<int, int>& size) {
  applyNewSettings();
  try {
    double seconds = 0.0;
    if (pipeline_->reserveFor(size.first, size.second, &seconds)) {
      NODELET_INFO(
          "buffers of the stream reserved for %dx%d sets (from the first "
          "camera_info) in %.0f ms",
          size.first, size.second, 1e3 * seconds);
    }
  } catch (const Cancelled&) {
    // shutting down
  } catch (const std::exception& e) {
    // Not needed for the sets: they size what they use themselves.
    pipeline_->resetWarmStart();
    NODELET_WARN(
        "reserving the stream's buffers for %dx%d sets failed (%s); "
        "the first sets allocate them",
        size.first, size.second, e.what());
  }
}

void NormalFusionNodelet::publishOutputs(const PipelineOutput& output) {
  if (pub_fused_.getNumSubscribers() > 0) pub_fused_.publish(output.fused);
  if (output.fused_vis) pub_vis_.publish(output.fused_vis);
  pub_stats_.publish(output.stats);
  output_rate_->tick();
}

void NormalFusionNodelet::recordError(const std::string& text) {
  std::lock_guard<std::mutex> lock(stats_mutex_);
  last_error_ = text;
  last_error_time_ = ros::WallTime::now();
  recent_errors_.push_back(last_error_time_);
  while (recent_errors_.size() > 100) recent_errors_.pop_front();
}

void NormalFusionNodelet::logThrottled(bool is_error, const std::string& text) {
  if (!log_throttle_.admit(text)) return;
  if (is_error) {
    NODELET_ERROR("%s", text.c_str());
  } else {
    NODELET_WARN("%s", text.c_str());
  }
}

}  // namespace node
}  // namespace normal_fusion

PLUGINLIB_EXPORT_CLASS(normal_fusion::node::NormalFusionNodelet,
                       nodelet::Nodelet)
