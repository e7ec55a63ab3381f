// rostests: launch/bag.launch (rosbag play -> nodelet -> rosbag record) and
// fuse_bag give the same results on the same bag; a bag played twice into a
// running nodelet (bag_loop.test) is fused in both passes.
#include <gtest/gtest.h>
#include <normal_fusion/FusionStats.h>
#include <ros/ros.h>

#include <rosgraph_msgs/Log.h>

#include <atomic>
#include <cstdlib>
#include <mutex>
#include <string>
#include <vector>

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

/// The demo's failure mode: a bag shorter than a second played twice while
/// the node runs. The second pass's stamps repeat the first's.
TEST(BagLoop, PlayedTwiceIntoARunningNodeFusesBothPasses) {
  ASSERT_TRUE(ros::isInitialized()) << "run it under bag_loop.test";
  char dir_template[] = "/tmp/nf_bag_loop_XXXXXX";
  const std::string dir = mkdtemp(dir_template);
  constexpr int kFrames = 6;  // 0.5 s at 10 Hz
  nf::test::writeSyntheticBag(dir + "/in.bag", kFrames);
  ros::NodeHandle nh;
  std::mutex mutex;
  std::vector<nf::FusionStatsConstPtr> outputs;
  std::atomic<int> pass{0};
  std::vector<int> pass_of;
  ros::Subscriber stats = nh.subscribe<nf::FusionStats>(
      "/fusion_stats", 50, [&](const nf::FusionStatsConstPtr& m) {
        std::lock_guard<std::mutex> lock(mutex);
        outputs.push_back(m);
        pass_of.push_back(pass.load());
      });
  std::vector<std::string> infos;
  ros::Subscriber logs = nh.subscribe<rosgraph_msgs::Log>(
      "/rosout", 100, [&](const rosgraph_msgs::LogConstPtr& m) {
        std::lock_guard<std::mutex> lock(mutex);
        if (m->level == rosgraph_msgs::Log::INFO) infos.push_back(m->msg);
      });
  ros::AsyncSpinner spinner(2);
  spinner.start();
  const std::string play = "rosbag play -q --wait-for-subscribers " + dir +
                           "/in.bag >/dev/null 2>&1";
  for (int p = 1; p <= 2; ++p) {
    pass = p;
    ASSERT_EQ(std::system(play.c_str()), 0) << "pass " << p;
    ros::WallDuration(1.5).sleep();  // the last frame's solve
  }
  std::lock_guard<std::mutex> lock(mutex);
  int per_pass[3] = {0, 0, 0};
  bool second_pass_cold_start = false;
  for (std::size_t k = 0; k < outputs.size(); ++k) {
    ++per_pass[pass_of[k]];
    if (pass_of[k] == 2 && per_pass[2] == 1) {
      second_pass_cold_start = !outputs[k]->warm_started;
    }
  }
  EXPECT_GE(per_pass[1], kFrames - 1) << "first pass";
  EXPECT_GE(per_pass[2], kFrames - 1) << "second pass";
  EXPECT_TRUE(second_pass_cold_start) << "the stream was not restarted";
  int resets = 0;
  for (const std::string& text : infos) {
    resets += text.find("time went back") != std::string::npos ? 1 : 0;
  }
  EXPECT_GE(resets, 1) << "no info line on the time jump";
  EXPECT_LE(resets, 2) << "the time jump was reported per message";
  std::system(("rm -rf " + dir).c_str());
}

}  // namespace

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  // Under bag_loop.test, rostest gives a master; bag_launch.test runs
  // roslaunch itself and wants none of it.
  const bool with_node =
      testing::GTEST_FLAG(filter).find("BagLoop") != std::string::npos;
  if (with_node) {
    ros::init(argc, argv, "test_bag_loop");
  } else {
    ros::Time::init();
  }
  return RUN_ALL_TESTS();
}
