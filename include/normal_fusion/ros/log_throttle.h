// Throttled logging for the nodelets: each kind of message (its text without
// the numbers, so that the same problem with another stamp or size is the
// same kind) is let through at most once per period. Thread-safe.
#pragma once

#include <ros/time.h>

#include <cctype>
#include <map>
#include <mutex>
#include <string>

namespace normal_fusion {
namespace node {

class LogThrottle {
 public:
  explicit LogThrottle(double period_s) : period_s_(period_s) {}

  /// True when no message of this kind was let through within the period.
  bool admit(const std::string& text) {
    return admitKey(kindOf(text), period_s_);
  }

  /// The same for an explicit key and period.
  bool admitKey(const std::string& key, double period_s) {
    const ros::WallTime now = ros::WallTime::now();
    std::lock_guard<std::mutex> lock(mutex_);
    auto it = last_.find(key);
    if (it != last_.end() && (now - it->second).toSec() < period_s) {
      return false;
    }
    // Bounded: a flood of distinct texts cannot grow the map without end.
    if (last_.size() >= 1000) last_.clear();
    last_[key] = now;
    return true;
  }

  /// The text without digits, '.' and '-'.
  static std::string kindOf(const std::string& text) {
    std::string key;
    for (char c : text) {
      if (!std::isdigit(static_cast<unsigned char>(c)) && c != '.' &&
          c != '-') {
        key += c;
      }
    }
    return key;
  }

 private:
  const double period_s_;
  std::mutex mutex_;
  std::map<std::string, ros::WallTime> last_;
};

}  // namespace node
}  // namespace normal_fusion
