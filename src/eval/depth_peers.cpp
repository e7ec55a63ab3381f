#include "eval/depth_peers.h"

#include <cmath>
#include <limits>
#include <opencv2/core.hpp>
#include <opencv2/rgbd.hpp>

#include "normal_fusion/errors.h"

namespace normal_fusion {
namespace depth_peers {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

bool hasDepth(float z) { return std::isfinite(z) && z > 0.0f; }

int cvMethod(OpenCvNormalMethod method) {
  switch (method) {
    case OpenCvNormalMethod::kFals:
      return cv::rgbd::RgbdNormals::RGBD_NORMALS_METHOD_FALS;
    case OpenCvNormalMethod::kLinemod:
      return cv::rgbd::RgbdNormals::RGBD_NORMALS_METHOD_LINEMOD;
    case OpenCvNormalMethod::kSri:
      return cv::rgbd::RgbdNormals::RGBD_NORMALS_METHOD_SRI;
  }
  return cv::rgbd::RgbdNormals::RGBD_NORMALS_METHOD_FALS;
}

/// The depth (LINEMOD) or the back-projected points (FALS, SRI), NaN where
/// there is no depth.
cv::Mat openCvInput(const ScalarMap& depth_m, const Mat3& K_inv,
                    bool as_points) {
  const int W = depth_m.width(), H = depth_m.height();
  cv::Mat input(H, W, as_points ? CV_32FC3 : CV_32FC1);
  for (int y = 0; y < H; ++y) {
    float* row = input.ptr<float>(y);
    for (int x = 0; x < W; ++x) {
      const float z = depth_m.at(0, y, x);
      const bool valid = hasDepth(z);
      if (!as_points) {
        row[x] = valid ? z : kNaN;
        continue;
      }
      const double rx = K_inv[0] * x + K_inv[1] * y + K_inv[2];
      const double ry = K_inv[3] * x + K_inv[4] * y + K_inv[5];
      const double rz = K_inv[6] * x + K_inv[7] * y + K_inv[8];
      row[3 * x + 0] = valid ? static_cast<float>(z * rx / rz) : kNaN;
      row[3 * x + 1] = valid ? static_cast<float>(z * ry / rz) : kNaN;
      row[3 * x + 2] = valid ? z : kNaN;
    }
  }
  return input;
}

}  // namespace

std::string name(OpenCvNormalMethod method) {
  switch (method) {
    case OpenCvNormalMethod::kFals:
      return "FALS";
    case OpenCvNormalMethod::kLinemod:
      return "LINEMOD";
    case OpenCvNormalMethod::kSri:
      return "SRI";
  }
  return "unknown";
}

std::vector<OpenCvNormalMethod> allOpenCvMethods() {
  return {OpenCvNormalMethod::kFals, OpenCvNormalMethod::kLinemod,
          OpenCvNormalMethod::kSri};
}

NormalMap opencvDepthNormals(const ScalarMap& depth_m,
                             const CameraIntrinsics& K,
                             OpenCvNormalMethod method, int window) {
  if (depth_m.channels() != 1 || depth_m.empty()) {
    throw InputError("opencvDepthNormals: depth must be one non-empty plane");
  }
  if (window != 1 && window != 3 && window != 5 && window != 7) {
    throw InputError("opencvDepthNormals: window must be 1, 3, 5 or 7, not " +
                     std::to_string(window));
  }
  const int W = depth_m.width(), H = depth_m.height();
  K.validateForImage(W, H);
  const Mat3 K_inv = K.inverse();
  const cv::Mat K_cv = (cv::Mat_<float>(3, 3) << K.K[0], K.K[1], K.K[2], K.K[3],
                        K.K[4], K.K[5], K.K[6], K.K[7], K.K[8]);
  const cv::Mat input =
      openCvInput(depth_m, K_inv, method != OpenCvNormalMethod::kLinemod);
  cv::rgbd::RgbdNormals estimator(H, W, CV_32F, K_cv, window, cvMethod(method));
  cv::Mat normals_cv;
  estimator(input, normals_cv);
  const int channels = normals_cv.channels();
  NormalMap normals(W, H, 3, kNaN);
  for (int y = 0; y < H; ++y) {
    const float* row = normals_cv.ptr<float>(y);
    for (int x = 0; x < W; ++x) {
      if (!hasDepth(depth_m.at(0, y, x))) continue;
      double n[3] = {row[channels * x], row[channels * x + 1],
                     row[channels * x + 2]};
      const double length = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
      if (!std::isfinite(length) || length < 1e-12) continue;
      // Facing the camera along the pixel's ray, not only n_z <= 0.
      const double rx = K_inv[0] * x + K_inv[1] * y + K_inv[2];
      const double ry = K_inv[3] * x + K_inv[4] * y + K_inv[5];
      const double rz = K_inv[6] * x + K_inv[7] * y + K_inv[8];
      const double sign = n[0] * rx + n[1] * ry + n[2] * rz > 0.0 ? -1.0 : 1.0;
      for (int c = 0; c < 3; ++c) {
        normals.at(c, y, x) = static_cast<float>(sign * n[c] / length);
      }
    }
  }
  return normals;
}

}  // namespace depth_peers
}  // namespace normal_fusion
