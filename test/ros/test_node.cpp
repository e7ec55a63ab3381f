// rostest of the running node (nodelet or normal_fusion_node): lazy
// subscription, an output for every synchronized set with the input's stamp,
// accuracy, warm start, bad inputs, dynamic_reconfigure, missing inputs.
// With ~compare_namespaces set, it checks instead that two nodes in those
// namespaces (the nodelet and the standalone node) give the same outputs.
#include <diagnostic_msgs/DiagnosticArray.h>
#include <dynamic_reconfigure/ConfigDescription.h>
#include <dynamic_reconfigure/Reconfigure.h>
#include <gtest/gtest.h>
#include <normal_fusion/FusionStats.h>
#include <ros/master.h>
#include <ros/network.h>
#include <ros/ros.h>
#include <rosgraph_msgs/Log.h>
#include <tf2_ros/transform_broadcaster.h>
#include <xmlrpcpp/XmlRpc.h>

#include <signal.h>

#include <cstdint>
#include <cstdio>
#include <fstream>
#include <functional>
#include <map>
#include <mutex>
#include <random>
#include <set>
#include <sstream>
#include <thread>

#include "normal_fusion/metrics.h"
#include "normal_fusion/ros/conversions.h"
#include "ros_test_util.h"

namespace nf = normal_fusion;
using nf::test::cameraInfoMessage;
using nf::test::imageMessage;
using nf::test::makeHeader;
using nf::test::normalsMessage;

namespace {

constexpr int kWidth = 96, kHeight = 72;

/// Polls `done` until it holds or `seconds` pass.
bool waitFor(const std::function<bool()>& done, double seconds) {
  const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(seconds);
  while (ros::WallTime::now() < end) {
    if (done()) return true;
    ros::WallDuration(0.01).sleep();
  }
  return done();
}

/// Publishers of one node's inputs and collectors of its outputs.
class NodeClient {
 public:
  explicit NodeClient(const std::string& ns) : nh_(ns) {
    image_ = nh_.advertise<sensor_msgs::Image>("image", 10);
    info_ = nh_.advertise<sensor_msgs::CameraInfo>("camera_info", 10);
    normals_[0] = nh_.advertise<sensor_msgs::Image>("normals_0", 10);
    normals_[1] = nh_.advertise<sensor_msgs::Image>("normals_1", 10);
  }

  void listen(bool fused, bool vis, bool stats) {
    if (fused) {
      fused_sub_ = nh_.subscribe<sensor_msgs::Image>(
          "fused_normals", 20, [this](const sensor_msgs::ImageConstPtr& m) {
            std::lock_guard<std::mutex> lock(mutex_);
            fused_[m->header.stamp] = m;
          });
    }
    if (vis) {
      vis_sub_ = nh_.subscribe<sensor_msgs::Image>(
          "fused_normals_vis", 20, [this](const sensor_msgs::ImageConstPtr& m) {
            std::lock_guard<std::mutex> lock(mutex_);
            vis_[m->header.stamp] = m;
          });
    }
    if (stats) {
      stats_sub_ = nh_.subscribe<nf::FusionStats>(
          "fusion_stats", 20, [this](const nf::FusionStatsConstPtr& m) {
            std::lock_guard<std::mutex> lock(mutex_);
            stats_[m->header.stamp] = m;
          });
    }
  }

  void stopListening() {
    fused_sub_.shutdown();
    vis_sub_.shutdown();
    stats_sub_.shutdown();
  }

  int inputSubscribers() const {
    return image_.getNumSubscribers() + info_.getNumSubscribers() +
           normals_[0].getNumSubscribers() + normals_[1].getNumSubscribers();
  }

  /// Publishes one frame's messages; `mutate` may spoil them first.
  struct FrameMessages {
    sensor_msgs::ImagePtr image, normals[2];
    sensor_msgs::CameraInfoPtr info;
  };
  FrameMessages messagesFor(const nf::test::NoisyFrame& f, double stamp) const {
    const std_msgs::Header header = makeHeader(stamp);
    FrameMessages m;
    m.image = imageMessage(f.frame.image, header);
    m.info = cameraInfoMessage(f.frame.K, kWidth, kHeight, header);
    m.normals[0] = normalsMessage(f.noisy, header);
    m.normals[1] = normalsMessage(f.from_depth, header);
    return m;
  }
  void publish(const FrameMessages& m) {
    if (m.info) info_.publish(m.info);
    if (m.normals[0]) normals_[0].publish(m.normals[0]);
    if (m.normals[1]) normals_[1].publish(m.normals[1]);
    if (m.image) image_.publish(m.image);
  }

  sensor_msgs::ImageConstPtr fused(const ros::Time& stamp) {
    std::lock_guard<std::mutex> lock(mutex_);
    auto it = fused_.find(stamp);
    return it == fused_.end() ? nullptr : it->second;
  }
  sensor_msgs::ImageConstPtr vis(const ros::Time& stamp) {
    std::lock_guard<std::mutex> lock(mutex_);
    auto it = vis_.find(stamp);
    return it == vis_.end() ? nullptr : it->second;
  }
  nf::FusionStatsConstPtr stats(const ros::Time& stamp) {
    std::lock_guard<std::mutex> lock(mutex_);
    auto it = stats_.find(stamp);
    return it == stats_.end() ? nullptr : it->second;
  }
  std::size_t statsCount() {
    std::lock_guard<std::mutex> lock(mutex_);
    return stats_.size();
  }

  ros::NodeHandle nh_;

 private:
  ros::Publisher image_, info_, normals_[2];
  ros::Subscriber fused_sub_, vis_sub_, stats_sub_;
  std::mutex mutex_;
  std::map<ros::Time, sensor_msgs::ImageConstPtr> fused_, vis_;
  std::map<ros::Time, nf::FusionStatsConstPtr> stats_;
};

/// Collects /rosout so that tests can check what the node logged.
class LogCollector {
 public:
  LogCollector() {
    ros::NodeHandle nh;
    sub_ = nh.subscribe<rosgraph_msgs::Log>(
        "/rosout", 100, [this](const rosgraph_msgs::LogConstPtr& m) {
          std::lock_guard<std::mutex> lock(mutex_);
          logs_.push_back(*m);
        });
  }
  /// True once a message at `level` or above contains every part.
  bool seen(std::uint8_t level, const std::vector<std::string>& parts) {
    std::lock_guard<std::mutex> lock(mutex_);
    for (const auto& log : logs_) {
      if (log.level < level) continue;
      bool all = true;
      for (const auto& p : parts) {
        all = all && log.msg.find(p) != std::string::npos;
      }
      if (all) return true;
    }
    return false;
  }

 private:
  ros::Subscriber sub_;
  std::mutex mutex_;
  std::vector<rosgraph_msgs::Log> logs_;
};

std::string nodeName() {
  std::string name = "/normal_fusion";
  ros::NodeHandle("~").getParam("node_name", name);
  return name;
}

const nf::test::NoisyFrame& sceneFrame() {
  static const nf::test::NoisyFrame frame =
      nf::test::noisyFrame(nf::synthetic::renderScene(0, kWidth, kHeight), 17);
  return frame;
}

/// Publishes `m` and waits for the outputs with its stamp.
bool answered(NodeClient& client, const NodeClient::FrameMessages& m,
              double seconds = 5.0) {
  client.publish(m);
  const ros::Time stamp = m.image->header.stamp;
  return waitFor([&] { return client.stats(stamp) != nullptr; }, seconds);
}

double next_stamp = 100.0;
double newStamp(double step = 0.1) { return next_stamp += step; }

bool compareMode() {
  std::string namespaces;
  return ros::NodeHandle("~").getParam("compare_namespaces", namespaces) &&
         !namespaces.empty();
}

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
/// The pid of the process that runs a node, from its XML-RPC API (-1 when
/// unknown).
int pidOfNode(const std::string& node) {
  XmlRpc::XmlRpcValue args, result, payload;
  args[0] = ros::this_node::getName();
  args[1] = node;
  if (!ros::master::execute("lookupNode", args, result, payload, true)) {
    return -1;
  }
  std::string host, uri = static_cast<std::string>(payload);
  std::uint32_t port = 0;
  if (!ros::network::splitURI(uri, host, port)) return -1;
  XmlRpc::XmlRpcClient client(host.c_str(), static_cast<int>(port), "/");
  XmlRpc::XmlRpcValue pid_args, pid_result;
  pid_args[0] = ros::this_node::getName();
  if (!client.execute("getPid", pid_args, pid_result) ||
      static_cast<int>(pid_result[0]) != 1) {
    return -1;
  }
  return static_cast<int>(pid_result[2]);
}

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
  ros::Subscriber sub_;
  std::mutex mutex_;
  std::map<std::string, diagnostic_msgs::DiagnosticStatus> latest_;
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

/// One class of bad input: which rule of the node's input checks (see
/// normal_fusion::node::inputRuleNames; "" for the checks of the set as a
/// whole), how a good frame is spoiled, and what the error must say.
struct BadInputCase {
  const char* what;
  const char* rule;
  std::function<void(NodeClient::FrameMessages&)> spoil;
  std::vector<std::string> logged;
};

std::vector<BadInputCase> badInputCases() {
  using Messages = NodeClient::FrameMessages;
  const nf::test::NoisyFrame& f = sceneFrame();
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  return {
      {"unsupported encoding",
       "encoding",
       [](Messages& m) { m.image->encoding = "yuv422"; },
       {"/image", "unsupported encoding 'yuv422'"}},
      {"unknown normals encoding",
       "encoding",
       [](Messages& m) { m.normals[1]->encoding = "64FC3"; },
       {"/normals_1", "unsupported encoding '64FC3'"}},
      {"empty image",
       "minimum size",
       [](Messages& m) {
         m.image->width = 0;
         m.image->data.clear();
       },
       {"/image", "non-empty"}},
      {"1x1 image",
       "",
       [](Messages& m) {
         m.image->width = m.image->height = 1;
         m.image->step = 3;
         m.image->data.assign(3, 0);
       },
       {"/image", "at least 2x2"}},
      {"1xN image",
       "",
       [](Messages& m) {
         m.image->width = 1;
         m.image->step = 3;
         m.image->data.assign(3 * m.image->height, 0);
       },
       {"/image", "at least 2x2"}},
      {"8000x6000 image",
       "maximum size",
       [](Messages& m) {
         // Only the header: the check comes before any buffer is read.
         m.image->width = 8000;
         m.image->height = 6000;
         m.image->step = 3 * 8000;
         m.image->data.clear();
       },
       {"/image", "8000x6000", "max_pixels"}},
      {"step shorter than a row",
       "step",
       [](Messages& m) { m.normals[0]->step = 4; },
       {"/normals_0", "step 4 is shorter"}},
      {"step and size inconsistent",
       "data size",
       [](Messages& m) { m.normals[0]->data.resize(100); },
       {"/normals_0", "height * step"}},
      {"big-endian floats",
       "endianness",
       [](Messages& m) { m.normals[0]->is_bigendian = 1; },
       {"/normals_0", "big-endian"}},
      {"zero stamp",
       "stamp zero",
       [](Messages& m) { m.image->header.stamp = ros::Time(); },
       {"/image", "stamp is zero"}},
      {"stamp not normalized",
       "stamp normalized",
       [](Messages& m) {
         m.image->header.stamp.nsec = 1500000000u;
         m.info->header.stamp.nsec = 1500000000u;
       },
       {"/image", "not normalized"}},
      {"size mismatch",
       "",
       [&](Messages& m) {
         nf::NormalMap w(kWidth, kHeight / 2, 3, 0.0f);
         for (std::size_t i = 0; i < w.pixelCount(); ++i) w.plane(2)[i] = -1;
         m.normals[1] = normalsMessage(w, m.image->header);
       },
       {"/normals_1", "aspect ratio"}},
      {"all-NaN map",
       "",
       [&](Messages& m) {
         m.normals[0] = normalsMessage(nf::NormalMap(kWidth, kHeight, 3, nan),
                                       m.image->header);
       },
       {"/normals_0", "no valid normal"}},
      {"infinite normals",
       "",
       [&](Messages& m) {
         nf::NormalMap bad = f.noisy;
         bad.plane(0)[5] = std::numeric_limits<float>::infinity();
         m.normals[0] = normalsMessage(bad, m.image->header);
       },
       {"/normals_0", "infinite"}},
      {"non-unit vectors",
       "",
       [&](Messages& m) {
         nf::NormalMap big = f.from_depth;
         for (int c = 0; c < 3; ++c) {
           for (std::size_t i = 0; i < big.pixelCount(); ++i) {
             big.plane(c)[i] *= 3.0f;
           }
         }
         m.normals[1] = normalsMessage(big, m.image->header);
       },
       {"/normals_1", "not unit vectors"}},
      {"normals in another frame",
       "",
       [](Messages& m) { m.normals[0]->header.frame_id = "elsewhere"; },
       {"/normals_0", "frame_id 'elsewhere'"}},
      {"camera_info in another frame",
       "",
       [](Messages& m) { m.info->header.frame_id = "elsewhere"; },
       {"/camera_info", "frame_id 'elsewhere'"}},
      {"zero K",
       "K shape",
       [](Messages& m) { m.info->K.fill(0.0); },
       {"/camera_info", "expected K"}},
      {"negative focal length",
       "K shape",
       [](Messages& m) { m.info->K[0] = -500.0; },
       {"/camera_info", "fx, fy > 0"}},
      {"non-finite K",
       "K finite",
       [inf](Messages& m) { m.info->K[2] = inf; },
       {"/camera_info", "not finite"}},
      {"camera_info of another size",
       "camera_info size",
       [](Messages& m) { m.info->width = 320; },
       {"/camera_info", "camera_info is for a 320x"}},
      {"focal length 1e-150",
       "K rays",
       [](Messages& m) { m.info->K[0] = m.info->K[4] = 1e-150; },
       {"/camera_info", "ray of pixel"}},
      {"principal point 1e30",
       "K rays",
       [](Messages& m) { m.info->K[2] = 1e30; },
       {"/camera_info", "ray of pixel"}},
      {"det(K) = inf",
       "K rays",
       [](Messages& m) { m.info->K[0] = m.info->K[4] = 1e200; },
       {"/camera_info", "K is singular"}},
      {"missing camera_info",
       "",
       [](Messages& m) { m.info.reset(); },
       {"/camera_info", "no camera_info for the image"}},
  };
}

TEST(Node, EveryInputRuleHasABadInputCase) {
  if (compareMode()) GTEST_SKIP();
  std::set<std::string> covered;
  for (const BadInputCase& c : badInputCases()) covered.insert(c.rule);
  for (const std::string& rule : nf::node::inputRuleNames()) {
    EXPECT_EQ(covered.count(rule), 1u) << "no bad-input case for " << rule;
  }
}

TEST(Node, BadInputIsSkippedAndTheNextGoodFrameAnswered) {
  if (compareMode()) GTEST_SKIP();
  NodeClient client("");
  LogCollector logs;
  client.listen(false, false, true);
  ASSERT_TRUE(waitFor([&] { return client.inputSubscribers() == 4; }, 5.0));
  const nf::test::NoisyFrame& f = sceneFrame();
  using Messages = NodeClient::FrameMessages;
  const std::vector<BadInputCase> cases = badInputCases();
  for (const BadInputCase& c : cases) {
    Messages bad = client.messagesFor(f, newStamp());
    const ros::Time bad_stamp = bad.image->header.stamp;
    c.spoil(bad);
    client.publish(bad);
    // The missing camera_info shows only once the next frame's arrives.
    if (std::string(c.what) != "missing camera_info") {
      EXPECT_TRUE(waitFor(
          [&] { return logs.seen(rosgraph_msgs::Log::ERROR, c.logged); }, 3.0))
          << c.what << ": no error naming " << c.logged[0] << " and '"
          << c.logged[1] << "'";
    }
    const Messages good = client.messagesFor(f, newStamp(1.0));
    EXPECT_TRUE(answered(client, good)) << c.what << ": next frame unanswered";
    EXPECT_FALSE(client.stats(bad_stamp)) << c.what << ": bad frame answered";
    EXPECT_TRUE(waitFor(
        [&] { return logs.seen(rosgraph_msgs::Log::ERROR, c.logged); }, 2.0))
        << c.what << ": no error naming " << c.logged[0] << " and '"
        << c.logged[1] << "'";
  }
  // A duplicate: the image of the last frame again.
  Messages again = client.messagesFor(f, next_stamp);
  again.info.reset();
  again.normals[0].reset();
  again.normals[1].reset();
  client.publish(again);
  EXPECT_TRUE(waitFor(
      [&] {
        return logs.seen(rosgraph_msgs::Log::ERROR, {"/image", "duplicate"});
      },
      2.0));
  EXPECT_TRUE(answered(client, client.messagesFor(f, newStamp(1.0))));
  const auto last = client.stats(ros::Time(next_stamp));
  ASSERT_TRUE(last);
  EXPECT_GE(last->frames_skipped, cases.size());
}

/// Stamps are fused wherever they lie in ros::Time's range: one in the year
/// 2100 (beyond a 32-bit Duration from the others), then time going back.
TEST(Node, FarStampsAndTimeGoingBackAreFused) {
  if (compareMode()) GTEST_SKIP();
  NodeClient client("");
  LogCollector logs;
  client.listen(false, false, true);
  ASSERT_TRUE(waitFor([&] { return client.inputSubscribers() == 4; }, 5.0));
  const nf::test::NoisyFrame& f = sceneFrame();
  ASSERT_TRUE(answered(client, client.messagesFor(f, newStamp())));
  const double year_2100 = 4102444800.0;
  EXPECT_TRUE(answered(client, client.messagesFor(f, year_2100)));
  EXPECT_TRUE(answered(client, client.messagesFor(f, year_2100 + 0.1)));
  // Back to the present: the synchronizer and the stream restart.
  EXPECT_TRUE(answered(client, client.messagesFor(f, newStamp())));
  EXPECT_TRUE(waitFor(
      [&] {
        return logs.seen(rosgraph_msgs::Log::INFO,
                         {"time went back", "synchronizer and stream reset"});
      },
      2.0));
  EXPECT_FALSE(logs.seen(rosgraph_msgs::Log::ERROR, {"32-bit"}));
  const auto stats = client.stats(ros::Time(next_stamp));
  ASSERT_TRUE(stats);
  EXPECT_FALSE(stats->warm_started);
  EXPECT_TRUE(answered(client, client.messagesFor(f, newStamp())));
  EXPECT_TRUE(client.stats(ros::Time(next_stamp))->warm_started);
}

/// A seeded fuzz: a few hundred messages spoiled at random (encodings,
/// sizes, steps, bytes, stamps, K) on every input topic, with a good frame
/// after every tenth; the node answers each good frame and the last one.
TEST(Node, SurvivesSeededFuzz) {
  if (compareMode()) GTEST_SKIP();
  NodeClient client("");
  client.listen(false, false, true);
  ASSERT_TRUE(waitFor([&] { return client.inputSubscribers() == 4; }, 5.0));
  const nf::test::NoisyFrame& f = sceneFrame();
  std::mt19937 rng(20261201);
  auto pick = [&](int n) {
    return static_cast<int>(std::uniform_int_distribution<int>(0, n - 1)(rng));
  };
  const char* const encodings[] = {"rgb8",  "bgr8",  "mono8", "mono16",
                                   "32FC3", "32FC1", "16UC1", "yuv422",
                                   "",      "8UC3",  "rgba8", "64FC1"};
  const double specials[] = {0.0,
                             -1.0,
                             1e-150,
                             1e300,
                             std::numeric_limits<double>::infinity(),
                             std::numeric_limits<double>::quiet_NaN(),
                             -0.0,
                             1e30};
  auto spoilImage = [&](sensor_msgs::Image& m) {
    switch (pick(7)) {
      case 0:
        m.encoding = encodings[pick(12)];
        break;
      case 1:
        m.width = static_cast<std::uint32_t>(pick(3) == 0 ? rng() : pick(200));
        break;
      case 2:
        m.height = static_cast<std::uint32_t>(pick(3) == 0 ? rng() : pick(200));
        break;
      case 3:
        m.step = static_cast<std::uint32_t>(pick(2) == 0 ? rng() : pick(2000));
        break;
      case 4:
        m.data.resize(pick(2) == 0 ? pick(1000) : m.data.size() + pick(64));
        break;
      case 5:  // random bytes: NaN, inf, huge and non-unit floats
        for (int k = 0; k < 64 && !m.data.empty(); ++k) {
          m.data[pick(static_cast<int>(m.data.size()))] =
              static_cast<std::uint8_t>(rng());
        }
        break;
      default:
        m.is_bigendian = static_cast<std::uint8_t>(pick(3));
    }
  };
  int good = 0;
  for (int k = 0; k < 300; ++k) {
    NodeClient::FrameMessages m = client.messagesFor(f, newStamp(0.05));
    const int mutations = 1 + pick(3);
    for (int j = 0; j < mutations; ++j) {
      switch (pick(6)) {
        case 0:
          spoilImage(*m.image);
          break;
        case 1:
          spoilImage(*m.normals[0]);
          break;
        case 2:
          spoilImage(*m.normals[1]);
          break;
        case 3:
          m.info->K[pick(9)] = specials[pick(8)];
          break;
        case 4: {
          std_msgs::Header& h =
              pick(2) == 0 ? m.image->header : m.normals[pick(2)]->header;
          h.stamp.nsec = static_cast<std::uint32_t>(rng());
          if (pick(4) == 0) h.stamp.sec = static_cast<std::uint32_t>(rng());
          break;
        }
        default:
          m.info->width = static_cast<std::uint32_t>(pick(200));
      }
    }
    client.publish(m);
    if (k % 10 == 9) {
      ros::WallDuration(0.05).sleep();
      ++good;
      EXPECT_TRUE(answered(client, client.messagesFor(f, newStamp(1.0))))
          << "good frame " << good << " (after fuzz message " << k
          << ") unanswered";
    }
  }
  EXPECT_TRUE(answered(client, client.messagesFor(f, newStamp(1.0))));
}

TEST(Node, WarnsNamingTheMissingInputs) {
  if (compareMode()) GTEST_SKIP();
  NodeClient client("");
  LogCollector logs;
  client.listen(false, false, true);
  ASSERT_TRUE(waitFor([&] { return client.inputSubscribers() == 4; }, 5.0));
  // Image and camera_info only, for longer than missing_input_timeout.
  const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(3.5);
  bool warned = false;
  while (ros::WallTime::now() < end && !warned) {
    auto m = client.messagesFor(sceneFrame(), newStamp());
    m.normals[0].reset();
    m.normals[1].reset();
    client.publish(m);
    ros::WallDuration(0.1).sleep();
    warned = logs.seen(rosgraph_msgs::Log::WARN,
                       {"missing inputs", "/normals_0", "/normals_1"});
  }
  EXPECT_TRUE(warned);
  EXPECT_FALSE(
      logs.seen(rosgraph_msgs::Log::WARN, {"missing inputs", "/image ("}));
  EXPECT_TRUE(answered(client, client.messagesFor(sceneFrame(), newStamp())));
}

TEST(Node, DynamicReconfigureTakesEffectOnTheNextFrame) {
  if (compareMode()) GTEST_SKIP();
  NodeClient client("");
  LogCollector logs;
  client.listen(false, false, true);
  ASSERT_TRUE(waitFor([&] { return client.inputSubscribers() == 4; }, 5.0));
  const std::string service = nodeName() + "/set_parameters";
  ASSERT_TRUE(ros::service::waitForService(service, 5000));
  dynamic_reconfigure::Reconfigure current;  // empty request: reads the config
  ASSERT_TRUE(ros::service::call(service, current));
  dynamic_reconfigure::Reconfigure srv;
  dynamic_reconfigure::IntParameter p;
  for (const auto& [name, value] :
       std::vector<std::pair<std::string, int>>{{"inner_iterations", 3},
                                                {"max_outer_iterations", 1},
                                                {"pyramid_levels", 1}}) {
    p.name = name;
    p.value = value;
    srv.request.config.ints.push_back(p);
  }
  dynamic_reconfigure::BoolParameter b;
  b.name = "warm_start";
  b.value = false;
  srv.request.config.bools.push_back(b);
  dynamic_reconfigure::DoubleParameter d;
  d.name = "edge_w_min";
  d.value = 5.0;  // invalid: refused with a warning naming it
  srv.request.config.doubles.push_back(d);
  ASSERT_TRUE(ros::service::call(service, srv));
  double w_min_before = -1.0, w_min_after = -2.0;
  for (const auto& q : current.response.config.doubles) {
    if (q.name == "edge_w_min") w_min_before = q.value;
  }
  for (const auto& q : srv.response.config.doubles) {
    if (q.name == "edge_w_min") w_min_after = q.value;
  }
  EXPECT_EQ(w_min_after, w_min_before) << "edge_w_min = 5 was not refused";
  EXPECT_TRUE(waitFor(
      [&] { return logs.seen(rosgraph_msgs::Log::WARN, {"'edge_w_min' = 5"}); },
      2.0));
  const auto m = client.messagesFor(sceneFrame(), newStamp());
  ASSERT_TRUE(answered(client, m));
  const auto stats = client.stats(m.image->header.stamp);
  EXPECT_EQ(stats->inner_iterations, 3u);
  EXPECT_EQ(stats->outer_iterations, 1u);
  EXPECT_FALSE(stats->warm_started);
  // Back to the configuration from before, for whatever runs next.
  dynamic_reconfigure::Reconfigure restore;
  restore.request.config = current.response.config;
  ASSERT_TRUE(ros::service::call(service, restore));
  const auto again = client.messagesFor(sceneFrame(), newStamp());
  ASSERT_TRUE(answered(client, again));
  EXPECT_GT(client.stats(again.image->header.stamp)->inner_iterations, 3u);
}

/// The warm start and the inputs' temporal averages (temporal_frames, set
/// through dynamic_reconfigure) carried by the camera's rotation from tf.
/// rqt_reconfigure's view: every dynamic numeric parameter has the node's
/// finite range in the description (the .cfg declares none, so that the
/// node itself refuses out-of-range values with a warning).
TEST(Node, DescriptionCarriesEveryNumericRange) {
  if (compareMode()) GTEST_SKIP();
  std::mutex mutex;
  dynamic_reconfigure::ConfigDescription description;
  bool received = false;
  ros::NodeHandle nh;
  ros::Subscriber sub = nh.subscribe<dynamic_reconfigure::ConfigDescription>(
      nodeName() + "/parameter_descriptions", 1,
      [&](const dynamic_reconfigure::ConfigDescriptionConstPtr& m) {
        std::lock_guard<std::mutex> lock(mutex);
        description = *m;
        received = true;
      });
  ASSERT_TRUE(waitFor(
      [&] {
        std::lock_guard<std::mutex> lock(mutex);
        return received;
      },
      5.0));
  std::lock_guard<std::mutex> lock(mutex);
  std::map<std::string, std::pair<double, double>> shown;
  for (const auto& p : description.min.doubles) shown[p.name].first = p.value;
  for (const auto& p : description.max.doubles) shown[p.name].second = p.value;
  for (const auto& p : description.min.ints) shown[p.name].first = p.value;
  for (const auto& p : description.max.ints) shown[p.name].second = p.value;
  int checked = 0;
  for (const auto& range : nf::node::numericParameterRanges()) {
    if (!nf::node::isDynamicParameter(range.name)) continue;
    ASSERT_EQ(shown.count(range.name), 1u) << range.name;
    const auto [lo, hi] = shown[range.name];
    EXPECT_TRUE(std::isfinite(lo) && std::isfinite(hi)) << range.name;
    EXPECT_EQ(hi, range.max) << range.name;
    EXPECT_EQ(lo, range.min < 1e-300 ? 0.0 : range.min) << range.name;
    ++checked;
  }
  EXPECT_GE(checked, 39);  // 31 settings and 8 input weights
  EXPECT_EQ(shown["edge_w_min"], std::make_pair(0.0, 1.0));
}

/// The node's dynamic_reconfigure service: reads the configuration when made,
/// sets values, and puts the configuration back when it goes.
class Reconfigure {
 public:
  Reconfigure() : service_(nodeName() + "/set_parameters") {
    ok_ = ros::service::waitForService(service_, 5000) &&
          ros::service::call(service_, original_);
  }
  ~Reconfigure() {
    dynamic_reconfigure::Reconfigure restore;
    restore.request.config = original_.response.config;
    EXPECT_TRUE(ros::service::call(service_, restore));
  }
  bool ok() const { return ok_; }
  /// Sends one value; returns the configuration the node answers with.
  dynamic_reconfigure::Config set(const std::string& name, double value) {
    dynamic_reconfigure::Reconfigure srv;
    dynamic_reconfigure::DoubleParameter p;
    p.name = name;
    p.value = value;
    srv.request.config.doubles.push_back(p);
    EXPECT_TRUE(ros::service::call(service_, srv)) << name;
    return srv.response.config;
  }
  dynamic_reconfigure::Config set(const std::string& name,
                                  const std::string& value) {
    dynamic_reconfigure::Reconfigure srv;
    dynamic_reconfigure::StrParameter p;
    p.name = name;
    p.value = value;
    srv.request.config.strs.push_back(p);
    EXPECT_TRUE(ros::service::call(service_, srv)) << name;
    return srv.response.config;
  }

 private:
  std::string service_;
  dynamic_reconfigure::Reconfigure original_;
  bool ok_ = false;
};

/// The configuration as a map name -> value text, for comparisons.
std::map<std::string, std::string> configValues(
    const dynamic_reconfigure::Config& config) {
  std::map<std::string, std::string> values;
  for (const auto& p : config.bools) values[p.name] = p.value ? "1" : "0";
  for (const auto& p : config.ints) values[p.name] = std::to_string(p.value);
  for (const auto& p : config.doubles) {
    std::ostringstream text;
    text << p.value;
    values[p.name] = text.str();
  }
  for (const auto& p : config.strs) values[p.name] = "'" + p.value + "'";
  return values;
}

/// One invalid value through dynamic_reconfigure is refused alone: every
/// other setting keeps its value (a live stream keeps its budget); accepted
/// extreme values still give output.
TEST(Node, AnInvalidReconfigureValueLeavesEveryOtherSetting) {
  if (compareMode()) GTEST_SKIP();
  NodeClient client("");
  LogCollector logs;
  client.listen(false, false, true);
  ASSERT_TRUE(waitFor([&] { return client.inputSubscribers() == 4; }, 5.0));
  Reconfigure reconfigure;
  ASSERT_TRUE(reconfigure.ok());
  auto set = [&](const std::string& name, double value) {
    return reconfigure.set(name, value);
  };
  // A live stream's budget first.
  const auto live = configValues(set("time_budget_ms", 33.0));
  ASSERT_EQ(live.at("time_budget_ms"), "33");
  const double inf = std::numeric_limits<double>::infinity();
  const double nan = std::numeric_limits<double>::quiet_NaN();
  for (const auto& [name, value] : std::vector<std::pair<std::string, double>>{
           {"huber_eps", inf},
           {"edge_smoothing_sigma", inf},
           {"edge_smoothing_sigma", 1e4},
           {"weight_0", inf},
           {"time_budget_ms", -1.0},
           {"time_budget_ms", nan}}) {
    const auto after = configValues(set(name, value));
    EXPECT_EQ(after, live) << name << " = " << value
                           << " changed the configuration";
    EXPECT_TRUE(waitFor(
        [&] {
          return logs.seen(rosgraph_msgs::Log::WARN, {"'" + name + "' = "});
        },
        2.0))
        << "no warning names " << name;
    const auto m = client.messagesFor(sceneFrame(), newStamp());
    ASSERT_TRUE(answered(client, m)) << "no output after " << name;
    EXPECT_GT(client.stats(m.image->header.stamp)->solve_time, 0.0);
  }
  // Accepted extremes: the largest pre-smoothing, a huge input weight, a
  // budget of 1 ms.
  for (const auto& [name, value] : std::vector<std::pair<std::string, double>>{
           {"edge_smoothing_sigma", 10.0},
           {"weight_0", 1e6},
           {"time_budget_ms", 1.0}}) {
    auto after = configValues(set(name, value));
    std::ostringstream text;
    text << value;
    EXPECT_EQ(after.at(name), text.str()) << name << " was not accepted";
    const auto m = client.messagesFor(sceneFrame(), newStamp());
    ASSERT_TRUE(answered(client, m, 10.0)) << "no output with " << name;
  }
}

/// fixed_frame naming a frame that tf does not know: the warning names the
/// parameter, and frames are still answered (cold-started).
TEST(Node, AnUnknownFixedFrameIsNamedInTheWarning) {
  if (compareMode()) GTEST_SKIP();
  NodeClient client("");
  LogCollector logs;
  client.listen(false, false, true);
  ASSERT_TRUE(waitFor([&] { return client.inputSubscribers() == 4; }, 5.0));
  Reconfigure reconfigure;
  ASSERT_TRUE(reconfigure.ok());
  reconfigure.set("fixed_frame", std::string("no_such_frame"));
  for (int k = 0; k < 3; ++k) {
    EXPECT_TRUE(answered(client, client.messagesFor(sceneFrame(), newStamp())));
  }
  EXPECT_TRUE(waitFor(
      [&] {
        return logs.seen(rosgraph_msgs::Log::WARN,
                         {"fixed_frame 'no_such_frame'"});
      },
      2.0));
}

TEST(Node, RotationCompensatedWarmStartAndInputAveragesWithTf) {
  if (compareMode()) GTEST_SKIP();
  NodeClient client("");
  client.listen(false, false, true);
  ASSERT_TRUE(waitFor([&] { return client.inputSubscribers() == 4; }, 5.0));
  const std::string service = nodeName() + "/set_parameters";
  ASSERT_TRUE(ros::service::waitForService(service, 5000));
  dynamic_reconfigure::Reconfigure current;
  ASSERT_TRUE(ros::service::call(service, current));
  dynamic_reconfigure::Reconfigure srv;
  dynamic_reconfigure::StrParameter frame;
  frame.name = "fixed_frame";
  frame.value = "world";
  srv.request.config.strs.push_back(frame);
  dynamic_reconfigure::DoubleParameter timeout;
  timeout.name = "tf_timeout";
  timeout.value = 1.0;
  srv.request.config.doubles.push_back(timeout);
  dynamic_reconfigure::IntParameter averaging;
  averaging.name = "temporal_frames";
  averaging.value = 8;
  srv.request.config.ints.push_back(averaging);
  ASSERT_TRUE(ros::service::call(service, srv));
  tf2_ros::TransformBroadcaster broadcaster;
  ros::WallDuration(0.5).sleep();  // the node's tf listener connects
  const auto sequence =
      nf::synthetic::renderSequence(0, kWidth, kHeight, 3, 2.0, 30.0);
  for (std::size_t k = 0; k < sequence.size(); ++k) {
    const double stamp = newStamp(1.0 / 30.0);
    broadcaster.sendTransform(nf::test::cameraInWorld(sequence[k].pose, stamp));
    const auto m =
        client.messagesFor(nf::test::noisyFrame(sequence[k], 70 + k), stamp);
    ASSERT_TRUE(answered(client, m)) << "frame " << k;
    const auto stats = client.stats(m.image->header.stamp);
    EXPECT_EQ(stats->warm_started, k > 0) << "frame " << k;
    EXPECT_EQ(stats->rotation_compensated, k > 0) << "frame " << k;
    EXPECT_EQ(stats->inputs_averaged, k > 0) << "frame " << k;
    EXPECT_GT(stats->input_average_time, 0.0) << "frame " << k;
  }
  dynamic_reconfigure::Reconfigure restore;
  restore.request.config = current.response.config;
  ASSERT_TRUE(ros::service::call(service, restore));
}

// Two nodes (the nodelet and the standalone node) fed the same frames give
// the same fused maps and statistics.
TEST(Compare, NodeletAndStandaloneNodeGiveTheSameOutputs) {
  std::string namespaces;
  if (!ros::NodeHandle("~").getParam("compare_namespaces", namespaces)) {
    GTEST_SKIP();
  }
  const std::string a = namespaces.substr(0, namespaces.find(' '));
  const std::string b = namespaces.substr(namespaces.find(' ') + 1);
  NodeClient first(a), second(b);
  first.listen(true, false, true);
  second.listen(true, false, true);
  ASSERT_TRUE(waitFor(
      [&] {
        return first.inputSubscribers() == 4 && second.inputSubscribers() == 4;
      },
      5.0));
  const auto sequence =
      nf::synthetic::renderSequence(2, kWidth, kHeight, 4, 0.3, 30.0);
  for (std::size_t k = 0; k < sequence.size(); ++k) {
    const nf::test::NoisyFrame f = nf::test::noisyFrame(sequence[k], 50 + k);
    const auto m = first.messagesFor(f, newStamp(1.0 / 30.0));
    const ros::Time stamp = m.image->header.stamp;
    ASSERT_TRUE(answered(first, m));
    ASSERT_TRUE(answered(second, m));
    ASSERT_TRUE(waitFor(
        [&] { return first.fused(stamp) && second.fused(stamp); }, 2.0));
    const auto s1 = first.stats(stamp), s2 = second.stats(stamp);
    EXPECT_EQ(s1->inner_iterations, s2->inner_iterations);
    EXPECT_EQ(s1->outer_iterations, s2->outer_iterations);
    EXPECT_EQ(s1->warm_started, s2->warm_started);
    EXPECT_NEAR(s1->final_energy, s2->final_energy,
                1e-6 * std::abs(s1->final_energy));
    const nf::NormalMap n1 = nf::test::normalsFromImage(*first.fused(stamp));
    const nf::NormalMap n2 = nf::test::normalsFromImage(*second.fused(stamp));
    double worst = 0.0;
    for (int c = 0; c < 3; ++c) {
      for (std::size_t i = 0; i < n1.pixelCount(); ++i) {
        worst = std::max(worst, static_cast<double>(
                                    std::abs(n1.plane(c)[i] - n2.plane(c)[i])));
      }
    }
    EXPECT_LT(worst, 1e-5) << "frame " << k;
  }
}

}  // namespace

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "test_normal_fusion_node");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  const int result = RUN_ALL_TESTS();
  spinner.stop();
  ros::shutdown();
  return result;
}
