// make_demo_bag: the demo's input bag, with two normal-map estimates per frame.
//
//   make_demo_bag --output IN.bag [--castel DIR | --synthetic] [--frames N]
//                 [--ground-truth GT.bag]
//
// Real data (default when present): the ViSP castel sequence of Debian's
// visp-images-data package, 30 frames of an Intel SR300 (640x480 grey image,
// 640x480 16-bit depth, intrinsics of both cameras, the depth-to-colour
// extrinsic). Per frame it computes, in the depth camera:
//   normals_0 (fine, noisy): central differences of the raw depth, 640x480;
//   normals_1 (coarse, smooth): the depth median-pooled 4x4 and box-smoothed,
//     then differentiated: 160x120;
// rotates both into the colour camera and registers them into the colour
// image by forward projection with a z-buffer (the depth is moved, not the
// image; unobserved pixels stay NaN). The bag holds /image (mono8, as
// recorded), /camera_info (colour intrinsics), /normals_0 (640x480 32FC3) and
// /normals_1 (160x120 32FC3, the colour intrinsics scaled by 1/4), all stamped
// at 30 Hz.
//
// Synthetic (--synthetic, or when the data is missing): a slowly moving
// ray-cast room at 320x240 with the same two kinds of estimates from a noisy
// depth map, and the exact normals written to --ground-truth.
#include <rosbag/bag.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/image_encodings.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <limits>
#include <opencv2/imgcodecs.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "eval/castle.h"
#include "eval/synthetic.h"
#include "normal_fusion/errors.h"
#include "normal_fusion/geometry.h"
#include "normal_fusion/registration.h"
#include "normal_fusion/ros/conversions.h"

namespace nf = normal_fusion;

namespace {

constexpr double kFps = 30.0;
constexpr double kFirstStamp = 1000.0;
constexpr int kCoarseFactor = 4;
const float kNaN = std::numeric_limits<float>::quiet_NaN();

const char* const kUsage =
    "usage: make_demo_bag --output IN.bag [--castel DIR | --synthetic]\n"
    "                     [--frames N] [--ground-truth GT.bag]\n"
    "Writes /image, /camera_info, /normals_0 (fine, noisy, full size) and\n"
    "/normals_1 (coarse, smooth, 1/4 size) for the normal_fusion demo.\n";

/// Median of the valid depths in each factor x factor block.
nf::ScalarMap poolDepth(const nf::ScalarMap& depth, int factor) {
  const int W = depth.width() / factor, H = depth.height() / factor;
  nf::ScalarMap pooled(W, H, 1, kNaN);
  std::vector<float> block;
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      block.clear();
      for (int dy = 0; dy < factor; ++dy) {
        for (int dx = 0; dx < factor; ++dx) {
          const float z = depth.at(0, y * factor + dy, x * factor + dx);
          if (std::isfinite(z)) block.push_back(z);
        }
      }
      if (static_cast<int>(block.size()) * 2 < factor * factor) continue;
      std::nth_element(block.begin(), block.begin() + block.size() / 2,
                       block.end());
      pooled.at(0, y, x) = block[block.size() / 2];
    }
  }
  return pooled;
}

/// 3x3 mean over valid depths (smooths the pooled depth).
nf::ScalarMap smoothDepth(const nf::ScalarMap& depth) {
  nf::ScalarMap out(depth.width(), depth.height(), 1, kNaN);
  for (int y = 0; y < depth.height(); ++y) {
    for (int x = 0; x < depth.width(); ++x) {
      if (!std::isfinite(depth.at(0, y, x))) continue;
      double sum = 0.0;
      int count = 0;
      for (int dy = -1; dy <= 1; ++dy) {
        for (int dx = -1; dx <= 1; ++dx) {
          const int yy = y + dy, xx = x + dx;
          if (yy < 0 || xx < 0 || yy >= depth.height() || xx >= depth.width()) {
            continue;
          }
          const float z = depth.at(0, yy, xx);
          if (std::isfinite(z)) {
            sum += z;
            ++count;
          }
        }
      }
      out.at(0, y, x) = static_cast<float>(sum / count);
    }
  }
  return out;
}

/// Moves normals computed on a depth map of camera "d" into camera "c"
/// (registration.h): z-buffer, 2x2 footprint to close the gaps of the finer
/// target grid, normals rotated by R_c_d and not turned toward camera "c"
/// (the demo's estimates are the depth camera's normals, rotated).
nf::NormalMap registerNormals(const nf::NormalMap& normals_d,
                              const nf::ScalarMap& depth_d,
                              const nf::CameraIntrinsics& K_d,
                              const std::array<double, 9>& R_c_d,
                              const std::array<double, 3>& t_c_d,
                              const nf::CameraIntrinsics& K_c, int width,
                              int height) {
  nf::depth::RegistrationSettings settings;
  settings.splat = nf::depth::Splat::k2x2;
  settings.face_camera = false;
  nf::NormalMap out;
  nf::depth::registerNormals(depth_d, normals_d, nullptr, K_d,
                             nf::depth::TargetCamera{K_c, width, height},
                             nf::depth::RigidTransform{R_c_d, t_c_d}, settings,
                             out, nullptr);
  return out;
}

struct Writer {
  rosbag::Bag bag;
  std::string frame_id = "camera_color_optical_frame";

  void write(int k, const cv::Mat& grey_or_rgb, const nf::CameraIntrinsics& K,
             const nf::NormalMap& fine, const nf::NormalMap& coarse) {
    std_msgs::Header header;
    header.stamp = ros::Time(kFirstStamp + k / kFps);
    header.frame_id = frame_id;
    header.seq = k;
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
    sensor_msgs::CameraInfo info;
    info.header = header;
    info.width = image.width;
    info.height = image.height;
    info.distortion_model = "plumb_bob";
    info.D.assign(5, 0.0);
    for (int i = 0; i < 9; ++i) info.K[i] = K.K[i];
    info.R = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    info.P = {K.K[0], 0, K.K[2], 0, 0, K.K[4], K.K[5], 0, 0, 0, 1, 0};
    sensor_msgs::Image fine_msg, coarse_msg;
    nf::node::normalsToMessage(fine, header, fine_msg);
    nf::node::normalsToMessage(coarse, header, coarse_msg);
    bag.write("/camera_info", header.stamp, info);
    bag.write("/normals_0", header.stamp, fine_msg);
    bag.write("/normals_1", header.stamp, coarse_msg);
    bag.write("/image", header.stamp, image);
  }
};

int castel(const std::string& dir, const std::string& output, int frames) {
  const std::string seq = dir + "/castel/";
  const nf::CameraIntrinsics K_c =
      nf::castle::readIntrinsics(dir + "/chateau.xml");
  const nf::CameraIntrinsics K_d =
      nf::castle::readIntrinsics(dir + "/chateau_depth.xml");
  // color_M_depth = depth_M_color^-1.
  const nf::Pose T_c_d =
      nf::inverse(nf::castle::readPose(dir + "/depth_M_color.txt"));
  const std::array<double, 9>& R_c_d = T_c_d.R;
  const std::array<double, 3>& t_c_d = T_c_d.t;
  Writer writer;
  writer.bag.open(output, rosbag::bagmode::Write);
  int written = 0;
  for (int k = 0; k < frames; ++k) {
    char name[64];
    std::snprintf(name, sizeof(name), "image_%04d.pgm", k);
    const cv::Mat grey = cv::imread(seq + name, cv::IMREAD_GRAYSCALE);
    if (grey.empty()) break;
    std::snprintf(name, sizeof(name), "depth_image_%04d.bin", k);
    const nf::ScalarMap depth =
        nf::castle::readDepth(seq + name, nf::castel::kDepthScaleM);
    // Fine: the raw depth's normals, in the depth camera.
    const nf::NormalMap fine_d = nf::synthetic::normalsFromDepth(depth, K_d);
    // Coarse: pooled and smoothed depth at 1/4 size.
    const nf::ScalarMap coarse_depth =
        smoothDepth(poolDepth(depth, kCoarseFactor));
    const double s = 1.0 / kCoarseFactor;
    const nf::CameraIntrinsics K_d_coarse = K_d.scaled(s, s);
    const nf::NormalMap coarse_d =
        nf::synthetic::normalsFromDepth(coarse_depth, K_d_coarse);
    const nf::NormalMap fine = registerNormals(fine_d, depth, K_d, R_c_d, t_c_d,
                                               K_c, grey.cols, grey.rows);
    const nf::NormalMap coarse = registerNormals(
        coarse_d, coarse_depth, K_d_coarse, R_c_d, t_c_d, K_c.scaled(s, s),
        grey.cols / kCoarseFactor, grey.rows / kCoarseFactor);
    writer.write(k, grey, K_c, fine, coarse);
    ++written;
  }
  writer.bag.close();
  if (written == 0) throw nf::InputError(seq + ": no frame found");
  std::printf(
      "make_demo_bag: %d frames of the ViSP castel sequence (real SR300 data) "
      "-> %s\n",
      written, output.c_str());
  return 0;
}

int synthetic(const std::string& output, const std::string& gt_output,
              int frames) {
  const int W = 320, H = 240;
  const auto sequence =
      nf::synthetic::renderSequence(0, W, H, frames, 0.3, kFps);
  Writer writer;
  writer.frame_id = "camera";
  writer.bag.open(output, rosbag::bagmode::Write);
  rosbag::Bag gt;
  if (!gt_output.empty()) gt.open(gt_output, rosbag::bagmode::Write);
  for (int k = 0; k < frames; ++k) {
    const nf::synthetic::Frame& frame = sequence[k];
    // Fine: normals of a noisy, quantized depth map.
    const nf::NormalMap fine =
        nf::synthetic::normalsFromNoisyDepth(frame, 0.0015, 0.02, 100 + k);
    // Coarse: the same kind of depth, pooled 4x4 and smoothed.
    const nf::ScalarMap noisy_depth = nf::synthetic::addDepthNoise(
        frame.depth, 0.0015, nf::synthetic::kDepthQuantizationM, 0.02, 200 + k);
    const double s = 1.0 / kCoarseFactor;
    const nf::NormalMap coarse = nf::synthetic::normalsFromDepth(
        smoothDepth(poolDepth(noisy_depth, kCoarseFactor)),
        frame.K.scaled(s, s));
    cv::Mat rgb(H, W, CV_8UC3);
    for (int y = 0; y < H; ++y) {
      for (int x = 0; x < W; ++x) {
        for (int c = 0; c < 3; ++c) {
          rgb.at<cv::Vec3b>(y, x)[c] = static_cast<std::uint8_t>(std::lround(
              255.0f *
              std::min(std::max(frame.image.at(c, y, x), 0.0f), 1.0f)));
        }
      }
    }
    writer.write(k, rgb, frame.K, fine, coarse);
    if (!gt_output.empty()) {
      std_msgs::Header header;
      header.stamp = ros::Time(kFirstStamp + k / kFps);
      header.frame_id = writer.frame_id;
      sensor_msgs::Image msg;
      nf::node::normalsToMessage(frame.normals_gt, header, msg);
      gt.write("/normals_gt", header.stamp, msg);
    }
  }
  writer.bag.close();
  if (!gt_output.empty()) gt.close();
  std::printf(
      "make_demo_bag: %d frames of a SYNTHETIC sequence (ray-cast room, %dx%d) "
      "-> %s\n",
      frames, W, H, output.c_str());
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  std::string output, dir = nf::castel::kDefaultDirectory, gt_output;
  bool force_synthetic = false;
  int frames = 30;
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
    return synthetic(output, gt_output, frames);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "make_demo_bag: %s\n", e.what());
    return 1;
  }
}
