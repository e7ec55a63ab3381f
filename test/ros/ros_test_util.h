// Message builders for the ROS tests: synthetic frames as sensor_msgs.
#pragma once

#include <geometry_msgs/TransformStamped.h>
#include <gtest/gtest.h>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>

#include <tf2/LinearMath/Matrix3x3.h>
#include <tf2/LinearMath/Quaternion.h>

#include <boost/make_shared.hpp>
#include <cmath>
#include <cstring>
#include <limits>
#include <string>

#include "eval/synthetic.h"
#include "normal_fusion/metrics.h"
#include "normal_fusion/types.h"

namespace normal_fusion {
namespace test {

/// The main() of a rostest's gtest binary: gtest's and ROS's arguments, a
/// node named `node_name` whose callbacks run on two threads while the tests
/// run.
inline int runRosTests(int argc, char** argv, const char* node_name) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, node_name);
  ros::AsyncSpinner spinner(2);
  spinner.start();
  const int result = RUN_ALL_TESTS();
  spinner.stop();
  ros::shutdown();
  return result;
}

inline std_msgs::Header makeHeader(double stamp_s,
                                   const std::string& frame = "camera") {
  std_msgs::Header header;
  header.stamp = ros::Time(stamp_s);
  header.frame_id = frame;
  return header;
}

/// A 1- or 3-plane image in [0, 1] as mono8 / rgb8.
inline sensor_msgs::ImagePtr imageMessage(const ColorImage& image,
                                          const std_msgs::Header& header) {
  auto msg = boost::make_shared<sensor_msgs::Image>();
  msg->header = header;
  msg->width = image.width();
  msg->height = image.height();
  const int C = image.channels() == 1 ? 1 : 3;
  msg->encoding = C == 1 ? "mono8" : "rgb8";
  msg->step = msg->width * C;
  msg->data.resize(static_cast<std::size_t>(msg->step) * msg->height);
  for (int y = 0; y < image.height(); ++y) {
    for (int x = 0; x < image.width(); ++x) {
      for (int c = 0; c < C; ++c) {
        const float v = std::min(std::max(image.at(c, y, x), 0.0f), 1.0f);
        msg->data[y * msg->step + x * C + c] =
            static_cast<std::uint8_t>(std::lround(v * 255.0f));
      }
    }
  }
  return msg;
}

/// A normal map as 32FC3.
inline sensor_msgs::ImagePtr normalsMessage(const NormalMap& normals,
                                            const std_msgs::Header& header) {
  auto msg = boost::make_shared<sensor_msgs::Image>();
  msg->header = header;
  msg->width = normals.width();
  msg->height = normals.height();
  msg->encoding = "32FC3";
  msg->step = msg->width * 12;
  msg->data.resize(static_cast<std::size_t>(msg->step) * msg->height);
  for (int y = 0; y < normals.height(); ++y) {
    for (int x = 0; x < normals.width(); ++x) {
      const float v[3] = {normals.at(0, y, x), normals.at(1, y, x),
                          normals.at(2, y, x)};
      std::memcpy(&msg->data[y * msg->step + x * 12], v, sizeof(v));
    }
  }
  return msg;
}

inline sensor_msgs::CameraInfoPtr cameraInfoMessage(
    const CameraIntrinsics& K, int width, int height,
    const std_msgs::Header& header) {
  auto msg = boost::make_shared<sensor_msgs::CameraInfo>();
  msg->header = header;
  msg->width = width;
  msg->height = height;
  msg->distortion_model = "plumb_bob";
  msg->D.assign(5, 0.0);
  for (int i = 0; i < 9; ++i) msg->K[i] = K.K[i];
  msg->R = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  msg->P = {K.K[0], K.K[1], K.K[2], 0, K.K[3], K.K[4], K.K[5], 0, 0, 0, 1, 0};
  return msg;
}

/// A 32FC3 message back to planes.
inline NormalMap normalsFromImage(const sensor_msgs::Image& msg) {
  NormalMap normals(msg.width, msg.height, 3);
  for (int y = 0; y < static_cast<int>(msg.height); ++y) {
    for (int x = 0; x < static_cast<int>(msg.width); ++x) {
      float v[3];
      std::memcpy(v, &msg.data[y * msg.step + x * 12], sizeof(v));
      for (int c = 0; c < 3; ++c) normals.at(c, y, x) = v[c];
    }
  }
  return normals;
}

/// A synthetic frame with two noisy inputs: the paper's noise (sigma 0.4)
/// and the normals of a noisy depth map.
struct NoisyFrame {
  synthetic::Frame frame;
  NormalMap noisy;
  NormalMap from_depth;
};

inline NoisyFrame noisyFrame(const synthetic::Frame& frame,
                             std::uint64_t seed) {
  NoisyFrame out;
  out.frame = frame;
  out.noisy = synthetic::addPaperNoise(frame.normals_gt, 0.4, seed);
  out.from_depth = synthetic::normalsFromNoisyDepth(frame, 0.01, 0.02, seed);
  return out;
}

/// A tf message world -> camera for a synthetic pose (X_cam = R X_world + t):
/// the transform takes camera points into the world, rotation R^T,
/// translation -R^T t.
inline geometry_msgs::TransformStamped cameraInWorld(
    const synthetic::Pose& pose, double stamp) {
  const auto& R = pose.R;
  tf2::Matrix3x3 Rt(R[0], R[3], R[6], R[1], R[4], R[7], R[2], R[5], R[8]);
  tf2::Quaternion q;
  Rt.getRotation(q);
  geometry_msgs::TransformStamped t;
  t.header.stamp = ros::Time(stamp);
  t.header.frame_id = "world";
  t.child_frame_id = "camera";
  t.transform.rotation.x = q.x();
  t.transform.rotation.y = q.y();
  t.transform.rotation.z = q.z();
  t.transform.rotation.w = q.w();
  const auto& tr = pose.t;
  t.transform.translation.x = -(R[0] * tr[0] + R[3] * tr[1] + R[6] * tr[2]);
  t.transform.translation.y = -(R[1] * tr[0] + R[4] * tr[1] + R[7] * tr[2]);
  t.transform.translation.z = -(R[2] * tr[0] + R[5] * tr[1] + R[8] * tr[2]);
  return t;
}

}  // namespace test
}  // namespace normal_fusion
