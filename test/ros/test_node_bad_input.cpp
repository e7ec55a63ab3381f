// rostest of the running node, bad inputs (part of the gtest node test_node):
// a case for every input rule skipped with an error naming the topic and the
// next frame answered, stamps far apart and going back, a seeded fuzz, and
// the warning that names missing inputs.
#include <gtest/gtest.h>
#include <ros/ros.h>
#include <rosgraph_msgs/Log.h>

#include <cstdint>
#include <functional>
#include <limits>
#include <random>
#include <set>
#include <string>
#include <vector>

#include "node_test_util.h"
#include "normal_fusion/ros/conversions.h"

using nf::test::normalsMessage;

namespace {

using nf::node_test::answered;
using nf::node_test::compareMode;
using nf::node_test::kHeight;
using nf::node_test::kWidth;
using nf::node_test::LogCollector;
using nf::node_test::newStamp;
using nf::node_test::next_stamp;
using nf::node_test::NodeClient;
using nf::node_test::sceneFrame;
using nf::node_test::waitFor;

/// One class of bad input: which rule of the node's input checks (see
/// normal_fusion::node::inputRuleNames; "" for the checks of the set as a
/// whole), how a good frame is spoiled, and what the error must say.
struct BadInputCase {
  const char* what;
  const char* rule;
  std::function<void(NodeClient::FrameMessages&)> spoil;
  std::vector<std::string> logged;
};

// Over 80 lines: a table, one entry per case.
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
// Over 80 lines: one seeded sequence, whose messages depend on every draw.
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

}  // namespace
