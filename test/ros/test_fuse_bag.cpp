// fuse_bag, run as a program on a synthetic bag (no master).
#include <gtest/gtest.h>
#include <normal_fusion/FusionStats.h>
#include <sys/wait.h>

#include <cstdio>
#include <string>

#include "bag_test_util.h"

namespace nf = normal_fusion;

namespace {

struct ToolRun {
  int status = -1;
  std::string output;
};

ToolRun run(const std::string& args) {
  ToolRun r;
  const std::string command = std::string(FUSE_BAG_BIN) + " " + args + " 2>&1";
  FILE* pipe = popen(command.c_str(), "r");
  char buffer[512];
  while (pipe && std::fgets(buffer, sizeof(buffer), pipe)) r.output += buffer;
  const int status = pipe ? pclose(pipe) : -1;
  r.status = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return r;
}

std::string tempDir() {
  char dir[] = "/tmp/nf_fuse_bag_XXXXXX";
  return mkdtemp(dir);
}

TEST(FuseBag, WritesOneOutputPerSetWithTheImageStamps) {
  ros::Time::init();
  const std::string dir = tempDir();
  nf::test::writeSyntheticBag(dir + "/in.bag", 5);
  const ToolRun r = run("--input " + dir + "/in.bag --output " + dir +
                        "/out.bag --num-inputs 2 --set num_threads=2 --quiet");
  ASSERT_EQ(r.status, 0) << r.output;
  EXPECT_NE(r.output.find("frames fused:       5 (4 warm-started)"),
            std::string::npos)
      << r.output;
  EXPECT_NE(r.output.find("solve time / frame"), std::string::npos);
  const auto images =
      nf::test::readTopic<sensor_msgs::Image>(dir + "/in.bag", "/image");
  const auto fused = nf::test::readTopic<sensor_msgs::Image>(dir + "/out.bag",
                                                             "/fused_normals");
  const auto vis = nf::test::readTopic<sensor_msgs::Image>(
      dir + "/out.bag", "/fused_normals_vis");
  const auto stats =
      nf::test::readTopic<nf::FusionStats>(dir + "/out.bag", "/fusion_stats");
  ASSERT_EQ(fused.size(), images.size());
  EXPECT_EQ(vis.size(), images.size());
  EXPECT_EQ(stats.size(), images.size());
  for (const auto& [stamp, image] : images) {
    ASSERT_EQ(fused.count(stamp), 1u);
    EXPECT_EQ(fused.at(stamp)->header.frame_id, image->header.frame_id);
    EXPECT_EQ(fused.at(stamp)->width, image->width);
    EXPECT_EQ(stats.at(stamp)->inputs_present,
              (std::vector<std::uint8_t>{1, 1}));
  }
  std::system(("rm -rf " + dir).c_str());
}

TEST(FuseBag, ParametersFromTheFileAndTheCommandLine) {
  const std::string dir = tempDir();
  nf::test::writeSyntheticBag(dir + "/in.bag", 2);
  {
    FILE* f = std::fopen((dir + "/p.yaml").c_str(), "w");
    std::fputs("num_inputs: 2\ninner_iterations: 7\nlambda: -1\n", f);
    std::fclose(f);
  }
  const ToolRun r = run("--input " + dir + "/in.bag --output " + dir +
                        "/out.bag --params " + dir +
                        "/p.yaml --set max_outer_iterations=1 --set "
                        "pyramid_levels=1 --no-vis --quiet");
  ASSERT_EQ(r.status, 0) << r.output;
  EXPECT_NE(r.output.find("'lambda' = -1"), std::string::npos) << r.output;
  const auto stats =
      nf::test::readTopic<nf::FusionStats>(dir + "/out.bag", "/fusion_stats");
  ASSERT_EQ(stats.size(), 2u);
  for (const auto& entry : stats) {
    EXPECT_EQ(entry.second->inner_iterations, 7u);
    EXPECT_EQ(entry.second->outer_iterations, 1u);
  }
  EXPECT_TRUE(nf::test::readTopic<sensor_msgs::Image>(dir + "/out.bag",
                                                      "/fused_normals_vis")
                  .empty());
  std::system(("rm -rf " + dir).c_str());
}

TEST(FuseBag, RotationCompensatedWarmStartFromTheBagsTf) {
  const std::string dir = tempDir();
  nf::test::writeSyntheticBag(dir + "/in.bag", 3, true);
  const ToolRun r = run("--input " + dir + "/in.bag --output " + dir +
                        "/out.bag --num-inputs 2 --set fixed_frame=world "
                        "--set num_threads=2 --no-vis");
  ASSERT_EQ(r.status, 0) << r.output;
  EXPECT_NE(r.output.find("3 transforms from /tf"), std::string::npos)
      << r.output;
  const auto stats =
      nf::test::readTopic<nf::FusionStats>(dir + "/out.bag", "/fusion_stats");
  ASSERT_EQ(stats.size(), 3u);
  int compensated = 0;
  for (const auto& entry : stats) {
    compensated += entry.second->rotation_compensated;
    EXPECT_EQ(entry.second->rotation_compensated, entry.second->warm_started);
  }
  EXPECT_EQ(compensated, 2);
  // Without the transforms: a warning, and cold starts.
  nf::test::writeSyntheticBag(dir + "/no_tf.bag", 2);
  const ToolRun cold = run("--input " + dir + "/no_tf.bag --output " + dir +
                           "/out2.bag --num-inputs 2 --set fixed_frame=world");
  ASSERT_EQ(cold.status, 0) << cold.output;
  EXPECT_NE(cold.output.find("cold start"), std::string::npos) << cold.output;
  EXPECT_NE(cold.output.find("frames fused:       2 (0 warm-started)"),
            std::string::npos)
      << cold.output;
  std::system(("rm -rf " + dir).c_str());
}

TEST(FuseBag, FailsClearly) {
  const std::string dir = tempDir();
  nf::test::writeSyntheticBag(dir + "/in.bag", 1);
  ToolRun r = run("--output " + dir + "/out.bag");
  EXPECT_EQ(r.status, 2);
  EXPECT_NE(r.output.find("--input and --output are required"),
            std::string::npos);
  r = run("--input " + dir + "/missing.bag --output " + dir + "/out.bag");
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.output.find("cannot read"), std::string::npos);
  // Three inputs asked for, the bag has two.
  r = run("--input " + dir + "/in.bag --output " + dir +
          "/out.bag --num-inputs 3 --quiet");
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.output.find("no messages on: /normals_2"), std::string::npos)
      << r.output;
  r = run("--input " + dir + "/in.bag --output " + dir + "/out.bag --bogus");
  EXPECT_EQ(r.status, 2);
  std::system(("rm -rf " + dir).c_str());
}

}  // namespace
