// rostest of the running node (nodelet or normal_fusion_node), one gtest node
// built from test_node*.cpp: here lazy subscription, an output for every
// synchronized set with the input's stamp, accuracy, warm start, the live
// overlay, the launch file's environment, shutdown and diagnostics; bad
// inputs, dynamic_reconfigure and the comparison of two nodes in the others.
#include <diagnostic_msgs/DiagnosticArray.h>
#include <gtest/gtest.h>
#include <ros/ros.h>

#include <signal.h>

#include <cstdint>
#include <cstdio>
#include <fstream>
#include <map>
#include <mutex>
#include <string>
#include <vector>

#include "node_test_util.h"
#include "normal_fusion/metrics.h"

using nf::test::cameraInfoMessage;
using nf::test::imageMessage;
using nf::test::makeHeader;
using nf::test::normalsMessage;

namespace {

using nf::node_test::answered;
using nf::node_test::compareMode;
using nf::node_test::kHeight;
using nf::node_test::kWidth;
using nf::node_test::newStamp;
using nf::node_test::NodeClient;
using nf::node_test::pidOfNode;
using nf::node_test::sceneFrame;
using nf::node_test::waitFor;

TEST(Node, SubscribesOnlyWhileSomeoneListens) {
  if (compareMode()) GTEST_SKIP();
  NodeClient client("");
  ros::WallDuration(1.0).sleep();
  EXPECT_EQ(client.inputSubscribers(), 0) << "subscribed with no listener";
  for (int output = 0; output < 3; ++output) {
    client.listen(output == 0, output == 1, output == 2);
    EXPECT_TRUE(waitFor([&] { return client.inputSubscribers() == 4; }, 5.0))
        << "output " << output << ": " << client.inputSubscribers()
        << " input subscriptions";
    client.stopListening();
    EXPECT_TRUE(waitFor([&] { return client.inputSubscribers() == 0; }, 5.0))
        << "still subscribed after the last listener left";
  }
}

TEST(Node, AnswersEverySetWithItsStampAndBeatsTheInputs) {
  if (compareMode()) GTEST_SKIP();
  NodeClient client("");
  client.listen(true, true, true);
  ASSERT_TRUE(waitFor([&] { return client.inputSubscribers() == 4; }, 5.0));
  const auto sequence =
      nf::synthetic::renderSequence(1, kWidth, kHeight, 5, 0.3, 30.0);
  for (std::size_t k = 0; k < sequence.size(); ++k) {
    const nf::test::NoisyFrame f = nf::test::noisyFrame(sequence[k], 30 + k);
    const double stamp = newStamp(1.0 / 30.0);
    const auto m = client.messagesFor(f, stamp);
    ASSERT_TRUE(answered(client, m)) << "no output for frame " << k;
    ASSERT_TRUE(waitFor(
        [&] {
          return client.fused(ros::Time(stamp)) && client.vis(ros::Time(stamp));
        },
        2.0));
    const auto fused = client.fused(ros::Time(stamp));
    const auto vis = client.vis(ros::Time(stamp));
    const auto stats = client.stats(ros::Time(stamp));
    EXPECT_EQ(fused->header.frame_id, m.image->header.frame_id);
    EXPECT_EQ(fused->encoding, "32FC3");
    EXPECT_EQ(fused->width, static_cast<unsigned>(kWidth));
    EXPECT_EQ(fused->height, static_cast<unsigned>(kHeight));
    EXPECT_EQ(vis->encoding, "rgb8");
    EXPECT_EQ(stats->inputs_present, (std::vector<std::uint8_t>{1, 1}));
    EXPECT_EQ(stats->warm_started, k > 0) << "frame " << k;
    EXPECT_EQ(stats->frames_dropped, 0u);
    const nf::NormalMap fused_map = nf::test::normalsFromImage(*fused);
    const double p_fused = nf::psnr(fused_map, f.frame.normals_gt);
    EXPECT_GT(p_fused, nf::psnr(f.noisy, f.frame.normals_gt)) << "frame " << k;
    EXPECT_GT(p_fused, nf::psnr(f.from_depth, f.frame.normals_gt))
        << "frame " << k;
  }
}

/// Launched with live:=true (~expect_live), the node's parameters are the
/// live overlay's (config/live.yaml) over the defaults; without it, the
/// defaults (no frame budget).
TEST(Node, LaunchedLiveHasTheLiveOverlay) {
  if (compareMode()) GTEST_SKIP();
  bool expect_live = false;
  ros::NodeHandle("~").getParam("expect_live", expect_live);
  std::string node_name;
  ASSERT_TRUE(ros::NodeHandle("~").getParam("node_name", node_name));
  const ros::NodeHandle node(node_name);
  double budget = -1.0, cold_budget = -1.0, tolerance = -1.0;
  int max_iterations = -1, max_outer = -1;
  ASSERT_TRUE(node.getParam("time_budget_ms", budget));
  ASSERT_TRUE(node.getParam("cold_start_budget_ms", cold_budget));
  ASSERT_TRUE(node.getParam("relative_tolerance", tolerance));
  ASSERT_TRUE(node.getParam("max_total_inner_iterations", max_iterations));
  ASSERT_TRUE(node.getParam("max_outer_iterations", max_outer));
  EXPECT_EQ(cold_budget, 0.0);
  if (expect_live) {
    EXPECT_EQ(budget, 33.0);
    EXPECT_EQ(tolerance, 1e-6);
    EXPECT_EQ(max_iterations, 4000);
    EXPECT_EQ(max_outer, 400);
  } else {
    EXPECT_EQ(budget, 0.0);
    EXPECT_EQ(tolerance, 1e-4);
    EXPECT_EQ(max_iterations, 1000);
    EXPECT_EQ(max_outer, 40);
  }
}

/// The process that runs the node (~process_node: the nodelet manager, or
/// the standalone node) has the launch file's OMP_WAIT_POLICY, passive by
/// default: its pid from the node's XML-RPC API, its environment from /proc.
TEST(Node, RunsWithTheLaunchFilesWaitPolicy) {
  if (compareMode()) GTEST_SKIP();
  std::string process_node;
  ASSERT_TRUE(ros::NodeHandle("~").getParam("process_node", process_node));
  const int pid = pidOfNode(process_node);
  ASSERT_GT(pid, 0) << process_node;
  std::ifstream environ("/proc/" + std::to_string(pid) + "/environ",
                        std::ios::binary);
  ASSERT_TRUE(environ.good()) << pid;
  std::string entry, policy = "(not set)";
  while (std::getline(environ, entry, '\0')) {
    if (entry.rfind("OMP_WAIT_POLICY=", 0) == 0) policy = entry.substr(16);
  }
  EXPECT_EQ(policy, "passive") << process_node << " (pid " << pid << ")";
}

/// SIGINT (what roslaunch sends first) while the node solves a 1920x1440
/// frame: the process ends promptly, long before the solve would have.
/// Run alone (shutdown_*.test): the node is gone afterwards.
TEST(Shutdown, SigintDuringALargeSolveEndsTheProcessPromptly) {
  std::string process_node;
  ASSERT_TRUE(ros::NodeHandle("~").getParam("process_node", process_node));
  NodeClient client("");
  client.listen(false, false, true);
  ASSERT_TRUE(waitFor([&] { return client.inputSubscribers() == 4; }, 10.0));
  const int pid = pidOfNode(process_node);
  ASSERT_GT(pid, 0) << process_node;
  // A cold solve of this size takes many seconds (1000 inner iterations).
  const auto big =
      nf::test::noisyFrame(nf::synthetic::renderScene(0, 1920, 1440), 23);
  const std_msgs::Header header = makeHeader(newStamp());
  NodeClient::FrameMessages m;
  m.image = imageMessage(big.frame.image, header);
  m.info = cameraInfoMessage(big.frame.K, 1920, 1440, header);
  m.normals[0] = normalsMessage(big.noisy, header);
  m.normals[1] = normalsMessage(big.from_depth, header);
  client.publish(m);
  // Wait until the worker is busy: the process takes more than a core.
  auto cpuTicks = [&] {
    std::ifstream stat("/proc/" + std::to_string(pid) + "/stat");
    std::string field;
    for (int k = 0; k < 13 && stat >> field; ++k) {
    }
    long utime = 0, stime = 0;
    stat >> utime >> stime;
    return utime + stime;
  };
  ros::WallDuration(2.0).sleep();
  const long before = cpuTicks();
  ros::WallDuration(0.5).sleep();
  const long busy = cpuTicks() - before;
  EXPECT_GT(busy, 10) << "the node is not solving";  // ticks of 10 ms
  ASSERT_FALSE(client.stats(header.stamp)) << "the solve already finished";
  const ros::WallTime sent = ros::WallTime::now();
  ASSERT_EQ(kill(pid, SIGINT), 0);
  double ended = -1.0;
  while ((ros::WallTime::now() - sent).toSec() < 30.0) {
    // A zombie (exited, not yet reaped by roslaunch) counts as ended.
    std::ifstream stat("/proc/" + std::to_string(pid) + "/stat");
    std::string pid_text, comm, state;
    if (!(stat >> pid_text >> comm >> state) || state == "Z") {
      ended = (ros::WallTime::now() - sent).toSec();
      break;
    }
    ros::WallDuration(0.01).sleep();
  }
  ASSERT_GE(ended, 0.0) << "still running 30 s after SIGINT";
  std::printf("%s ended %.3f s after SIGINT\n", process_node.c_str(), ended);
  EXPECT_LT(ended, 1.0) << process_node;
}

/// The node's statuses on /diagnostics, newest first per name.
class DiagnosticsCollector {
 public:
  DiagnosticsCollector() {
    ros::NodeHandle nh;
    sub_ = nh.subscribe<diagnostic_msgs::DiagnosticArray>(
        "/diagnostics", 10,
        [this](const diagnostic_msgs::DiagnosticArrayConstPtr& m) {
          std::lock_guard<std::mutex> lock(mutex_);
          for (const auto& status : m->status) {
            if (status.name.find("normal_fusion") == std::string::npos) {
              continue;
            }
            latest_[status.name.find("output rate") != std::string::npos
                        ? "rate"
                        : "main"] = status;
          }
        });
  }
  /// The latest status of "main" (the node's) or "rate" (the output rate).
  bool latest(const std::string& which, diagnostic_msgs::DiagnosticStatus* s) {
    std::lock_guard<std::mutex> lock(mutex_);
    auto it = latest_.find(which);
    if (it == latest_.end()) return false;
    *s = it->second;
    return true;
  }
  void clear() {
    std::lock_guard<std::mutex> lock(mutex_);
    latest_.clear();
  }

 private:
  std::mutex mutex_;
  std::map<std::string, diagnostic_msgs::DiagnosticStatus> latest_;
  // Declared last so that it is destroyed first: a callback still arriving
  // on the spinner's threads never finds the data it writes to destroyed.
  ros::Subscriber sub_;
};

std::string valueOf(const diagnostic_msgs::DiagnosticStatus& s,
                    const std::string& key) {
  for (const auto& kv : s.values) {
    if (kv.key == key) return kv.value;
  }
  return "(none)";
}

TEST(Node, PublishesDiagnostics) {
  if (compareMode()) GTEST_SKIP();
  NodeClient client("");
  DiagnosticsCollector diagnostics;
  client.listen(false, false, true);
  ASSERT_TRUE(waitFor([&] { return client.inputSubscribers() == 4; }, 5.0));
  // Frames at 10 Hz for 1.5 s: fusing, the camera's frame as hardware_id, an
  // output rate within the expected bounds.
  diagnostic_msgs::DiagnosticStatus status, rate;
  for (int k = 0; k < 40; ++k) {
    client.publish(client.messagesFor(sceneFrame(), newStamp()));
    ros::WallDuration(0.1).sleep();
    if (k == 15) diagnostics.clear();
    if (k > 15 && diagnostics.latest("main", &status) &&
        diagnostics.latest("rate", &rate)) {
      break;
    }
  }
  ASSERT_TRUE(diagnostics.latest("main", &status) &&
              diagnostics.latest("rate", &rate));
  EXPECT_EQ(status.level, diagnostic_msgs::DiagnosticStatus::OK)
      << status.message;
  EXPECT_EQ(status.hardware_id, "camera");
  EXPECT_GT(std::stoi(valueOf(status, "frames processed")), 0);
  for (const char* key :
       {"output rate (Hz, last 5 s)", "mean latency (s, last 5 s)",
        "frames dropped (worker busy)", "frames skipped (bad input)",
        "last error"}) {
    EXPECT_NE(valueOf(status, key), "(none)") << key;
  }
  EXPECT_GT(std::stoi(valueOf(rate, "Events since startup")), 0);
  // Inputs stop while someone listens: stale after missing_input_timeout.
  diagnostics.clear();
  EXPECT_TRUE(waitFor(
      [&] {
        return diagnostics.latest("main", &status) &&
               status.level == diagnostic_msgs::DiagnosticStatus::WARN &&
               status.message.find("stale") != std::string::npos;
      },
      5.0))
      << "level " << int(status.level) << ": " << status.message;
  // Repeated bad input: ERROR, naming the topic.
  for (int k = 0; k < 4; ++k) {
    auto bad = client.messagesFor(sceneFrame(), newStamp());
    bad.image->encoding = "nv12";  // not the bad-input test's (throttled) one
    client.publish(bad);
  }
  diagnostics.clear();
  EXPECT_TRUE(waitFor(
      [&] {
        return diagnostics.latest("main", &status) &&
               status.level == diagnostic_msgs::DiagnosticStatus::ERROR;
      },
      3.0))
      << "level " << int(status.level) << ": " << status.message;
  EXPECT_NE(status.message.find("/image"), std::string::npos) << status.message;
  EXPECT_TRUE(answered(client, client.messagesFor(sceneFrame(), newStamp())));
}

}  // namespace

int main(int argc, char** argv) {
  return normal_fusion::test::runRosTests(argc, argv,
                                          "test_normal_fusion_node");
}
