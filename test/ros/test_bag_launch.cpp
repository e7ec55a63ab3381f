// rostest: launch/bag.launch (rosbag play -> nodelet -> rosbag record) and
// fuse_bag give the same results on the same bag.
#include <gtest/gtest.h>
#include <normal_fusion/FusionStats.h>
#include <ros/ros.h>

#include <cstdlib>
#include <string>

#include "bag_test_util.h"

namespace nf = normal_fusion;

namespace {

TEST(BagLaunch, MatchesFuseBag) {
  char dir_template[] = "/tmp/nf_bag_launch_XXXXXX";
  const std::string dir = mkdtemp(dir_template);
  constexpr int kFrames = 6;
  nf::test::writeSyntheticBag(dir + "/in.bag", kFrames);
  // num_threads 2 in both: the same solver configuration.
  const std::string offline =
      std::string(FUSE_BAG_BIN) + " --input " + dir + "/in.bag --output " +
      dir + "/offline.bag --num-inputs 2 --set num_threads=2 --quiet";
  ASSERT_EQ(std::system(offline.c_str()), 0);
  {
    FILE* f = std::fopen((dir + "/params.yaml").c_str(), "w");
    std::fputs("num_threads: 2\n", f);
    std::fclose(f);
  }
  const std::string launch =
      "roslaunch normal_fusion bag.launch input:=" + dir +
      "/in.bag output:=" + dir + "/launch.bag num_inputs:=2 params:=" + dir +
      "/params.yaml linger:=2.0 output_log:=log";
  ASSERT_EQ(std::system(launch.c_str()), 0);

  const auto offline_fused = nf::test::readTopic<sensor_msgs::Image>(
      dir + "/offline.bag", "/fused_normals");
  const auto launch_fused = nf::test::readTopic<sensor_msgs::Image>(
      dir + "/launch.bag", "/fused_normals");
  const auto launch_stats = nf::test::readTopic<nf::FusionStats>(
      dir + "/launch.bag", "/fusion_stats");
  const auto offline_stats = nf::test::readTopic<nf::FusionStats>(
      dir + "/offline.bag", "/fusion_stats");
  ASSERT_EQ(offline_fused.size(), static_cast<std::size_t>(kFrames));
  std::string stamps;
  for (const auto& entry : offline_fused) {
    stamps += " " + std::to_string(entry.first.toSec()) +
              (launch_fused.count(entry.first) ? "" : " (missing)");
  }
  ASSERT_EQ(launch_fused.size(), offline_fused.size())
      << "bag.launch did not fuse every frame:" << stamps;
  for (const auto& [stamp, fused] : offline_fused) {
    ASSERT_EQ(launch_fused.count(stamp), 1u) << stamp;
    ASSERT_EQ(launch_stats.count(stamp), 1u) << stamp;
    EXPECT_EQ(launch_stats.at(stamp)->frames_dropped, 0u);
    EXPECT_EQ(launch_stats.at(stamp)->inner_iterations,
              offline_stats.at(stamp)->inner_iterations);
    EXPECT_EQ(launch_stats.at(stamp)->warm_started,
              offline_stats.at(stamp)->warm_started);
    const nf::NormalMap a = nf::test::normalsFromImage(*fused);
    const nf::NormalMap b = nf::test::normalsFromImage(*launch_fused.at(stamp));
    double worst = 0.0;
    for (int c = 0; c < 3; ++c) {
      for (std::size_t i = 0; i < a.pixelCount(); ++i) {
        worst = std::max(worst, static_cast<double>(
                                    std::abs(a.plane(c)[i] - b.plane(c)[i])));
      }
    }
    EXPECT_LT(worst, 1e-5) << "frame at " << stamp;
  }
  std::system(("rm -rf " + dir).c_str());
}

}  // namespace

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::Time::init();
  return RUN_ALL_TESTS();
}
