#include "eval/peers.h"

#include <cmath>
#include <limits>
#include <opencv2/core.hpp>
#include <opencv2/ximgproc.hpp>
#include <sstream>

#include "normal_fusion/errors.h"

namespace normal_fusion {
namespace peers {
namespace {

/// The guide as OpenCV wants it: 8-bit (FGS) or float in [0, 1].
cv::Mat guideMat(const ColorImage& guide, bool eight_bit) {
  const int W = guide.width(), H = guide.height();
  const int channels = guide.channels();
  cv::Mat out(H, W, CV_32FC(channels));
  for (int y = 0; y < H; ++y) {
    float* row = out.ptr<float>(y);
    for (int x = 0; x < W; ++x) {
      for (int c = 0; c < channels; ++c) {
        row[x * channels + c] =
            std::min(std::max(guide.at(c, y, x), 0.0f), 1.0f);
      }
    }
  }
  if (!eight_bit) return out;
  cv::Mat out8;
  out.convertTo(out8, CV_8U, 255.0);
  return out8;
}

cv::Mat filterOnce(const cv::Mat& src, const cv::Mat& guide_f,
                   const cv::Mat& guide_8u, const PeerSetting& s) {
  cv::Mat dst;
  switch (s.filter) {
    case PeerFilter::kJointBilateral: {
      const int d = 2 * static_cast<int>(std::ceil(2.0 * s.a)) + 1;
      cv::ximgproc::jointBilateralFilter(guide_f, src, dst, d, s.b, s.a);
      break;
    }
    case PeerFilter::kGuided:
      cv::ximgproc::guidedFilter(guide_f, src, dst, static_cast<int>(s.a), s.b);
      break;
    case PeerFilter::kFastGlobalSmoother:
      cv::ximgproc::fastGlobalSmootherFilter(guide_8u, src, dst, s.a, s.b);
      break;
    case PeerFilter::kDomainTransform:
      cv::ximgproc::dtFilter(guide_f, src, dst, s.a, s.b, cv::ximgproc::DTF_NC,
                             3);
      break;
  }
  return dst;
}

}  // namespace

std::string name(PeerFilter filter) {
  switch (filter) {
    case PeerFilter::kJointBilateral:
      return "joint bilateral";
    case PeerFilter::kGuided:
      return "guided filter";
    case PeerFilter::kFastGlobalSmoother:
      return "fast global smoother";
    case PeerFilter::kDomainTransform:
      return "domain transform";
  }
  return "unknown";
}

std::vector<PeerFilter> allPeers() {
  return {PeerFilter::kJointBilateral, PeerFilter::kGuided,
          PeerFilter::kFastGlobalSmoother, PeerFilter::kDomainTransform};
}

std::string PeerSetting::label() const {
  std::ostringstream s;
  switch (filter) {
    case PeerFilter::kJointBilateral:
      s << "sigma_space " << a << ", sigma_color " << b;
      break;
    case PeerFilter::kGuided:
      s << "radius " << a << ", eps " << b;
      break;
    case PeerFilter::kFastGlobalSmoother:
      s << "lambda " << a << ", sigma_color " << b;
      break;
    case PeerFilter::kDomainTransform:
      s << "sigma_spatial " << a << ", sigma_color " << b;
      break;
  }
  return s.str();
}

std::vector<PeerSetting> settingsGrid(PeerFilter filter) {
  std::vector<PeerSetting> grid;
  auto add = [&](std::initializer_list<double> as,
                 std::initializer_list<double> bs) {
    for (double a : as) {
      for (double b : bs) grid.push_back({filter, a, b});
    }
  };
  switch (filter) {
    case PeerFilter::kJointBilateral:
      add({2, 4, 8}, {0.05, 0.1, 0.2, 0.4});
      break;
    case PeerFilter::kGuided:
      add({2, 4, 8, 16}, {1e-3, 1e-2, 1e-1});
      break;
    case PeerFilter::kFastGlobalSmoother:
      add({10, 30, 100, 300, 1000}, {2, 4, 8, 16});
      break;
    case PeerFilter::kDomainTransform:
      add({5, 10, 20, 40}, {0.05, 0.1, 0.2, 0.4});
      break;
  }
  return grid;
}

NormalMap applyPeer(const NormalMap& normals, const ColorImage& guide,
                    const PeerSetting& setting) {
  if (normals.channels() != 3 || !normals.sameSize(guide) ||
      (guide.channels() != 1 && guide.channels() != 3)) {
    throw InputError(
        "peer filter: expected a 3-channel normal map and a 1- or "
        "3-channel guide of the same size");
  }
  const int W = normals.width(), H = normals.height();
  cv::Mat src(H, W, CV_32FC3), mask(H, W, CV_32FC1);
  bool any_missing = false;
  for (int y = 0; y < H; ++y) {
    cv::Vec3f* row = src.ptr<cv::Vec3f>(y);
    float* m = mask.ptr<float>(y);
    for (int x = 0; x < W; ++x) {
      const float n[3] = {normals.at(0, y, x), normals.at(1, y, x),
                          normals.at(2, y, x)};
      const bool valid = isValidNormal(n[0], n[1], n[2]) &&
                         std::isfinite(n[0]) && std::isfinite(n[1]) &&
                         std::isfinite(n[2]);
      row[x] = valid ? cv::Vec3f(n[0], n[1], n[2]) : cv::Vec3f(0, 0, 0);
      m[x] = valid ? 1.0f : 0.0f;
      any_missing = any_missing || !valid;
    }
  }
  const cv::Mat guide_f = guideMat(guide, false);
  const cv::Mat guide_8u = setting.filter == PeerFilter::kFastGlobalSmoother
                               ? guideMat(guide, true)
                               : cv::Mat();
  const cv::Mat filtered = filterOnce(src, guide_f, guide_8u, setting);
  cv::Mat weight;
  if (any_missing) weight = filterOnce(mask, guide_f, guide_8u, setting);
  NormalMap out(W, H, 3);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (int y = 0; y < H; ++y) {
    const cv::Vec3f* row = filtered.ptr<cv::Vec3f>(y);
    const float* w = any_missing ? weight.ptr<float>(y) : nullptr;
    for (int x = 0; x < W; ++x) {
      cv::Vec3f v = row[x];
      const bool reached = w == nullptr || w[x] > 1e-3f;
      const float len = std::sqrt(v.dot(v));
      for (int c = 0; c < 3; ++c) {
        out.at(c, y, x) = reached && len > 1e-6f ? v[c] / len : nan;
      }
    }
  }
  return out;
}

}  // namespace peers
}  // namespace normal_fusion
