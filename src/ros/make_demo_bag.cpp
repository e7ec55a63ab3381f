// make_demo_bag: the demo's input bag, holding what an RGB-D camera driver
// records and nothing computed.
//
//   make_demo_bag --output IN.bag [--castel DIR | --synthetic [--size WxH]]
//                 [--frames N] [--ground-truth GT.bag]
//
// Topics, named as a RealSense driver names them, all stamped at 30 Hz (the
// colour image and the depth of a frame share the header stamp; the depth is
// written 2 ms later in bag time, as a receiver gets it later):
//   /camera/color/image_raw      the colour camera's image
//   /camera/color/camera_info    its intrinsics (frame
//                                camera_color_optical_frame)
//   /camera/depth/image_rect_raw the depth camera's depth, 16UC1 millimetres
//                                (0 = none), as the driver publishes it
//   /camera/depth/camera_info    its intrinsics (camera_depth_optical_frame)
//   /tf_static                   camera_color_optical_frame <-
//                                camera_depth_optical_frame (latched)
//   /tf                          world <- camera_color_optical_frame per
//                                frame, only where the sequence has poses
//
// Real data (default when present): the ViSP castel sequence of Debian's
// visp-images-data package, 30 frames of an Intel SR300: the 640x480 grey
// image as recorded (mono8), the 640x480 depth (its 1/8 mm units rounded to
// millimetres), both intrinsics and the depth-to-colour extrinsic of
// depth_M_color.txt. The sequence has no camera poses, so no /tf.
//
// Synthetic (--synthetic, or when the data is missing): a slowly moving
// ray-cast room (default 320x240): the colour camera's rgb8 image, and the
// depth rendered from a depth camera 25 mm to its right (same intrinsics),
// with a depth camera's noise (sigma_z growing with z^2, millimetre steps,
// dropouts); /tf holds the colour camera's pose in the room, and the exact
// normals of the colour camera go to --ground-truth (/normals_gt).
#include <rosbag/bag.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <tf2/LinearMath/Matrix3x3.h>
#include <tf2/LinearMath/Quaternion.h>
#include <tf2_msgs/TFMessage.h>

#include <algorithm>
#include <boost/make_shared.hpp>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <string>
#include <vector>

#include "eval/castle.h"
#include "eval/synthetic.h"
#include "normal_fusion/errors.h"
#include "normal_fusion/geometry.h"
#include "normal_fusion/ros/conversions.h"

namespace nf = normal_fusion;

namespace {

constexpr double kFps = 30.0;
constexpr double kFirstStamp = 1000.0;
/// Bag time of a frame's depth after its colour image (s).
constexpr double kDepthDelayS = 0.002;
/// The synthetic depth camera's centre in the colour camera's frame (m).
constexpr double kSyntheticBaselineM = 0.025;
const char* const kColorFrame = "camera_color_optical_frame";
const char* const kDepthFrame = "camera_depth_optical_frame";

const char* const kUsage =
    "usage: make_demo_bag --output IN.bag [--castel DIR | --synthetic "
    "[--size WxH]]\n"
    "                     [--frames N] [--ground-truth GT.bag]\n"
    "Writes what an RGB-D driver records for the normal_fusion demo:\n"
    "/camera/color/image_raw, /camera/color/camera_info,\n"
    "/camera/depth/image_rect_raw (16UC1 mm), /camera/depth/camera_info,\n"
    "/tf_static (depth to colour) and, with camera poses, /tf.\n";

ros::Time stampOf(int k) { return ros::Time(kFirstStamp + k / kFps); }

sensor_msgs::CameraInfo cameraInfo(const std_msgs::Header& header,
                                   const nf::CameraIntrinsics& K, int width,
                                   int height) {
  sensor_msgs::CameraInfo info;
  info.header = header;
  info.width = width;
  info.height = height;
  info.distortion_model = "plumb_bob";
  info.D.assign(5, 0.0);
  for (int i = 0; i < 9; ++i) info.K[i] = K.K[i];
  info.R = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  info.P = {K.K[0], 0, K.K[2], 0, 0, K.K[4], K.K[5], 0, 0, 0, 1, 0};
  return info;
}

/// A pose as a tf transform parent <- child: T_parent_child maps child points
/// into the parent frame.
geometry_msgs::TransformStamped transformOf(const nf::Pose& T_parent_child,
                                            const std::string& parent,
                                            const std::string& child,
                                            const ros::Time& stamp) {
  const nf::Mat3& R = T_parent_child.R;
  const tf2::Matrix3x3 R_tf(R[0], R[1], R[2], R[3], R[4], R[5], R[6], R[7],
                            R[8]);
  tf2::Quaternion q;
  R_tf.getRotation(q);
  geometry_msgs::TransformStamped T;
  T.header.stamp = stamp;
  T.header.frame_id = parent;
  T.child_frame_id = child;
  T.transform.translation.x = T_parent_child.t[0];
  T.transform.translation.y = T_parent_child.t[1];
  T.transform.translation.z = T_parent_child.t[2];
  T.transform.rotation.x = q.x();
  T.transform.rotation.y = q.y();
  T.transform.rotation.z = q.z();
  T.transform.rotation.w = q.w();
  return T;
}

struct DriverBag {
  rosbag::Bag bag;

  /// The depth-to-colour transform, latched as a driver's static publisher
  /// advertises it, just before the first frame so that it is there first.
  void writeStaticTransform(const nf::Pose& T_color_depth) {
    const ros::Time stamp = stampOf(0) - ros::Duration(0.001);
    tf2_msgs::TFMessage tf;
    tf.transforms.push_back(
        transformOf(T_color_depth, kColorFrame, kDepthFrame, stamp));
    auto header = boost::make_shared<ros::M_string>();
    (*header)["type"] = ros::message_traits::datatype(tf);
    (*header)["md5sum"] = ros::message_traits::md5sum(tf);
    (*header)["message_definition"] = ros::message_traits::definition(tf);
    (*header)["callerid"] = "/camera/realsense2_camera_manager";
    (*header)["latching"] = "1";
    bag.write("/tf_static", stamp, tf, header);
  }

  /// The colour camera's pose in the world at frame k.
  void writeCameraMotion(int k, const nf::Pose& T_color_world) {
    tf2_msgs::TFMessage tf;
    tf.transforms.push_back(transformOf(nf::inverse(T_color_world), "world",
                                        kColorFrame, stampOf(k)));
    bag.write("/tf", stampOf(k), tf);
  }

  void writeFrame(int k, const cv::Mat& grey_or_rgb,
                  const nf::CameraIntrinsics& K_color,
                  const nf::ScalarMap& depth_m,
                  const nf::CameraIntrinsics& K_depth) {
    std_msgs::Header header;
    header.stamp = stampOf(k);
    header.seq = k;
    header.frame_id = kColorFrame;
    sensor_msgs::Image image;
    image.header = header;
    image.width = grey_or_rgb.cols;
    image.height = grey_or_rgb.rows;
    image.encoding = grey_or_rgb.channels() == 1 ? "mono8" : "rgb8";
    image.step =
        static_cast<std::uint32_t>(grey_or_rgb.cols * grey_or_rgb.channels());
    image.data.resize(static_cast<std::size_t>(image.step) * image.height);
    for (int y = 0; y < grey_or_rgb.rows; ++y) {
      std::memcpy(&image.data[y * image.step], grey_or_rgb.ptr(y), image.step);
    }
    const sensor_msgs::CameraInfo color_info =
        cameraInfo(header, K_color, image.width, image.height);

    header.frame_id = kDepthFrame;
    sensor_msgs::Image depth;
    depth.header = header;
    depth.width = depth_m.width();
    depth.height = depth_m.height();
    depth.encoding = "16UC1";
    depth.step = static_cast<std::uint32_t>(2 * depth.width);
    depth.data.resize(static_cast<std::size_t>(depth.step) * depth.height);
    for (std::size_t i = 0; i < depth_m.pixelCount(); ++i) {
      const float z = depth_m.plane(0)[i];
      const long mm =
          std::isfinite(z) && z > 0.0f ? std::lround(1000.0 * z) : 0;
      const std::uint16_t value =
          static_cast<std::uint16_t>(std::min<long>(mm, 65535));
      std::memcpy(&depth.data[2 * i], &value, 2);  // little-endian host
    }
    const sensor_msgs::CameraInfo depth_info =
        cameraInfo(header, K_depth, depth.width, depth.height);

    // The depth a little after the colour in bag time (its header keeps the
    // frame's stamp), so that a player delivers the colour camera_info that
    // the registration needs before the frame's depth.
    const ros::Time depth_time = header.stamp + ros::Duration(kDepthDelayS);
    bag.write("/camera/color/camera_info", header.stamp, color_info);
    bag.write("/camera/color/image_raw", header.stamp, image);
    bag.write("/camera/depth/camera_info", depth_time, depth_info);
    bag.write("/camera/depth/image_rect_raw", depth_time, depth);
  }
};

int castel(const std::string& dir, const std::string& output, int frames) {
  const std::string seq = dir + "/castel/";
  const nf::CameraIntrinsics K_color =
      nf::castle::readIntrinsics(dir + "/chateau.xml");
  const nf::CameraIntrinsics K_depth =
      nf::castle::readIntrinsics(dir + "/chateau_depth.xml");
  // color_M_depth = depth_M_color^-1.
  const nf::Pose T_color_depth =
      nf::inverse(nf::castle::readPose(dir + "/depth_M_color.txt"));
  DriverBag writer;
  writer.bag.open(output, rosbag::bagmode::Write);
  writer.writeStaticTransform(T_color_depth);
  int written = 0;
  for (int k = 0; k < frames; ++k) {
    char name[64];
    std::snprintf(name, sizeof(name), "image_%04d.pgm", k);
    const cv::Mat grey = cv::imread(seq + name, cv::IMREAD_GRAYSCALE);
    if (grey.empty()) break;
    std::snprintf(name, sizeof(name), "depth_image_%04d.bin", k);
    const nf::ScalarMap depth_m =
        nf::castle::readDepth(seq + name, nf::castel::kDepthScaleM);
    writer.writeFrame(k, grey, K_color, depth_m, K_depth);
    ++written;
  }
  writer.bag.close();
  if (written == 0) throw nf::InputError(seq + ": no frame found");
  std::printf(
      "make_demo_bag: %d frames of the ViSP castel sequence (real SR300 data: "
      "grey image, depth, both intrinsics, the depth-to-colour transform) "
      "-> %s\n",
      written, output.c_str());
  return 0;
}

cv::Mat rgbBytes(const nf::ColorImage& image) {
  cv::Mat rgb(image.height(), image.width(), CV_8UC3);
  for (int y = 0; y < image.height(); ++y) {
    for (int x = 0; x < image.width(); ++x) {
      for (int c = 0; c < 3; ++c) {
        rgb.at<cv::Vec3b>(y, x)[c] = static_cast<std::uint8_t>(std::lround(
            255.0f * std::min(std::max(image.at(c, y, x), 0.0f), 1.0f)));
      }
    }
  }
  return rgb;
}

int synthetic(const std::string& output, const std::string& gt_output,
              int frames, int W, int H) {
  const auto sequence =
      nf::synthetic::renderSequence(0, W, H, frames, 0.3, kFps);
  // The depth camera: the colour camera moved by the baseline along its x.
  nf::Pose T_color_depth;
  T_color_depth.t = {kSyntheticBaselineM, 0.0, 0.0};
  const nf::Pose T_depth_color = nf::inverse(T_color_depth);
  DriverBag writer;
  writer.bag.open(output, rosbag::bagmode::Write);
  writer.writeStaticTransform(T_color_depth);
  rosbag::Bag gt;
  if (!gt_output.empty()) gt.open(gt_output, rosbag::bagmode::Write);
  for (int k = 0; k < frames; ++k) {
    const nf::synthetic::Frame& frame = sequence[k];
    nf::Pose T_depth_world;
    T_depth_world.R = nf::multiply(T_depth_color.R, frame.pose.R);
    T_depth_world.t = nf::transformPoint(T_depth_color, frame.pose.t);
    const nf::synthetic::Frame depth_view =
        nf::synthetic::renderScene(0, W, H, T_depth_world);
    // A depth camera's noise: sigma 1.5 mm at 1 m growing with z^2, 1 mm
    // steps, 2 % of the pixels without depth.
    const nf::ScalarMap depth_m = nf::synthetic::addDepthNoise(
        depth_view.depth, 0.0015, nf::synthetic::kDepthQuantizationM, 0.02,
        100 + k);
    writer.writeCameraMotion(k, frame.pose);
    writer.writeFrame(k, rgbBytes(frame.image), frame.K, depth_m, depth_view.K);
    if (!gt_output.empty()) {
      std_msgs::Header header;
      header.stamp = stampOf(k);
      header.frame_id = kColorFrame;
      sensor_msgs::Image msg;
      nf::node::normalsToMessage(frame.normals_gt, header, msg);
      gt.write("/normals_gt", header.stamp, msg);
    }
  }
  writer.bag.close();
  if (!gt_output.empty()) gt.close();
  std::printf(
      "make_demo_bag: %d frames of a SYNTHETIC sequence (ray-cast room, %dx%d: "
      "colour image, noisy depth from a camera 25 mm beside it, camera poses) "
      "-> %s\n",
      frames, W, H, output.c_str());
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  std::string output, dir = nf::castel::kDefaultDirectory, gt_output;
  bool force_synthetic = false;
  int frames = 30, width = 320, height = 240;
  for (int i = 1; i < argc; ++i) {
    const std::string key = argv[i];
    auto value = [&]() -> std::string {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "make_demo_bag: %s needs a value\n%s", key.c_str(),
                     kUsage);
        std::exit(2);
      }
      return argv[++i];
    };
    if (key == "--output") {
      output = value();
    } else if (key == "--castel") {
      dir = value();
    } else if (key == "--synthetic") {
      force_synthetic = true;
    } else if (key == "--frames") {
      frames = std::atoi(value().c_str());
    } else if (key == "--size") {
      const std::string size = value();
      if (std::sscanf(size.c_str(), "%dx%d", &width, &height) != 2 ||
          width < 8 || height < 8 || width > 4096 || height > 4096) {
        std::fprintf(stderr,
                     "make_demo_bag: --size %s: expected WxH, 8 to 4096\n%s",
                     size.c_str(), kUsage);
        return 2;
      }
    } else if (key == "--ground-truth") {
      gt_output = value();
    } else if (key == "--help") {
      std::fputs(kUsage, stdout);
      return 0;
    } else {
      std::fprintf(stderr, "make_demo_bag: unknown option %s\n%s", key.c_str(),
                   kUsage);
      return 2;
    }
  }
  if (output.empty() || frames < 1) {
    std::fprintf(stderr, "make_demo_bag: --output is required\n%s", kUsage);
    return 2;
  }
  ros::Time::init();
  try {
    const bool have_castel =
        std::ifstream(dir + "/castel/image_0000.pgm").good();
    if (!force_synthetic && have_castel) return castel(dir, output, frames);
    if (!force_synthetic) {
      std::printf(
          "make_demo_bag: the ViSP castel data is not installed at %s "
          "(package visp-images-data); using a synthetic sequence instead\n",
          dir.c_str());
    }
    return synthetic(output, gt_output, frames, width, height);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "make_demo_bag: %s\n", e.what());
    return 1;
  }
}
