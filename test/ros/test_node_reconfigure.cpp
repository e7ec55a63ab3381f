// rostest of the running node, its settings at run time (part of the gtest
// node test_node): dynamic_reconfigure on the next frame, the numeric ranges
// in the description, an invalid value refused alone, an unknown fixed_frame,
// and the rotation-compensated warm start and input averages from tf.
#include <dynamic_reconfigure/ConfigDescription.h>
#include <dynamic_reconfigure/Reconfigure.h>
#include <gtest/gtest.h>
#include <ros/ros.h>
#include <rosgraph_msgs/Log.h>
#include <tf2_ros/transform_broadcaster.h>

#include <cmath>
#include <limits>
#include <map>
#include <mutex>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include "node_test_util.h"
#include "normal_fusion/ros/parameters.h"

namespace {

using nf::node_test::answered;
using nf::node_test::compareMode;
using nf::node_test::kHeight;
using nf::node_test::kWidth;
using nf::node_test::LogCollector;
using nf::node_test::newStamp;
using nf::node_test::NodeClient;
using nf::node_test::nodeName;
using nf::node_test::sceneFrame;
using nf::node_test::waitFor;

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

}  // namespace
