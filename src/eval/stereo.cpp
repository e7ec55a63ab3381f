// Stereo depth: the rendered pair, semi-global matching, disparity to depth.
#include "eval/stereo.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <sstream>
#include <utility>
#include <vector>

#include "eval/synthetic_internal.h"
#include "normal_fusion/errors.h"

namespace normal_fusion {
namespace stereo {

using synthetic::internal::kMissing;

synthetic::Pose rightCameraPose(const synthetic::Pose& left,
                                double baseline_m) {
  synthetic::Pose right = left;
  // Same rotation; the centre C + b x_cam, so t' = -R (C + b x_cam) = t - b
  // e_x.
  right.t[0] = left.t[0] - baseline_m;
  return right;
}

StereoPair renderStereoPair(int scene_id, int width, int height,
                            double baseline_m) {
  return renderStereoPair(scene_id, width, height, baseline_m,
                          synthetic::defaultPose(scene_id));
}

StereoPair renderStereoPair(int scene_id, int width, int height,
                            double baseline_m, const synthetic::Pose& left) {
  synthetic::internal::requireRange("renderStereoPair: baseline_m", baseline_m,
                                    1e-6, 1.0);
  StereoPair pair;
  pair.baseline_m = baseline_m;
  pair.left = synthetic::renderScene(scene_id, width, height, left);
  pair.right = synthetic::renderScene(scene_id, width, height,
                                      rightCameraPose(left, baseline_m));
  return pair;
}

namespace {

/// Luminance as 8 bits, what a camera delivers to the matcher.
cv::Mat grey8(const ColorImage& image) {
  cv::Mat out(image.height(), image.width(), CV_8UC1);
  for (int y = 0; y < image.height(); ++y) {
    for (int x = 0; x < image.width(); ++x) {
      const double l = 0.299 * image.at(0, y, x) + 0.587 * image.at(1, y, x) +
                       0.114 * image.at(2, y, x);
      out.at<unsigned char>(y, x) = cv::saturate_cast<unsigned char>(
          std::lround(255.0 * std::min(1.0, std::max(0.0, l))));
    }
  }
  return out;
}

}  // namespace

ScalarMap sgbmDisparity(const ColorImage& left, const ColorImage& right,
                        const SgbmSettings& s) {
  if (left.width() != right.width() || left.height() != right.height() ||
      left.channels() != 3 || right.channels() != 3) {
    std::ostringstream msg;
    msg << "sgbmDisparity: expected two 3-plane images of one size, got "
        << left.width() << "x" << left.height() << "x" << left.channels()
        << " and " << right.width() << "x" << right.height() << "x"
        << right.channels();
    throw InputError(msg.str());
  }
  const int area = s.block_size * s.block_size;
  cv::Ptr<cv::StereoSGBM> sgbm = cv::StereoSGBM::create(
      0, s.num_disparities, s.block_size, s.p1_factor * area,
      s.p2_factor * area, s.disp12_max_diff, 0, s.uniqueness_ratio,
      s.speckle_window, s.speckle_range, cv::StereoSGBM::MODE_SGBM_3WAY);
  cv::Mat disparity16;
  sgbm->compute(grey8(left), grey8(right), disparity16);
  ScalarMap out(left.width(), left.height(), 1, kMissing);
  for (int y = 0; y < out.height(); ++y) {
    for (int x = 0; x < out.width(); ++x) {
      // Fixed point with 4 fractional bits; below the minimum = none.
      const short d16 = disparity16.at<short>(y, x);
      if (d16 > 0) out.at(0, y, x) = static_cast<float>(d16 / 16.0);
    }
  }
  return out;
}

namespace {

/// f b / v for v > 0, NaN elsewhere: the same map both ways.
ScalarMap reciprocalScaled(const ScalarMap& in, double focal_px,
                           double baseline_m) {
  synthetic::internal::requireRange("stereo: focal_px", focal_px, 1e-9, 1e9);
  synthetic::internal::requireRange("stereo: baseline_m", baseline_m, 1e-9,
                                    1e3);
  ScalarMap out(in.width(), in.height(), 1, kMissing);
  const double fb = focal_px * baseline_m;
  for (std::size_t i = 0; i < in.pixelCount(); ++i) {
    const double v = in.data()[i];
    if (std::isfinite(v) && v > 0.0) {
      out.data()[i] = static_cast<float>(fb / v);
    }
  }
  return out;
}

}  // namespace

ScalarMap reduceDisparity(const ScalarMap& disparity_px, int factor) {
  synthetic::internal::requireRange("reduceDisparity: factor", factor, 1, 64);
  ScalarMap out(disparity_px.width() / factor, disparity_px.height() / factor,
                1, kMissing);
  for (int y = 0; y < out.height(); ++y) {
    for (int x = 0; x < out.width(); ++x) {
      double lo = std::numeric_limits<double>::infinity(), hi = -lo, sum = 0.0;
      bool complete = true;
      for (int j = 0; j < factor && complete; ++j) {
        for (int i = 0; i < factor && complete; ++i) {
          const double d = disparity_px.at(0, y * factor + j, x * factor + i);
          complete = std::isfinite(d) && d > 0.0;
          lo = std::min(lo, d);
          hi = std::max(hi, d);
          sum += d;
        }
      }
      if (!complete || hi - lo > 1.0) continue;
      out.at(0, y, x) = static_cast<float>(sum / (factor * factor) / factor);
    }
  }
  return out;
}

ScalarMap depthFromDisparity(const ScalarMap& disparity_px, double focal_px,
                             double baseline_m) {
  return reciprocalScaled(disparity_px, focal_px, baseline_m);
}

ScalarMap disparityFromDepth(const ScalarMap& depth_m, double focal_px,
                             double baseline_m) {
  return reciprocalScaled(depth_m, focal_px, baseline_m);
}

double errorCorrelation(const ScalarMap& depth_m, const ScalarMap& truth_m,
                        int lag) {
  // The error over z^2: both noise laws (a z^2, z^2 / (f b) per pixel of
  // disparity) then have one scale over the image.
  const auto error = [&](int y, int x, double* e) {
    const double z = depth_m.at(0, y, x), t = truth_m.at(0, y, x);
    if (!std::isfinite(z) || !std::isfinite(t) || !(t > 0.0)) return false;
    *e = (z - t) / (t * t);
    return true;
  };
  std::vector<std::pair<double, double>> pairs;
  std::vector<double> magnitudes;
  for (int y = 0; y < depth_m.height(); ++y) {
    for (int x = 0; x + lag < depth_m.width(); ++x) {
      double a = 0.0, b = 0.0;
      if (!error(y, x, &a) || !error(y, x + lag, &b)) continue;
      pairs.emplace_back(a, b);
      magnitudes.push_back(std::abs(a));
    }
  }
  if (pairs.size() < 2) return std::numeric_limits<double>::quiet_NaN();
  // Errors clipped at 5 robust standard deviations, so that a few gross
  // outliers (flying pixels, mismatches) do not decide the figure.
  std::nth_element(magnitudes.begin(),
                   magnitudes.begin() + magnitudes.size() / 2,
                   magnitudes.end());
  const double clip = 5.0 * 1.4826 * magnitudes[magnitudes.size() / 2];
  double sa = 0, sb = 0, saa = 0, sbb = 0, sab = 0;
  for (const auto& p : pairs) {
    const double a = std::max(-clip, std::min(clip, p.first));
    const double b = std::max(-clip, std::min(clip, p.second));
    sa += a;
    sb += b;
    saa += a * a;
    sbb += b * b;
    sab += a * b;
  }
  const double n = static_cast<double>(pairs.size());
  const double cov = sab / n - (sa / n) * (sb / n);
  const double va = saa / n - (sa / n) * (sa / n);
  const double vb = sbb / n - (sb / n) * (sb / n);
  if (!(va > 0.0) || !(vb > 0.0)) return 0.0;
  return cov / std::sqrt(va * vb);
}

}  // namespace stereo
}  // namespace normal_fusion
