// rostest of the running node (nodelet or normal_fusion_node): lazy
// subscription, an output for every synchronized set with the input's stamp,
// accuracy, warm start, bad inputs, dynamic_reconfigure, missing inputs.
// With ~compare_namespaces set, it checks instead that two nodes in those
// namespaces (the nodelet and the standalone node) give the same outputs.
#include <diagnostic_msgs/DiagnosticArray.h>
#include <dynamic_reconfigure/Reconfigure.h>
#include <gtest/gtest.h>
#include <normal_fusion/FusionStats.h>
#include <ros/master.h>
#include <ros/network.h>
#include <ros/ros.h>
#include <rosgraph_msgs/Log.h>
#include <tf2_ros/transform_broadcaster.h>
#include <xmlrpcpp/XmlRpc.h>

#include <cstdint>
#include <fstream>
#include <functional>
#include <map>
#include <mutex>
#include <thread>

#include "normal_fusion/metrics.h"
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
TEST(Node, RunsWithTheLaunchFilesWaitPolicy) {
  if (compareMode()) GTEST_SKIP();
  std::string process_node;
  ASSERT_TRUE(ros::NodeHandle("~").getParam("process_node", process_node));
  XmlRpc::XmlRpcValue args, result, payload;
  args[0] = ros::this_node::getName();
  args[1] = process_node;
  ASSERT_TRUE(ros::master::execute("lookupNode", args, result, payload, true))
      << process_node;
  std::string host, uri = static_cast<std::string>(payload);
  std::uint32_t port = 0;
  ASSERT_TRUE(ros::network::splitURI(uri, host, port)) << uri;
  XmlRpc::XmlRpcClient client(host.c_str(), static_cast<int>(port), "/");
  XmlRpc::XmlRpcValue pid_args, pid_result;
  pid_args[0] = ros::this_node::getName();
  ASSERT_TRUE(client.execute("getPid", pid_args, pid_result)) << uri;
  ASSERT_EQ(static_cast<int>(pid_result[0]), 1) << uri;
  const int pid = static_cast<int>(pid_result[2]);
  std::ifstream environ("/proc/" + std::to_string(pid) + "/environ",
                        std::ios::binary);
  ASSERT_TRUE(environ.good()) << pid;
  std::string entry, policy = "(not set)";
  while (std::getline(environ, entry, '\0')) {
    if (entry.rfind("OMP_WAIT_POLICY=", 0) == 0) policy = entry.substr(16);
  }
  EXPECT_EQ(policy, "passive") << process_node << " (pid " << pid << ")";
}

TEST(Node, PublishesDiagnostics) {
  if (compareMode()) GTEST_SKIP();
  std::mutex mutex;
  std::map<std::string, std::string> values;
  std::string name;
  ros::NodeHandle nh;
  ros::Subscriber sub = nh.subscribe<diagnostic_msgs::DiagnosticArray>(
      "/diagnostics", 10,
      [&](const diagnostic_msgs::DiagnosticArrayConstPtr& m) {
        std::lock_guard<std::mutex> lock(mutex);
        for (const auto& status : m->status) {
          if (status.name.find("normal_fusion") == std::string::npos) continue;
          name = status.name;
          for (const auto& kv : status.values) values[kv.key] = kv.value;
        }
      });
  ASSERT_TRUE(waitFor(
      [&] {
        std::lock_guard<std::mutex> lock(mutex);
        return values.count("frames processed") > 0;
      },
      5.0));
  std::lock_guard<std::mutex> lock(mutex);
  EXPECT_GT(std::stoi(values["frames processed"]), 0) << name;
  for (const char* key :
       {"output rate (Hz, last 5 s)", "mean latency (s, last 5 s)",
        "frames dropped (worker busy)", "frames skipped (bad input)",
        "last error"}) {
    EXPECT_EQ(values.count(key), 1u) << key;
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
  struct Case {
    const char* what;
    std::function<void(Messages&)> spoil;
    std::vector<std::string> logged;
  };
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const std::vector<Case> cases = {
      {"unsupported encoding",
       [](Messages& m) { m.image->encoding = "yuv422"; },
       {"/image", "unsupported encoding 'yuv422'"}},
      {"size mismatch",
       [&](Messages& m) {
         const nf::NormalMap wide(kWidth, kHeight / 2, 3, 0.0f);
         nf::NormalMap w = wide;
         for (std::size_t i = 0; i < w.pixelCount(); ++i) w.plane(2)[i] = -1;
         m.normals[1] = normalsMessage(w, m.image->header);
       },
       {"/normals_1", "aspect ratio"}},
      {"step and size inconsistent",
       [](Messages& m) { m.normals[0]->data.resize(100); },
       {"/normals_0", "height * step"}},
      {"all-NaN map",
       [&](Messages& m) {
         m.normals[0] = normalsMessage(nf::NormalMap(kWidth, kHeight, 3, nan),
                                       m.image->header);
       },
       {"/normals_0", "no valid normal"}},
      {"non-unit vectors",
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
      {"zero K",
       [](Messages& m) { m.info->K.fill(0.0); },
       {"/camera_info", "expected K"}},
      {"non-finite K",
       [](Messages& m) {
         m.info->K[2] = std::numeric_limits<double>::infinity();
       },
       {"/camera_info", "not finite"}},
      {"missing camera_info",
       [](Messages& m) { m.info.reset(); },
       {"/camera_info", "no camera_info for the image"}},
      {"zero stamp",
       [](Messages& m) { m.image->header.stamp = ros::Time(); },
       {"/image", "stamp is zero"}},
  };
  for (const Case& c : cases) {
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
  // Out of order: an image older than the last one on its topic.
  Messages old = client.messagesFor(f, next_stamp - 0.5);
  old.info.reset();
  old.normals[0].reset();
  old.normals[1].reset();
  client.publish(old);
  EXPECT_TRUE(answered(client, client.messagesFor(f, newStamp(1.0))));
  EXPECT_TRUE(waitFor(
      [&] {
        return logs.seen(rosgraph_msgs::Log::ERROR, {"/image", "out of order"});
      },
      2.0));
  const auto last = client.stats(ros::Time(next_stamp));
  ASSERT_TRUE(last);
  EXPECT_GE(last->frames_skipped, cases.size());
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
  d.value = 5.0;  // invalid: corrected to 1 with a warning naming it
  srv.request.config.doubles.push_back(d);
  ASSERT_TRUE(ros::service::call(service, srv));
  bool corrected = false;
  for (const auto& q : srv.response.config.doubles) {
    if (q.name == "edge_w_min") corrected = q.value == 1.0;
  }
  EXPECT_TRUE(corrected);
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
