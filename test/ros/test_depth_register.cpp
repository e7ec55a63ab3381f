// rostest of the depth_to_normals node with register_to_rgb: a plane seen by a
// depth camera 5 cm beside the colour camera (and turned 3 degrees), the
// transform from tf. Without the transform: an error naming both frames, no
// output, and the next frame answered once tf has it; with it: normals in
// the colour frame, at the colour size, equal to the plane's normal there;
// bad colour camera_infos (an unsupported lens model among them) skipped
// with an error; a distorted colour camera registered through its model; a
// colour camera_info of the depth's frame and size: nothing registered.
// Under depth_register.test (the nodelet's own launch file) and
// depth_register_rgbd.test (launch/rgbd.launch register:=true).
#include <geometry_msgs/TransformStamped.h>
#include <gtest/gtest.h>
#include <ros/ros.h>
#include <rosgraph_msgs/Log.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <tf2_ros/static_transform_broadcaster.h>

#include <boost/make_shared.hpp>
#include <cmath>
#include <cstring>
#include <functional>
#include <map>
#include <mutex>
#include <string>
#include <utility>
#include <vector>

#include "normal_fusion/types.h"
#include "ros_test_util.h"

namespace nf = normal_fusion;

namespace {

constexpr int kDepthWidth = 64, kDepthHeight = 48;
constexpr int kRgbWidth = 80, kRgbHeight = 60;
constexpr double kPi = 3.14159265358979323846;
const char* const kDepthFrame = "camera_depth_optical_frame";
const char* const kRgbFrame = "camera_color_optical_frame";

const nf::CameraIntrinsics kDepthK(60.0, 60.0, 31.5, 23.5);
const nf::CameraIntrinsics kRgbK(70.0, 70.0, 39.5, 29.5);

/// T_rgb_depth: p_rgb = R p_depth + t; the depth camera 5 cm to the colour
/// camera's right, turned 3 degrees about y.
const double kAngle = 3.0 * kPi / 180.0;
const double kR[9] = {std::cos(kAngle),  0, std::sin(kAngle), 0, 1, 0,
                      -std::sin(kAngle), 0, std::cos(kAngle)};
const double kT[3] = {0.05, 0.0, 0.0};

/// The plane n_rgb . X_rgb = d (facing the colour camera), 1.2 m away.
struct Plane {
  double n[3];
  double d;
};
Plane planeRgb() {
  const double n[3] = {0.2, -0.1, -1.0};
  const double norm = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
  return {{n[0] / norm, n[1] / norm, n[2] / norm}, -1.2};
}

bool waitFor(const std::function<bool()>& done, double seconds) {
  const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(seconds);
  while (ros::WallTime::now() < end) {
    if (done()) return true;
    ros::WallDuration(0.01).sleep();
  }
  return done();
}

/// The plane's depth in the depth camera (32FC1, metres): the ray R r_depth
/// from t meets n . X = d at s (r_depth has z = 1, so s is the depth).
sensor_msgs::ImagePtr planeDepth(const std_msgs::Header& header) {
  const Plane p = planeRgb();
  auto msg = boost::make_shared<sensor_msgs::Image>();
  msg->header = header;
  msg->width = kDepthWidth;
  msg->height = kDepthHeight;
  msg->encoding = "32FC1";
  msg->step = 4 * kDepthWidth;
  msg->data.resize(static_cast<std::size_t>(msg->step) * kDepthHeight);
  for (int v = 0; v < kDepthHeight; ++v) {
    for (int u = 0; u < kDepthWidth; ++u) {
      const double r[3] = {(u - kDepthK.cx()) / kDepthK.fx(),
                           (v - kDepthK.cy()) / kDepthK.fy(), 1.0};
      double n_dot_dir = 0, n_dot_t = 0;
      for (int i = 0; i < 3; ++i) {
        double dir = 0;
        for (int k = 0; k < 3; ++k) dir += kR[3 * i + k] * r[k];
        n_dot_dir += p.n[i] * dir;
        n_dot_t += p.n[i] * kT[i];
      }
      const float z = static_cast<float>((p.d - n_dot_t) / n_dot_dir);
      std::memcpy(&msg->data[4 * (v * kDepthWidth + u)], &z, 4);
    }
  }
  return msg;
}

/// Inputs of the node, its normals by stamp, and /rosout.
class Client {
 public:
  Client() {
    // The node's topics: its own names, or those of a launch file (~depth,
    // ~camera_info, ~rgb_camera_info, ~normals).
    const ros::NodeHandle pnh("~");
    const auto topic = [&](const char* key, const char* name) {
      return pnh.param<std::string>(key, name);
    };
    depth_ = nh_.advertise<sensor_msgs::Image>(topic("depth", "depth"), 10);
    info_ = nh_.advertise<sensor_msgs::CameraInfo>(
        topic("camera_info", "camera_info"), 10);
    rgb_info_ = nh_.advertise<sensor_msgs::CameraInfo>(
        topic("rgb_camera_info", "rgb/camera_info"), 10);
    normals_sub_ = nh_.subscribe<sensor_msgs::Image>(
        topic("normals", "normals"), 20,
        [this](const sensor_msgs::ImageConstPtr& m) {
          std::lock_guard<std::mutex> lock(mutex_);
          normals_[m->header.stamp] = m;
        });
    log_sub_ = nh_.subscribe<rosgraph_msgs::Log>(
        "/rosout", 200, [this](const rosgraph_msgs::LogConstPtr& m) {
          std::lock_guard<std::mutex> lock(mutex_);
          if (m->level >= rosgraph_msgs::Log::ERROR) errors_.push_back(m->msg);
        });
  }
  std::string rgbInfoTopic() const { return rgb_info_.getTopic(); }
  bool connected() const {
    return depth_.getNumSubscribers() > 0 && info_.getNumSubscribers() > 0 &&
           rgb_info_.getNumSubscribers() > 0;
  }
  /// A depth frame of the plane with both camera_infos; returns its stamp.
  /// `spoil` may change the colour camera_info before it goes out.
  ros::Time publish(
      bool aligned,
      const std::function<void(sensor_msgs::CameraInfo&)>& spoil = nullptr) {
    std_msgs::Header h;
    next_stamp_ += 0.1;
    h.stamp = ros::Time(next_stamp_);
    h.frame_id = kDepthFrame;
    std_msgs::Header h_rgb = h;
    if (!aligned) h_rgb.frame_id = kRgbFrame;
    auto rgb_info = aligned ? nf::test::cameraInfoMessage(kDepthK, kDepthWidth,
                                                          kDepthHeight, h_rgb)
                            : nf::test::cameraInfoMessage(kRgbK, kRgbWidth,
                                                          kRgbHeight, h_rgb);
    if (spoil) spoil(*rgb_info);
    rgb_info_.publish(rgb_info);
    ros::WallDuration(0.05).sleep();  // the colour camera before the depth
    info_.publish(
        nf::test::cameraInfoMessage(kDepthK, kDepthWidth, kDepthHeight, h));
    depth_.publish(planeDepth(h));
    return h.stamp;
  }
  sensor_msgs::ImageConstPtr normals(const ros::Time& stamp) {
    std::lock_guard<std::mutex> lock(mutex_);
    auto it = normals_.find(stamp);
    return it == normals_.end() ? nullptr : it->second;
  }
  std::size_t normalsCount() {
    std::lock_guard<std::mutex> lock(mutex_);
    return normals_.size();
  }
  bool loggedError(const std::vector<std::string>& parts) {
    std::lock_guard<std::mutex> lock(mutex_);
    for (const std::string& text : errors_) {
      bool all = true;
      for (const auto& p : parts)
        all = all && text.find(p) != std::string::npos;
      if (all) return true;
    }
    return false;
  }

 private:
  ros::NodeHandle nh_;
  ros::Publisher depth_, info_, rgb_info_;
  std::mutex mutex_;
  std::map<ros::Time, sensor_msgs::ImageConstPtr> normals_;
  std::vector<std::string> errors_;
  double next_stamp_ = 300.0;
  // Declared last so that they are destroyed first: a callback still arriving
  // on the spinner's threads never finds the data it writes to destroyed.
  ros::Subscriber normals_sub_, log_sub_;
};

void broadcastTransform(tf2_ros::StaticTransformBroadcaster& broadcaster) {
  geometry_msgs::TransformStamped T;
  T.header.stamp = ros::Time::now();
  T.header.frame_id = kRgbFrame;  // parent: p_rgb = T p_depth
  T.child_frame_id = kDepthFrame;
  T.transform.translation.x = kT[0];
  T.transform.translation.y = kT[1];
  T.transform.translation.z = kT[2];
  // A rotation of kAngle about y.
  T.transform.rotation.x = 0.0;
  T.transform.rotation.y = std::sin(kAngle / 2);
  T.transform.rotation.z = 0.0;
  T.transform.rotation.w = std::cos(kAngle / 2);
  broadcaster.sendTransform(T);
}

/// Pixels with a normal, and the largest angle (degrees) to `n`.
int compareToNormal(const sensor_msgs::Image& msg, const double n[3],
                    double* worst_deg) {
  int valid = 0;
  *worst_deg = 0.0;
  for (std::size_t i = 0; i < std::size_t{msg.width} * msg.height; ++i) {
    float v[3];
    std::memcpy(v, &msg.data[12 * i], sizeof(v));
    if (!nf::isValidNormal(v[0], v[1], v[2])) continue;
    ++valid;
    const double dot = v[0] * n[0] + v[1] * n[1] + v[2] * n[2];
    *worst_deg = std::max(
        *worst_deg, std::acos(std::min(1.0, std::max(-1.0, dot))) * 180 / kPi);
  }
  return valid;
}

/// Bad colour camera_infos: an error naming the topic, the frame skipped,
/// the next good frame answered.
void expectBadColourInfosSkipped(Client& client) {
  const std::vector<
      std::pair<std::function<void(sensor_msgs::CameraInfo&)>, std::string>>
      bad = {
          {[](sensor_msgs::CameraInfo& i) { i.width = i.height = 0; },
           "expected the colour image's size"},
          {[](sensor_msgs::CameraInfo& i) { i.K.fill(0.0); }, "expected K"},
          {[](sensor_msgs::CameraInfo& i) { i.header.frame_id.clear(); },
           "expected both optical frames"},
          {[](sensor_msgs::CameraInfo& i) {
             i.distortion_model = "equidistant";
             i.D = {0.1, 0.0, 0.0, 0.0};
           },
           "distortion model 'equidistant' is not supported"},
          {[](sensor_msgs::CameraInfo& i) {
             i.distortion_model = "plumb_bob";
             i.D = {0.1, 0.0, 0.0, 0.0};
           },
           "with 4 coefficients; expected 5"},
      };
  for (const auto& c : bad) {
    const ros::Time bad_stamp = client.publish(false, c.first);
    EXPECT_TRUE(waitFor(
        [&] {
          return client.loggedError({client.rgbInfoTopic(), c.second});
        },
        5.0))
        << c.second;
    sensor_msgs::ImageConstPtr next;
    for (int k = 0; k < 10 && !next; ++k) {
      const ros::Time stamp = client.publish(false);
      waitFor([&] { return (next = client.normals(stamp)) != nullptr; }, 1.0);
    }
    EXPECT_TRUE(next) << c.second << ": next frame unanswered";
    EXPECT_FALSE(client.normals(bad_stamp)) << c.second << ": answered";
  }
}

TEST(DepthRegister, WaitsForTfThenGivesNormalsInTheColourCamera) {
  Client client;
  ASSERT_TRUE(waitFor([&] { return client.connected(); }, 10.0));
  // No transform yet: each frame is refused with an error naming the frames.
  std::vector<ros::Time> refused;
  for (int k = 0; k < 3; ++k) refused.push_back(client.publish(false));
  EXPECT_TRUE(waitFor(
      [&] {
        return client.loggedError(
            {"no transform to the colour frame", kRgbFrame, kDepthFrame});
      },
      5.0));
  ros::WallDuration(0.5).sleep();
  EXPECT_EQ(client.normalsCount(), 0u) << "answered without a transform";

  tf2_ros::StaticTransformBroadcaster broadcaster;
  broadcastTransform(broadcaster);
  sensor_msgs::ImageConstPtr out;
  for (int k = 0; k < 20 && !out; ++k) {
    const ros::Time stamp = client.publish(false);
    waitFor([&] { return (out = client.normals(stamp)) != nullptr; }, 1.0);
  }
  ASSERT_TRUE(out) << "no normals once the transform is there";
  for (const ros::Time& stamp : refused) EXPECT_FALSE(client.normals(stamp));
  EXPECT_EQ(out->header.frame_id, kRgbFrame);
  EXPECT_EQ(out->width, static_cast<unsigned>(kRgbWidth));
  EXPECT_EQ(out->height, static_cast<unsigned>(kRgbHeight));
  double worst_deg = 0;
  const Plane plane = planeRgb();
  const int valid = compareToNormal(*out, plane.n, &worst_deg);
  EXPECT_GT(valid, kRgbWidth * kRgbHeight / 2);
  EXPECT_LT(worst_deg, 0.1);

  expectBadColourInfosSkipped(client);

  // A colour camera with lens distortion: registered through its model.
  sensor_msgs::ImageConstPtr distorted;
  for (int k = 0; k < 10 && !distorted; ++k) {
    const ros::Time stamp =
        client.publish(false, [](sensor_msgs::CameraInfo& i) {
          i.distortion_model = "plumb_bob";
          i.D = {0.08, -0.15, 0.001, -0.0005, 0.02};
        });
    waitFor([&] { return (distorted = client.normals(stamp)) != nullptr; },
            1.0);
  }
  ASSERT_TRUE(distorted) << "no normals for a distorted colour camera";
  EXPECT_GT(compareToNormal(*distorted, plane.n, &worst_deg),
            kRgbWidth * kRgbHeight / 2);
  EXPECT_LT(worst_deg, 0.1);

  // The same frame, the colour camera_info now the depth's own: nothing is
  // registered, the plane's normal is the depth camera's, R^T n_rgb.
  double n_depth[3] = {0, 0, 0};
  for (int i = 0; i < 3; ++i) {
    for (int k = 0; k < 3; ++k) n_depth[i] += kR[3 * k + i] * plane.n[k];
  }
  sensor_msgs::ImageConstPtr aligned;
  for (int k = 0; k < 10 && !aligned; ++k) {
    const ros::Time stamp = client.publish(true);
    waitFor([&] { return (aligned = client.normals(stamp)) != nullptr; }, 1.0);
  }
  ASSERT_TRUE(aligned);
  EXPECT_EQ(aligned->header.frame_id, kDepthFrame);
  EXPECT_EQ(aligned->width, static_cast<unsigned>(kDepthWidth));
  EXPECT_GT(compareToNormal(*aligned, n_depth, &worst_deg),
            kDepthWidth * kDepthHeight / 2);
  EXPECT_LT(worst_deg, 0.1);
}

}  // namespace

int main(int argc, char** argv) {
  return normal_fusion::test::runRosTests(argc, argv, "test_depth_register");
}
