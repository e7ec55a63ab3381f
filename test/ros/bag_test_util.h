// A small synthetic input bag for the bag tests (fuse_bag, bag.launch).
#pragma once

#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <tf2_msgs/TFMessage.h>

#include <cstdlib>
#include <map>
#include <string>

#include "ros_test_util.h"

namespace normal_fusion {
namespace test {

/// Writes `frames` frames of a slowly moving synthetic room, 96x72 at 10 Hz
/// from stamp 50 s: /image (rgb8), /camera_info, /normals_0 (paper noise,
/// full size), /normals_1 (normals of a noisy depth map, half size); with
/// `with_tf`, the camera's pose on /tf (world -> camera).
inline void writeSyntheticBag(const std::string& path, int frames,
                              bool with_tf = false) {
  const auto sequence = synthetic::renderSequence(0, 96, 72, frames, 0.5, 10.0);
  rosbag::Bag bag(path, rosbag::bagmode::Write);
  for (int k = 0; k < frames; ++k) {
    const synthetic::Frame& frame = sequence[k];
    const std_msgs::Header header = makeHeader(50.0 + frame.stamp);
    const NoisyFrame f = noisyFrame(frame, 300 + k);
    synthetic::Frame half = synthetic::renderScene(0, 48, 36, frame.pose);
    const NormalMap half_noisy =
        synthetic::normalsFromNoisyDepth(half, 0.01, 0.02, 400 + k);
    bag.write("/camera_info", header.stamp,
              *cameraInfoMessage(frame.K, 96, 72, header));
    bag.write("/normals_0", header.stamp, *normalsMessage(f.noisy, header));
    bag.write("/normals_1", header.stamp, *normalsMessage(half_noisy, header));
    bag.write("/image", header.stamp, *imageMessage(frame.image, header));
    if (with_tf) {
      tf2_msgs::TFMessage tf;
      tf.transforms.push_back(cameraInWorld(frame.pose, header.stamp.toSec()));
      bag.write("/tf", header.stamp, tf);
    }
  }
  bag.close();
}

/// Every message of `topic` in a bag, by header stamp.
template <typename M>
std::map<ros::Time, boost::shared_ptr<M>> readTopic(const std::string& path,
                                                    const std::string& topic) {
  std::map<ros::Time, boost::shared_ptr<M>> out;
  rosbag::Bag bag(path, rosbag::bagmode::Read);
  rosbag::View view(bag, rosbag::TopicQuery(topic));
  for (const rosbag::MessageInstance& m : view) {
    if (auto msg = m.instantiate<M>()) out[msg->header.stamp] = msg;
  }
  return out;
}

}  // namespace test
}  // namespace normal_fusion
