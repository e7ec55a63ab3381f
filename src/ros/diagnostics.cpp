// The fusion nodelet's diagnostics: its status on /diagnostics, the output
// rate, and the warning when no synchronized set forms.
#include <algorithm>
#include <sstream>

#include "normal_fusion/ros/nodelet.h"

namespace normal_fusion {
namespace node {
namespace {

// Diagnostics: this many errors within the window is ERROR, fewer WARN.
constexpr double kErrorWindowS = 5.0;
constexpr int kRepeatedErrors = 3;

}  // namespace

void NormalFusionNodelet::setupDiagnostics() {
  ros::NodeHandle& nh = getNodeHandle();
  ros::NodeHandle& pnh = getPrivateNodeHandle();
  updater_ = std::make_unique<diagnostic_updater::Updater>(nh, pnh, getName());
  // The node's name until the first image names its camera frame.
  updater_->setHardwareID(getName());
  updater_->add("normal_fusion",
                [this](diagnostic_updater::DiagnosticStatusWrapper& status) {
                  diagnose(status);
                });
  output_rate_ = std::make_unique<diagnostic_updater::FrequencyStatus>(
      diagnostic_updater::FrequencyStatusParam(&rate_min_, &rate_max_, 0.1, 5),
      "fused_normals output rate");
  updater_->add(*output_rate_);
  timer_ = nh.createWallTimer(
      ros::WallDuration(1.0), [this](const ros::WallTimerEvent&) {
        {
          std::lock_guard<std::mutex> lock(stats_mutex_);
          if (!camera_frame_.empty()) {
            updater_->setHardwareID(camera_frame_);
          }
        }
        updater_->update();
        checkMissingInputs();
      });
}

void NormalFusionNodelet::checkMissingInputs() {
  double timeout, max_interval;
  bool approximate;
  {
    std::lock_guard<std::mutex> lock(settings_mutex_);
    timeout = settings_.missing_input_timeout;
    max_interval = settings_.max_interval;
    approximate = settings_.approximate_sync;
  }
  if (timeout <= 0.0) return;
  std::ostringstream text;
  {
    std::lock_guard<std::mutex> lock(connect_mutex_);
    if (!subscribed_) return;
  }
  const ros::WallTime now = ros::WallTime::now();
  {
    std::lock_guard<std::mutex> lock(sync_mutex_);
    const ros::WallTime since = std::max(last_set_time_, subscribed_since_);
    if ((now - since).toSec() < timeout) return;
    std::string missing;
    for (std::size_t j = 0; j < roles_.size(); ++j) {
      if (last_arrival_[j].isZero() || last_arrival_[j] < subscribed_since_) {
        missing += " " + roles_[j].name + " (nothing received)";
      } else if ((now - last_arrival_[j]).toSec() > timeout) {
        std::ostringstream age;
        age << " " << roles_[j].name << " (last message "
            << (now - last_arrival_[j]).toSec() << " s ago)";
        missing += age.str();
      }
    }
    text << "no synchronized set for " << (now - since).toSec() << " s; ";
    if (!missing.empty()) {
      text << "missing inputs:" << missing;
    } else {
      text << "every input arrives but the stamps do not match ("
           << (approximate ? "approximate" : "exact") << " sync, max_interval "
           << max_interval << " s); newest stamps:";
      for (std::size_t j = 0; j < roles_.size(); ++j) {
        const std::int64_t s = sync_->newestStamp(static_cast<int>(j));
        text << " " << roles_[j].name << " ";
        if (s == Synchronizer::kNone) {
          text << "none";
        } else {
          text << ros::Time().fromNSec(static_cast<std::uint64_t>(s));
        }
      }
    }
  }
  if (!log_throttle_.admitKey("missing", timeout)) return;
  NODELET_WARN("%s", text.str().c_str());
}

void NormalFusionNodelet::diagnose(
    diagnostic_updater::DiagnosticStatusWrapper& status) {
  // The other locks first: stats_mutex_ is taken inside sync_mutex_ elsewhere.
  bool subscribed = false;
  ros::WallTime since;
  {
    std::lock_guard<std::mutex> connect_lock(connect_mutex_);
    subscribed = subscribed_;
  }
  {
    std::lock_guard<std::mutex> sync_lock(sync_mutex_);
    since = subscribed_since_;
  }
  double stale_after = 5.0;
  {
    std::lock_guard<std::mutex> settings_lock(settings_mutex_);
    if (settings_.missing_input_timeout > 0.0) {
      stale_after = settings_.missing_input_timeout;
    }
  }
  std::lock_guard<std::mutex> lock(stats_mutex_);
  const ros::WallTime now = ros::WallTime::now();
  int recent = 0;
  double latency_sum = 0.0;
  for (const auto& entry : recent_outputs_) {
    if ((now - entry.first).toSec() <= 5.0) {
      ++recent;
      latency_sum += entry.second;
    }
  }
  const double rate = recent / 5.0;
  const double latency = recent > 0 ? latency_sum / recent : 0.0;
  int errors = 0;
  for (const ros::WallTime& t : recent_errors_) {
    if ((now - t).toSec() < kErrorWindowS) ++errors;
  }
  const ros::WallTime last = std::max(last_output_time_, since);
  const double quiet = subscribed ? (now - last).toSec() : 0.0;
  if (errors >= kRepeatedErrors) {
    status.summary(diagnostic_msgs::DiagnosticStatus::ERROR,
                   "repeated bad input (" + std::to_string(errors) +
                       " errors in " + std::to_string(int(kErrorWindowS)) +
                       " s): " + last_error_);
  } else if (errors > 0) {
    status.summary(diagnostic_msgs::DiagnosticStatus::WARN, last_error_);
  } else if (subscribed && quiet > stale_after) {
    std::ostringstream text;
    text << "stale: subscribed, but no output for " << quiet << " s";
    status.summary(diagnostic_msgs::DiagnosticStatus::WARN, text.str());
  } else if (!subscribed) {
    status.summary(diagnostic_msgs::DiagnosticStatus::OK,
                   "idle: no subscriber to the outputs");
  } else if (frames_processed_ == 0) {
    status.summary(diagnostic_msgs::DiagnosticStatus::OK,
                   "no frame processed yet");
  } else {
    status.summary(diagnostic_msgs::DiagnosticStatus::OK, "fusing");
  }
  status.add("output rate (Hz, last 5 s)", rate);
  status.add("mean latency (s, last 5 s)", latency);
  status.add("last solve time (s)", last_solve_time_);
  status.add("frames processed", static_cast<std::uint64_t>(frames_processed_));
  status.add("frames dropped (worker busy)",
             static_cast<std::uint64_t>(frames_dropped_));
  status.add("frames skipped (bad input)",
             static_cast<std::uint64_t>(frames_skipped_));
  status.add("last error", last_error_.empty() ? "none" : last_error_);
}

}  // namespace node
}  // namespace normal_fusion
