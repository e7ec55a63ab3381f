// Middlebury Aloe loader: the pair, the ground truth reduced, its normals.
#include "eval/aloe.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <limits>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>

#include "eval/stereo.h"
#include "normal_fusion/depth.h"
#include "normal_fusion/errors.h"

namespace normal_fusion {
namespace aloe {
namespace {

constexpr float kMissing = std::numeric_limits<float>::quiet_NaN();
constexpr const char* kFiles[3] = {"aloeL.jpg", "aloeR.jpg", "aloeGT.png"};

std::string pathOf(const std::string& directory, const char* name) {
  return (std::filesystem::path(directory) / name).string();
}

cv::Mat readOrThrow(const std::string& path, int flags) {
  cv::Mat image = cv::imread(path, flags);
  if (image.empty()) throw InputError("aloe: cannot decode '" + path + "'");
  return image;
}

/// BGR 8-bit to 3 planes R, G, B in [0, 1].
ColorImage toColorImage(const cv::Mat& bgr) {
  ColorImage out(bgr.cols, bgr.rows, 3);
  for (int y = 0; y < bgr.rows; ++y) {
    for (int x = 0; x < bgr.cols; ++x) {
      const cv::Vec3b p = bgr.at<cv::Vec3b>(y, x);
      for (int c = 0; c < 3; ++c) {
        out.at(c, y, x) = static_cast<float>(p[2 - c] / 255.0);
      }
    }
  }
  return out;
}

/// The ground truth reduced by `factor`: the mean of a block where all its
/// pixels are known and span at most one step, divided by the factor.
ScalarMap reduceDisparity(const cv::Mat& gt, int factor) {
  const int width = gt.cols / factor, height = gt.rows / factor;
  ScalarMap out(width, height, 1, kMissing);
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      int lo = 256, hi = -1, sum = 0;
      for (int j = 0; j < factor; ++j) {
        for (int i = 0; i < factor; ++i) {
          const int d = gt.at<unsigned char>(y * factor + j, x * factor + i);
          lo = std::min(lo, d);
          hi = std::max(hi, d);
          sum += d;
        }
      }
      if (lo == 0 || hi - lo > 1) continue;
      out.at(0, y, x) = static_cast<float>(
          sum / static_cast<double>(factor * factor) / factor);
    }
  }
  return out;
}

}  // namespace

bool available(const std::string& directory) {
  for (const char* name : kFiles) {
    if (!std::filesystem::is_regular_file(pathOf(directory, name))) {
      return false;
    }
  }
  return true;
}

NormalMap normalsFromDisparity(const ScalarMap& disparity_px,
                               const CameraIntrinsics& K, double baseline_m,
                               int window_radius) {
  depth::DepthNormalSettings settings;
  settings.method = depth::NormalMethod::kPlaneFit;
  settings.window_radius = window_radius;
  // Exact data: no noise term in the jump threshold.
  settings.noise_coefficient = 0.0;
  NormalMap normals;
  depth::depthToNormals(
      stereo::depthFromDisparity(disparity_px, K.fx(), baseline_m), K, settings,
      normals);
  return normals;
}

AloeData load(const AloeSettings& settings) {
  if (settings.downscale < 1 || settings.downscale > 8 ||
      !(settings.focal_full_px > 0.0) || !(settings.baseline_m > 0.0) ||
      settings.gt_window_radius < 1 || settings.gt_window_radius > 10) {
    throw ParameterError(
        "aloe: expected downscale in 1..8, focal length and baseline > 0, "
        "window radius in 1..10");
  }
  AloeData data;
  for (const char* name : kFiles) {
    const std::string path = pathOf(settings.directory, name);
    if (!std::filesystem::is_regular_file(path)) {
      data.note = "skipped: '" + path +
                  "' is missing (Debian's opencv-doc installs it)";
      return data;
    }
  }
  const cv::Mat left =
      readOrThrow(pathOf(settings.directory, kFiles[0]), cv::IMREAD_COLOR);
  const cv::Mat right =
      readOrThrow(pathOf(settings.directory, kFiles[1]), cv::IMREAD_COLOR);
  const cv::Mat gt =
      readOrThrow(pathOf(settings.directory, kFiles[2]), cv::IMREAD_GRAYSCALE);
  if (left.size() != right.size() || left.size() != gt.size()) {
    throw InputError("aloe: the two views and the ground truth differ in size");
  }
  const int factor = settings.downscale;
  const cv::Size reduced(left.cols / factor, left.rows / factor);
  cv::Mat left_small, right_small;
  cv::resize(left, left_small, reduced, 0, 0, cv::INTER_AREA);
  cv::resize(right, right_small, reduced, 0, 0, cv::INTER_AREA);
  data.left = toColorImage(left_small);
  data.right = toColorImage(right_small);
  data.disparity_gt = reduceDisparity(gt, factor);
  const double f = settings.focal_full_px / factor;
  data.K = CameraIntrinsics(f, f, (reduced.width - 1) / 2.0,
                            (reduced.height - 1) / 2.0);
  data.baseline_m = settings.baseline_m;
  data.depth_gt =
      stereo::depthFromDisparity(data.disparity_gt, f, settings.baseline_m);
  data.normals_gt =
      normalsFromDisparity(data.disparity_gt, data.K, settings.baseline_m,
                           settings.gt_window_radius);
  data.found = true;
  return data;
}

}  // namespace aloe
}  // namespace normal_fusion
