// rostest (demo_launch.test): the demo's pieces on a small driver's bag.
// make_demo_bag --synthetic writes only what an RGB-D driver records; played
// through launch/demo.launch (two DepthToNormalsNodelets registering the
// depth's normals into the colour camera, the fusion nodelet, one manager) it
// gives both normal maps and a fused map for every frame played, and fuse_bag
// on the recorded normals gives the nodelet's maps. The test runs roslaunch
// itself against rostest's master.
#include <gtest/gtest.h>
#include <normal_fusion/FusionStats.h>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>

#include <cstdlib>
#include <map>
#include <set>
#include <string>

#include "bag_test_util.h"

namespace nf = normal_fusion;

namespace {

constexpr int kFrames = 6;
constexpr int kWidth = 96, kHeight = 72;
const char* const kColorFrame = "camera_color_optical_frame";
const char* const kDepthFrame = "camera_depth_optical_frame";

/// A temporary folder holding a driver's bag in.bag and its ground truth
/// gt.bag; removed at the end.
struct DriverBag {
  std::string dir;
  DriverBag() {
    char dir_template[] = "/tmp/nf_demo_launch_XXXXXX";
    dir = mkdtemp(dir_template);
    const std::string make =
        std::string(MAKE_DEMO_BAG_BIN) + " --synthetic --frames " +
        std::to_string(kFrames) + " --size " + std::to_string(kWidth) + "x" +
        std::to_string(kHeight) + " --output " + dir +
        "/in.bag --ground-truth " + dir + "/gt.bag >/dev/null";
    made = std::system(make.c_str()) == 0;
  }
  ~DriverBag() { std::system(("rm -rf " + dir).c_str()); }
  bool made = false;
};

/// Messages per topic, and the connection header of each topic.
struct TopicCounts {
  std::map<std::string, int> count;
  std::map<std::string, ros::M_string> header;
};

TopicCounts topicsOf(const std::string& path) {
  TopicCounts out;
  rosbag::Bag bag(path, rosbag::bagmode::Read);
  rosbag::View view(bag);
  for (const rosbag::ConnectionInfo* c : view.getConnections()) {
    if (c->header) out.header[c->topic] = *c->header;
  }
  for (const rosbag::MessageInstance& m : view) ++out.count[m.getTopic()];
  return out;
}

/// Largest difference of a normal component between two maps of a size.
double largestDifference(const nf::NormalMap& a, const nf::NormalMap& b) {
  double worst = 0.0;
  for (int c = 0; c < 3; ++c) {
    for (std::size_t i = 0; i < a.pixelCount(); ++i) {
      worst = std::max(
          worst, static_cast<double>(std::abs(a.plane(c)[i] - b.plane(c)[i])));
    }
  }
  return worst;
}

TEST(DemoBag, HoldsOnlyWhatADriverRecords) {
  DriverBag driver;
  ASSERT_TRUE(driver.made);
  const TopicCounts topics = topicsOf(driver.dir + "/in.bag");
  const std::map<std::string, int> expected = {
      {"/camera/color/image_raw", kFrames},
      {"/camera/color/camera_info", kFrames},
      {"/camera/depth/image_rect_raw", kFrames},
      {"/camera/depth/camera_info", kFrames},
      {"/tf", kFrames},
      {"/tf_static", 1}};
  EXPECT_EQ(topics.count, expected);
  ASSERT_EQ(topics.header.count("/tf_static"), 1u);
  const ros::M_string& tf_static = topics.header.at("/tf_static");
  ASSERT_EQ(tf_static.count("latching"), 1u) << "played unlatched";
  EXPECT_EQ(tf_static.at("latching"), "1");

  const auto depth = nf::test::readTopic<sensor_msgs::Image>(
      driver.dir + "/in.bag", "/camera/depth/image_rect_raw");
  const auto color = nf::test::readTopic<sensor_msgs::Image>(
      driver.dir + "/in.bag", "/camera/color/image_raw");
  const auto depth_info = nf::test::readTopic<sensor_msgs::CameraInfo>(
      driver.dir + "/in.bag", "/camera/depth/camera_info");
  ASSERT_EQ(depth.size(), static_cast<std::size_t>(kFrames));
  for (const auto& [stamp, msg] : depth) {
    EXPECT_EQ(msg->encoding, "16UC1");
    EXPECT_EQ(msg->header.frame_id, kDepthFrame);
    EXPECT_EQ(msg->width, static_cast<unsigned>(kWidth));
    ASSERT_EQ(color.count(stamp), 1u) << "no colour image with the depth";
    EXPECT_EQ(color.at(stamp)->header.frame_id, kColorFrame);
    ASSERT_EQ(depth_info.count(stamp), 1u);
    EXPECT_EQ(depth_info.at(stamp)->header.frame_id, kDepthFrame);
    // Millimetres of a room a few metres deep, a few pixels without depth.
    int valid = 0;
    for (std::size_t i = 0; i + 1 < msg->data.size(); i += 2) {
      const int mm = msg->data[i] | (msg->data[i + 1] << 8);
      valid += mm > 0;
      if (mm > 0) {
        EXPECT_GT(mm, 500);
        EXPECT_LT(mm, 10000);
      }
    }
    EXPECT_GT(valid, kWidth * kHeight * 9 / 10);
  }
}

TEST(DemoLaunch, FusesEveryFramePlayedWithNormalsMadeInRos) {
  DriverBag driver;
  ASSERT_TRUE(driver.made);
  const std::string& dir = driver.dir;
  {
    FILE* f = std::fopen((dir + "/params.yaml").c_str(), "w");
    std::fputs("num_inputs: 2\nmax_total_inner_iterations: 200\n", f);
    std::fclose(f);
  }
  const std::string launch =
      "roslaunch normal_fusion demo.launch input:=" + dir +
      "/in.bag output:=" + dir + "/out.bag params:=" + dir +
      "/params.yaml rate:=0.25 linger:=2.0 output_log:=log";
  ASSERT_EQ(std::system(launch.c_str()), 0);

  const std::string out = dir + "/out.bag";
  const auto played = nf::test::readTopic<sensor_msgs::Image>(
      dir + "/in.bag", "/camera/depth/image_rect_raw");
  const auto normals_0 =
      nf::test::readTopic<sensor_msgs::Image>(out, "/depth_to_normals/normals");
  const auto normals_1 = nf::test::readTopic<sensor_msgs::Image>(
      out, "/depth_to_normals_1/normals");
  const auto fused =
      nf::test::readTopic<sensor_msgs::Image>(out, "/fused_normals");
  const auto stats = nf::test::readTopic<nf::FusionStats>(out, "/fusion_stats");
  const auto truth =
      nf::test::readTopic<sensor_msgs::Image>(dir + "/gt.bag", "/normals_gt");
  ASSERT_EQ(played.size(), static_cast<std::size_t>(kFrames));
  for (const auto& entry : played) {
    const ros::Time& stamp = entry.first;
    ASSERT_EQ(normals_0.count(stamp), 1u) << "no normals_0 at " << stamp;
    ASSERT_EQ(normals_1.count(stamp), 1u) << "no normals_1 at " << stamp;
    ASSERT_EQ(fused.count(stamp), 1u) << "no fused map at " << stamp;
    ASSERT_EQ(stats.count(stamp), 1u) << stamp;
    EXPECT_EQ(stats.at(stamp)->frames_dropped, 0u);
    EXPECT_EQ(stats.at(stamp)->inputs_present,
              std::vector<std::uint8_t>({1, 1}));
    // Registered into the colour camera: its frame and pixels.
    for (const auto* normals : {&normals_0, &normals_1}) {
      const sensor_msgs::Image& msg = *normals->at(stamp);
      EXPECT_EQ(msg.encoding, "32FC3");
      EXPECT_EQ(msg.header.frame_id, kColorFrame);
      EXPECT_EQ(msg.width, static_cast<unsigned>(kWidth));
      EXPECT_EQ(msg.height, static_cast<unsigned>(kHeight));
    }
    // The normals come from the depth: the plane fit's (normals_1) are close
    // to the exact ones, and the fused map is closer than normals_0.
    ASSERT_EQ(truth.count(stamp), 1u);
    const nf::NormalMap gt = nf::test::normalsFromImage(*truth.at(stamp));
    const nf::NormalMap fine = nf::test::normalsFromImage(*normals_0.at(stamp));
    const nf::NormalMap coarse =
        nf::test::normalsFromImage(*normals_1.at(stamp));
    const nf::NormalMap out_map = nf::test::normalsFromImage(*fused.at(stamp));
    EXPECT_LT(nf::angularError(coarse, gt).median_deg, 10.0) << stamp;
    EXPECT_GT(nf::psnr(out_map, gt), nf::psnr(fine, gt)) << stamp;
  }
  EXPECT_EQ(fused.size(), played.size());

  // The demo's offline comparison: fuse_bag on the recorded normals.
  const std::string offline =
      std::string(FUSE_BAG_BIN) + " --input " + out + " --output " + dir +
      "/offline.bag --params " + dir +
      "/params.yaml --image /camera/color/image_raw --camera-info "
      "/camera/color/camera_info --normals-0 /depth_to_normals/normals "
      "--normals-1 /depth_to_normals_1/normals --quiet";
  ASSERT_EQ(std::system(offline.c_str()), 0);
  const auto offline_fused = nf::test::readTopic<sensor_msgs::Image>(
      dir + "/offline.bag", "/fused_normals");
  ASSERT_EQ(offline_fused.size(), fused.size());
  for (const auto& [stamp, msg] : fused) {
    ASSERT_EQ(offline_fused.count(stamp), 1u) << stamp;
    EXPECT_LT(
        largestDifference(nf::test::normalsFromImage(*msg),
                          nf::test::normalsFromImage(*offline_fused.at(stamp))),
        1e-5)
        << stamp;
  }
}

}  // namespace

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  // rostest gives the master; roslaunch brings the nodes.
  ros::Time::init();
  return RUN_ALL_TESTS();
}
