// rostest of the node's full-motion warm start (motion.test): a translating
// camera whose depth (aligned with the image) and tf come with every frame,
// and a depth of another size, which the node refuses with an error while it
// keeps answering with the rotation-only warm start.
#include <gtest/gtest.h>
#include <ros/ros.h>
#include <tf2_ros/transform_broadcaster.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <string>
#include <vector>

#include "node_test_util.h"

namespace {

using nf::node_test::answered;
using nf::node_test::kHeight;
using nf::node_test::kWidth;
using nf::node_test::LogCollector;
using nf::node_test::newStamp;
using nf::node_test::NodeClient;
using nf::node_test::waitFor;

/// A depth map in metres (NaN = none) as REP 118 32FC1, or as 16UC1 in
/// millimetres (0 = none).
sensor_msgs::ImagePtr depthMessage(const nf::ScalarMap& depth_m,
                                   const std_msgs::Header& header,
                                   bool millimetres) {
  auto msg = boost::make_shared<sensor_msgs::Image>();
  msg->header = header;
  msg->width = depth_m.width();
  msg->height = depth_m.height();
  msg->encoding = millimetres ? "16UC1" : "32FC1";
  msg->is_bigendian = 0;
  const std::size_t bytes = millimetres ? 2 : 4;
  msg->step = static_cast<std::uint32_t>(depth_m.width() * bytes);
  msg->data.resize(msg->step * msg->height);
  for (std::size_t i = 0; i < depth_m.pixelCount(); ++i) {
    const float z = depth_m.plane(0)[i];
    if (millimetres) {
      const std::uint16_t mm =
          std::isfinite(z) ? static_cast<std::uint16_t>(std::lround(1e3 * z))
                           : 0;
      std::memcpy(msg->data.data() + 2 * i, &mm, 2);
    } else {
      std::memcpy(msg->data.data() + 4 * i, &z, 4);
    }
  }
  return msg;
}

/// The node's inputs with a depth topic and tf beside them.
class MotionClient {
 public:
  MotionClient() : client_("") {
    depth_ = client_.nh_.advertise<sensor_msgs::Image>("depth", 10);
    client_.listen(false, false, true);
  }

  bool connected() {
    return waitFor(
        [&] {
          return client_.inputSubscribers() == 4 &&
                 depth_.getNumSubscribers() == 1;
        },
        5.0);
  }

  /// Sends frame k's tf and depth, then (once the depth is queued: an
  /// optional input joins the set only when it is there) its inputs; the
  /// node's statistics of the frame, null when it did not answer.
  nf::FusionStatsConstPtr send(const nf::synthetic::Frame& frame,
                               const nf::ScalarMap& depth_m, int seed,
                               bool millimetres) {
    const double stamp = newStamp(1.0 / 30.0);
    broadcaster_.sendTransform(nf::test::cameraInWorld(frame.pose, stamp));
    depth_.publish(
        depthMessage(depth_m, nf::test::makeHeader(stamp), millimetres));
    ros::WallDuration(0.1).sleep();
    const auto m =
        client_.messagesFor(nf::test::noisyFrame(frame, seed), stamp);
    if (!answered(client_, m)) return nullptr;
    return client_.stats(m.image->header.stamp);
  }

 private:
  NodeClient client_;
  ros::Publisher depth_;
  tf2_ros::TransformBroadcaster broadcaster_;
};

TEST(MotionNode, TranslatingFramesAreWarmStartedByTheFullMotion) {
  MotionClient client;
  ASSERT_TRUE(client.connected());
  ros::WallDuration(0.5).sleep();  // the node's tf listener connects
  // Walking forward (4.7 cm per frame at 30 Hz) and a little sideways.
  const auto frames = nf::synthetic::renderTranslation(0, kWidth, kHeight, 4,
                                                       {{0.01, 0.0, 0.047}});
  for (std::size_t k = 0; k < frames.size(); ++k) {
    const auto stats =
        client.send(frames[k], frames[k].depth, 90 + k, k % 2 == 1);
    ASSERT_TRUE(stats) << "no output for frame " << k;
    EXPECT_EQ(stats->warm_started, k > 0) << "frame " << k;
    EXPECT_EQ(stats->rotation_compensated, k > 0) << "frame " << k;
    EXPECT_EQ(stats->motion_compensated, k > 0) << "frame " << k;
  }
}

TEST(MotionNode, ADepthOfAnotherSizeIsAnErrorAndTheRotationWarmStarts) {
  MotionClient client;
  LogCollector logs;
  ASSERT_TRUE(client.connected());
  ros::WallDuration(0.5).sleep();
  const auto frames = nf::synthetic::renderTranslation(0, kWidth, kHeight, 4,
                                                       {{0.0, 0.0, 0.047}});
  const nf::ScalarMap small(kWidth / 2, kHeight / 2, 1, 2.0f);
  // A new stream (its stamps follow the previous test's) with a good depth,
  // then one of half the size: refused, the next frame rotation-only.
  auto stats = client.send(frames[0], frames[0].depth, 120, false);
  ASSERT_TRUE(stats);
  stats = client.send(frames[1], small, 121, false);
  ASSERT_TRUE(stats) << "no output for the frame with the bad depth";
  EXPECT_TRUE(stats->motion_compensated);  // by the previous, good depth
  EXPECT_TRUE(waitFor(
      [&] {
        return logs.seen(rosgraph_msgs::Log::ERROR,
                         {"depth", "48x36", "96x72", "aligned with the image",
                          "rotation alone"});
      },
      3.0));
  stats = client.send(frames[2], frames[2].depth, 122, true);
  ASSERT_TRUE(stats) << "the node stopped answering";
  EXPECT_TRUE(stats->warm_started);
  EXPECT_TRUE(stats->rotation_compensated);
  EXPECT_FALSE(stats->motion_compensated);
  stats = client.send(frames[3], frames[3].depth, 123, true);
  ASSERT_TRUE(stats);
  EXPECT_TRUE(stats->motion_compensated);
}

}  // namespace

int main(int argc, char** argv) {
  return normal_fusion::test::runRosTests(argc, argv, "test_node_motion");
}
