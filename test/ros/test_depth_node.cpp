// rostest of the running depth_to_normals node (nodelet or standalone):
// lazy subscription, normals and confidence for each depth frame (facing the
// camera, NaN where depth is 0, the depth's header), REP 118 units, and bad
// depth messages that leave it alive to answer the next good frame.
#include <gtest/gtest.h>
#include <ros/ros.h>
#include <rosgraph_msgs/Log.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>

#include <boost/make_shared.hpp>
#include <cmath>
#include <cstring>
#include <functional>
#include <limits>
#include <map>
#include <mutex>
#include <string>
#include <vector>

#include "eval/synthetic.h"
#include "normal_fusion/metrics.h"
#include "ros_test_util.h"

namespace nf = normal_fusion;

namespace {

constexpr int kWidth = 64, kHeight = 48;
const float kNaN = std::numeric_limits<float>::quiet_NaN();

bool waitFor(const std::function<bool()>& done, double seconds) {
  const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(seconds);
  while (ros::WallTime::now() < end) {
    if (done()) return true;
    ros::WallDuration(0.01).sleep();
  }
  return done();
}

/// A depth frame as 16UC1 (millimetres) or 32FC1 (metres).
sensor_msgs::ImagePtr depthMessage(const nf::ScalarMap& depth_m,
                                   const std_msgs::Header& header,
                                   bool millimetres) {
  auto msg = boost::make_shared<sensor_msgs::Image>();
  msg->header = header;
  msg->width = depth_m.width();
  msg->height = depth_m.height();
  msg->encoding = millimetres ? "16UC1" : "32FC1";
  msg->step = msg->width * (millimetres ? 2 : 4);
  msg->data.resize(static_cast<std::size_t>(msg->step) * msg->height);
  for (std::size_t i = 0; i < depth_m.pixelCount(); ++i) {
    const float z = depth_m.data()[i];
    if (millimetres) {
      const std::uint16_t mm =
          std::isfinite(z) ? static_cast<std::uint16_t>(std::lround(z * 1000))
                           : 0;
      std::memcpy(&msg->data[2 * i], &mm, 2);
    } else {
      std::memcpy(&msg->data[4 * i], &z, 4);
    }
  }
  return msg;
}

/// Publishers of the node's inputs, collectors of its outputs and of /rosout.
class Client {
 public:
  Client() {
    depth_ = nh_.advertise<sensor_msgs::Image>("depth", 10);
    info_ = nh_.advertise<sensor_msgs::CameraInfo>("camera_info", 10);
    log_sub_ = nh_.subscribe<rosgraph_msgs::Log>(
        "/rosout", 200, [this](const rosgraph_msgs::LogConstPtr& m) {
          std::lock_guard<std::mutex> lock(mutex_);
          logs_.push_back(*m);
        });
  }
  void listen(bool normals, bool confidence) {
    if (normals) {
      normals_sub_ = nh_.subscribe<sensor_msgs::Image>(
          "normals", 20, [this](const sensor_msgs::ImageConstPtr& m) {
            std::lock_guard<std::mutex> lock(mutex_);
            normals_[m->header.stamp] = m;
          });
    }
    if (confidence) {
      confidence_sub_ = nh_.subscribe<sensor_msgs::Image>(
          "confidence", 20, [this](const sensor_msgs::ImageConstPtr& m) {
            std::lock_guard<std::mutex> lock(mutex_);
            confidence_[m->header.stamp] = m;
          });
    }
  }
  void stopListening() {
    normals_sub_.shutdown();
    confidence_sub_.shutdown();
  }
  int inputSubscribers() const {
    return depth_.getNumSubscribers() + info_.getNumSubscribers();
  }
  struct Frame {
    sensor_msgs::ImagePtr depth;
    sensor_msgs::CameraInfoPtr info;
  };
  void publish(const Frame& f) {
    if (f.info) info_.publish(f.info);
    if (f.depth) depth_.publish(f.depth);
  }
  sensor_msgs::ImageConstPtr normals(const ros::Time& stamp) {
    std::lock_guard<std::mutex> lock(mutex_);
    auto it = normals_.find(stamp);
    return it == normals_.end() ? nullptr : it->second;
  }
  sensor_msgs::ImageConstPtr confidence(const ros::Time& stamp) {
    std::lock_guard<std::mutex> lock(mutex_);
    auto it = confidence_.find(stamp);
    return it == confidence_.end() ? nullptr : it->second;
  }
  /// True once an ERROR contains every part.
  bool logged(const std::vector<std::string>& parts) {
    std::lock_guard<std::mutex> lock(mutex_);
    for (const auto& log : logs_) {
      if (log.level < rosgraph_msgs::Log::ERROR) continue;
      bool all = true;
      for (const auto& p : parts) {
        all = all && log.msg.find(p) != std::string::npos;
      }
      if (all) return true;
    }
    return false;
  }

 private:
  ros::NodeHandle nh_;
  ros::Publisher depth_, info_;
  std::mutex mutex_;
  std::map<ros::Time, sensor_msgs::ImageConstPtr> normals_, confidence_;
  std::vector<rosgraph_msgs::Log> logs_;
  // Declared last so that they are destroyed first: a callback still arriving
  // on the spinner's threads never finds the data it writes to destroyed.
  ros::Subscriber normals_sub_, confidence_sub_, log_sub_;
};

const nf::synthetic::Frame& scene() {
  static const nf::synthetic::Frame frame = [] {
    nf::synthetic::Frame f = nf::synthetic::renderScene(0, kWidth, kHeight);
    // A hole without depth.
    for (int y = 20; y < 24; ++y) {
      for (int x = 30; x < 34; ++x) f.depth.at(0, y, x) = kNaN;
    }
    return f;
  }();
  return frame;
}

double next_stamp = 200.0;
std_msgs::Header newHeader() {
  std_msgs::Header h;
  next_stamp += 0.1;
  h.stamp = ros::Time(next_stamp);
  h.frame_id = "camera_depth_optical_frame";
  return h;
}

Client::Frame goodFrame(bool millimetres = true) {
  const std_msgs::Header h = newHeader();
  return {depthMessage(scene().depth, h, millimetres),
          nf::test::cameraInfoMessage(scene().K, kWidth, kHeight, h)};
}

nf::NormalMap normalsOf(const sensor_msgs::Image& msg) {
  nf::NormalMap n(msg.width, msg.height, 3);
  for (std::size_t i = 0; i < n.pixelCount(); ++i) {
    float v[3];
    std::memcpy(v, &msg.data[12 * i], sizeof(v));
    for (int c = 0; c < 3; ++c) n.plane(c)[i] = v[c];
  }
  return n;
}

/// Under test/ros/rgbd.test (~rgbd true) only the Rgbd test runs.
bool rgbdMode() {
  bool rgbd = false;
  ros::NodeHandle("~").getParam("rgbd", rgbd);
  return rgbd;
}

bool answered(Client& client, const Client::Frame& f, double seconds = 5.0) {
  client.publish(f);
  const ros::Time stamp = f.depth->header.stamp;
  return waitFor([&] { return client.normals(stamp) != nullptr; }, seconds);
}

TEST(DepthNode, SubscribesOnlyWhileSomeoneListens) {
  if (rgbdMode()) GTEST_SKIP();
  Client client;
  ros::WallDuration(1.0).sleep();
  EXPECT_EQ(client.inputSubscribers(), 0) << "subscribed with no listener";
  for (int output = 0; output < 2; ++output) {
    client.listen(output == 0, output == 1);
    EXPECT_TRUE(waitFor([&] { return client.inputSubscribers() == 2; }, 5.0))
        << "output " << output;
    client.stopListening();
    EXPECT_TRUE(waitFor([&] { return client.inputSubscribers() == 0; }, 5.0))
        << "still subscribed after the last listener left";
  }
}

TEST(DepthNode, NormalsAndConfidenceForEachFrame) {
  if (rgbdMode()) GTEST_SKIP();
  Client client;
  client.listen(true, true);
  ASSERT_TRUE(waitFor([&] { return client.inputSubscribers() == 2; }, 5.0));
  const nf::synthetic::Frame& f = scene();
  nf::NormalMap by_unit[2];
  for (int millimetres = 0; millimetres < 2; ++millimetres) {
    const Client::Frame frame = goodFrame(millimetres == 1);
    ASSERT_TRUE(answered(client, frame)) << "millimetres " << millimetres;
    const ros::Time stamp = frame.depth->header.stamp;
    ASSERT_TRUE(
        waitFor([&] { return client.confidence(stamp) != nullptr; }, 2.0));
    const auto normals = client.normals(stamp);
    const auto confidence = client.confidence(stamp);
    // The depth's header, 32FC3 / 32FC1 at the depth's size.
    EXPECT_EQ(normals->header.frame_id, frame.depth->header.frame_id);
    EXPECT_EQ(confidence->header.stamp, stamp);
    EXPECT_EQ(normals->encoding, "32FC3");
    EXPECT_EQ(confidence->encoding, "32FC1");
    ASSERT_EQ(normals->width, static_cast<unsigned>(kWidth));
    ASSERT_EQ(normals->height, static_cast<unsigned>(kHeight));
    ASSERT_EQ(confidence->data.size(), 4u * kWidth * kHeight);
    const nf::NormalMap n = normalsOf(*normals);
    by_unit[millimetres] = n;
    int facing = 0, valid = 0;
    for (int y = 0; y < kHeight; ++y) {
      for (int x = 0; x < kWidth; ++x) {
        const float v[3] = {n.at(0, y, x), n.at(1, y, x), n.at(2, y, x)};
        float c;
        std::memcpy(&c, &confidence->data[4 * (y * kWidth + x)], 4);
        EXPECT_TRUE(c >= 0.0f && c <= 1.0f) << c;
        if (!nf::isValidNormal(v[0], v[1], v[2])) {
          EXPECT_EQ(c, 0.0f);
          continue;
        }
        ++valid;
        const double rx = (x - f.K.cx()) / f.K.fx();
        const double ry = (y - f.K.cy()) / f.K.fy();
        facing += v[0] * rx + v[1] * ry + v[2] <= 0.0;
      }
    }
    EXPECT_EQ(facing, valid);
    EXPECT_GT(valid, kWidth * kHeight * 8 / 10);
    // NaN where there is no depth.
    for (int y = 20; y < 24; ++y) {
      for (int x = 30; x < 34; ++x) EXPECT_TRUE(std::isnan(n.at(0, y, x)));
    }
    const nf::AngularErrorStats e = nf::angularError(n, f.normals_gt);
    EXPECT_LT(e.median_deg, 5.0) << "millimetres " << millimetres;
  }
  // 16UC1 millimetres and 32FC1 metres of the same depth: about the same
  // normals (the millimetre rounding aside).
  const nf::AngularErrorStats between =
      nf::angularError(by_unit[0], by_unit[1]);
  EXPECT_LT(between.median_deg, 2.0);
}

/// Under depth_standalone.test (~expect_defaults) the node was started with
/// refused values: the parameter server holds the defaults it uses instead.
TEST(DepthNode, RefusedParametersKeepTheirDefaults) {
  bool expect_defaults = false;
  ros::NodeHandle("~").getParam("expect_defaults", expect_defaults);
  if (rgbdMode() || !expect_defaults) GTEST_SKIP();
  ros::NodeHandle pnh("/depth_to_normals");
  std::string method;
  int window_radius = 0;
  double noise_coefficient = 0.0, edge_distance = 0.0;
  EXPECT_TRUE(pnh.getParam("method", method));
  EXPECT_TRUE(pnh.getParam("window_radius", window_radius));
  EXPECT_TRUE(pnh.getParam("noise_coefficient", noise_coefficient));
  EXPECT_TRUE(pnh.getParam("edge_distance", edge_distance));
  EXPECT_EQ(method, "plane_fit");
  EXPECT_EQ(window_radius, 2);
  EXPECT_DOUBLE_EQ(noise_coefficient, 0.0025);
  EXPECT_DOUBLE_EQ(edge_distance, 3.0);
  bool register_to_rgb = true;
  double tf_timeout = 0.0;
  std::string splat;
  EXPECT_TRUE(pnh.getParam("register_to_rgb", register_to_rgb));
  EXPECT_TRUE(pnh.getParam("tf_timeout", tf_timeout));
  EXPECT_TRUE(pnh.getParam("registration_splat", splat));
  EXPECT_FALSE(register_to_rgb);
  EXPECT_DOUBLE_EQ(tf_timeout, 0.1);
  EXPECT_EQ(splat, "2x2");
}

struct BadCase {
  const char* what;
  std::function<void(Client::Frame&)> spoil;
  std::vector<std::string> logged;
};

std::vector<BadCase> badCases() {
  using F = Client::Frame;
  return {
      {"wrong encoding",
       [](F& f) {
         f.depth->encoding = "rgb8";
         f.depth->step = kWidth * 3;
         f.depth->data.assign(f.depth->step * kHeight, 0);
       },
       {"/depth", "unsupported depth encoding 'rgb8'"}},
      {"unknown encoding",
       [](F& f) { f.depth->encoding = "yuv422"; },
       {"/depth", "unsupported encoding 'yuv422'"}},
      {"data size and step mismatch",
       [](F& f) { f.depth->data.resize(100); },
       {"/depth", "height * step"}},
      {"step shorter than a row",
       [](F& f) { f.depth->step = 8; },
       {"/depth", "step 8 is shorter"}},
      {"all NaN",
       [](F& f) {
         const nf::ScalarMap nan(kWidth, kHeight, 1, kNaN);
         f.depth = depthMessage(nan, f.depth->header, false);
       },
       {"/depth", "no valid depth in the 32FC1"}},
      {"all zero",
       [](F& f) { std::fill(f.depth->data.begin(), f.depth->data.end(), 0); },
       {"/depth", "no valid depth in the 16UC1"}},
      {"camera_info of another size",
       [](F& f) { f.info->width = 320; },
       {"/camera_info", "camera_info is for a 320x"}},
      {"stamp not normalized",
       [](F& f) {
         f.depth->header.stamp.nsec = 1500000000u;
         f.info->header.stamp.nsec = 1500000000u;
       },
       {"/depth", "not normalized"}},
      {"zero stamp",
       [](F& f) { f.depth->header.stamp = ros::Time(); },
       {"/depth", "stamp is zero"}},
      {"absurd focal length",
       [](F& f) { f.info->K[0] = f.info->K[4] = 1e-150; },
       {"/camera_info", "ray of pixel"}},
      {"zero K",
       [](F& f) { f.info->K.fill(0.0); },
       {"/camera_info", "expected K"}},
      {"non-finite K",
       [](F& f) { f.info->K[2] = std::numeric_limits<double>::infinity(); },
       {"/camera_info", "not finite"}},
      {"camera_info in another frame",
       [](F& f) { f.info->header.frame_id = "elsewhere"; },
       {"/camera_info", "frame_id 'elsewhere'"}},
      {"big-endian depth",
       [](F& f) { f.depth->is_bigendian = 1; },
       {"/depth", "big-endian"}},
      {"missing camera_info",
       [](F& f) { f.info.reset(); },
       {"/camera_info", "no camera_info for the depth image"}},
  };
}

TEST(DepthNode, BadDepthIsSkippedAndTheNextGoodFrameAnswered) {
  if (rgbdMode()) GTEST_SKIP();
  Client client;
  client.listen(true, false);
  ASSERT_TRUE(waitFor([&] { return client.inputSubscribers() == 2; }, 5.0));
  ASSERT_TRUE(answered(client, goodFrame()));
  for (const BadCase& c : badCases()) {
    Client::Frame bad = goodFrame();
    const ros::Time bad_stamp = bad.depth->header.stamp;
    c.spoil(bad);
    client.publish(bad);
    // A missing camera_info shows once the next frame's arrives.
    if (std::string(c.what) != "missing camera_info") {
      EXPECT_TRUE(waitFor([&] { return client.logged(c.logged); }, 3.0))
          << c.what << ": no error naming " << c.logged[0] << " and '"
          << c.logged[1] << "'";
    }
    const Client::Frame good = goodFrame();
    EXPECT_TRUE(answered(client, good)) << c.what << ": next frame unanswered";
    EXPECT_FALSE(client.normals(bad_stamp)) << c.what << ": bad frame answered";
    EXPECT_TRUE(waitFor([&] { return client.logged(c.logged); }, 3.0))
        << c.what << ": no error naming " << c.logged[0] << " and '"
        << c.logged[1] << "'";
  }
}

/// launch/rgbd.launch: colour image, its camera_info and the aligned depth
/// in; the fused map of the depth's normals (with their confidence) out.
TEST(Rgbd, DepthNormalsAreFusedGuidedByTheImage) {
  if (!rgbdMode()) GTEST_SKIP();
  ros::NodeHandle nh;
  auto image_pub =
      nh.advertise<sensor_msgs::Image>("/camera/color/image_raw", 5);
  auto info_pub =
      nh.advertise<sensor_msgs::CameraInfo>("/camera/color/camera_info", 5);
  auto depth_pub = nh.advertise<sensor_msgs::Image>(
      "/camera/aligned_depth_to_color/image_raw", 5);
  auto depth_info_pub = nh.advertise<sensor_msgs::CameraInfo>(
      "/camera/aligned_depth_to_color/camera_info", 5);
  std::mutex mutex;
  std::map<ros::Time, sensor_msgs::ImageConstPtr> fused;
  auto sub = nh.subscribe<sensor_msgs::Image>(
      "/fused_normals", 5, [&](const sensor_msgs::ImageConstPtr& m) {
        std::lock_guard<std::mutex> lock(mutex);
        fused[m->header.stamp] = m;
      });
  // The fusion subscribes to the depth normals, they to the depth.
  ASSERT_TRUE(waitFor(
      [&] {
        return image_pub.getNumSubscribers() > 0 &&
               depth_pub.getNumSubscribers() > 0 &&
               depth_info_pub.getNumSubscribers() > 0;
      },
      10.0));
  const nf::synthetic::Frame& f = scene();
  sensor_msgs::ImageConstPtr out;
  std_msgs::Header h;
  for (int k = 0; k < 20 && !out; ++k) {
    h = newHeader();
    auto image = boost::make_shared<sensor_msgs::Image>();
    image->header = h;
    image->width = kWidth;
    image->height = kHeight;
    image->encoding = "rgb8";
    image->step = 3 * kWidth;
    image->data.resize(image->step * kHeight);
    for (int y = 0; y < kHeight; ++y) {
      for (int x = 0; x < kWidth; ++x) {
        for (int c = 0; c < 3; ++c) {
          image->data[y * image->step + 3 * x + c] = static_cast<std::uint8_t>(
              std::lround(255 * std::min(1.0f, f.image.at(c, y, x))));
        }
      }
    }
    info_pub.publish(nf::test::cameraInfoMessage(f.K, kWidth, kHeight, h));
    depth_info_pub.publish(
        nf::test::cameraInfoMessage(f.K, kWidth, kHeight, h));
    depth_pub.publish(depthMessage(f.depth, h, true));
    image_pub.publish(image);
    waitFor(
        [&] {
          std::lock_guard<std::mutex> lock(mutex);
          auto it = fused.find(h.stamp);
          if (it != fused.end()) out = it->second;
          return out != nullptr;
        },
        2.0);
  }
  ASSERT_TRUE(out) << "no fused map";
  EXPECT_EQ(out->header.frame_id, h.frame_id);
  const nf::NormalMap n = normalsOf(*out);
  const nf::AngularErrorStats e = nf::angularError(n, f.normals_gt);
  EXPECT_LT(e.median_deg, 5.0);
  EXPECT_GT(e.pixel_count, kWidth * kHeight * 9 / 10);
}

}  // namespace

int main(int argc, char** argv) {
  return normal_fusion::test::runRosTests(argc, argv,
                                          "test_depth_to_normals_node");
}
