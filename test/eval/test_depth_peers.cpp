// OpenCV's RgbdNormals in the library's convention (src/eval/depth_peers.h):
// exact normals of a plane and a sphere on interior pixels, unit length,
// facing the camera (also where OpenCV's n_z <= 0 rule points them away),
// NaN without depth.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "eval/depth_peers.h"
#include "normal_fusion/errors.h"

namespace normal_fusion {
namespace {

using depth_peers::OpenCvNormalMethod;
constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
constexpr int kW = 160, kH = 120;
/// Pixels from the border or a hole that no method's window reaches over.
constexpr int kMargin = 9;

struct Vec {
  double x, y, z;
};

Vec rayOf(const CameraIntrinsics& K, int u, int v) {
  return {(u - K.cx()) / K.fx(), (v - K.cy()) / K.fy(), 1.0};
}

double dot(const Vec& a, const Vec& b) {
  return a.x * b.x + a.y * b.y + a.z * b.z;
}

Vec unit(const Vec& a) {
  const double l = std::sqrt(dot(a, a));
  return {a.x / l, a.y / l, a.z / l};
}

/// The plane n . P = d (d < 0: n faces the camera), NaN where it is behind.
ScalarMap planeDepth(const CameraIntrinsics& K, const Vec& n, double d) {
  ScalarMap depth(kW, kH, 1, kNaN);
  for (int v = 0; v < kH; ++v) {
    for (int u = 0; u < kW; ++u) {
      const double nr = dot(n, rayOf(K, u, v));
      if (nr < -1e-3) depth.at(0, v, u) = static_cast<float>(d / nr);
    }
  }
  return depth;
}

/// A sphere of radius R at centre C; NaN off it.
ScalarMap sphereDepth(const CameraIntrinsics& K, const Vec& C, double R) {
  ScalarMap depth(kW, kH, 1, kNaN);
  for (int v = 0; v < kH; ++v) {
    for (int u = 0; u < kW; ++u) {
      const Vec r = rayOf(K, u, v);
      const double a = dot(r, r), b = dot(r, C), c = dot(C, C) - R * R;
      const double disc = b * b - a * c;
      if (disc > 0.0) {
        depth.at(0, v, u) = static_cast<float>((b - std::sqrt(disc)) / a);
      }
    }
  }
  return depth;
}

/// True where every pixel within kMargin has depth (and the image goes on).
bool interior(const ScalarMap& depth, int u, int v) {
  if (u < kMargin || v < kMargin || u >= kW - kMargin || v >= kH - kMargin) {
    return false;
  }
  for (int dv = -kMargin; dv <= kMargin; ++dv) {
    for (int du = -kMargin; du <= kMargin; ++du) {
      if (!std::isfinite(depth.at(0, v + dv, u + du))) return false;
    }
  }
  return true;
}

/// Largest angle (degrees) to the exact normals on interior pixels; checks
/// unit length, facing the camera and NaN without depth on the way.
template <typename ExactNormal>
double maxInteriorErrorDeg(const ScalarMap& depth, const CameraIntrinsics& K,
                           OpenCvNormalMethod method, ExactNormal exact) {
  const NormalMap normals = depth_peers::opencvDepthNormals(depth, K, method);
  EXPECT_EQ(normals.channels(), 3);
  double worst = 0.0;
  int checked = 0;
  for (int v = 0; v < kH; ++v) {
    for (int u = 0; u < kW; ++u) {
      const Vec n{normals.at(0, v, u), normals.at(1, v, u),
                  normals.at(2, v, u)};
      if (!std::isfinite(depth.at(0, v, u))) {
        EXPECT_TRUE(std::isnan(n.x)) << u << "," << v;
        continue;
      }
      if (!interior(depth, u, v)) continue;
      ++checked;
      if (!std::isfinite(dot(n, n))) {
        worst = 180.0;
        continue;
      }
      EXPECT_NEAR(dot(n, n), 1.0, 1e-5);
      EXPECT_LE(dot(n, rayOf(K, u, v)), 0.0) << u << "," << v;
      const double c = std::min(1.0, std::max(-1.0, dot(n, exact(u, v))));
      worst = std::max(worst, std::acos(c) * 180.0 / M_PI);
    }
  }
  EXPECT_GT(checked, kW * kH / 10);
  return worst;
}

/// Bound per method: FALS fits the points; SRI resamples them to a
/// spherical grid and back; LINEMOD takes the depth as linear in the pixel
/// over its 11-pixel window, which it is not even on a plane.
double boundDeg(OpenCvNormalMethod method) {
  switch (method) {
    case OpenCvNormalMethod::kFals:
      return 0.5;
    case OpenCvNormalMethod::kSri:
      return 1.0;
    default:
      return 2.5;
  }
}

TEST(DepthPeers, ExactOnAFrontalishPlane) {
  const CameraIntrinsics K(150.0, 150.0, 79.5, 59.5);
  const Vec n = unit({0.3, -0.4, -1.0});
  const ScalarMap depth = planeDepth(K, n, -2.0);
  for (OpenCvNormalMethod method : depth_peers::allOpenCvMethods()) {
    EXPECT_LT(
        maxInteriorErrorDeg(depth, K, method, [&](int, int) { return n; }),
        boundDeg(method))
        << depth_peers::name(method);
  }
}

// n_z > 0 while n . r < 0: OpenCV's sign rule turns these normals away from
// the camera; the wrapper turns them back.
TEST(DepthPeers, ExactOnAnObliquePlaneFacingTheCamera) {
  const CameraIntrinsics K(60.0, 60.0, 79.5, 59.5);
  const Vec n = unit({1.0, 0.0, 0.3});
  const ScalarMap depth = planeDepth(K, n, -1.0);
  for (OpenCvNormalMethod method : depth_peers::allOpenCvMethods()) {
    EXPECT_LT(
        maxInteriorErrorDeg(depth, K, method, [&](int, int) { return n; }),
        boundDeg(method))
        << depth_peers::name(method);
  }
}

TEST(DepthPeers, ExactOnASphere) {
  const CameraIntrinsics K(150.0, 150.0, 79.5, 59.5);
  const Vec C{0.1, -0.05, 3.0};
  const double R = 1.2;
  const ScalarMap depth = sphereDepth(K, C, R);
  const auto exact = [&](int u, int v) {
    const Vec r = rayOf(K, u, v);
    const double z = depth.at(0, v, u);
    return unit({z * r.x - C.x, z * r.y - C.y, z - C.z});
  };
  for (OpenCvNormalMethod method : depth_peers::allOpenCvMethods()) {
    EXPECT_LT(maxInteriorErrorDeg(depth, K, method, exact), boundDeg(method))
        << depth_peers::name(method);
  }
}

TEST(DepthPeers, RejectsBadInput) {
  const CameraIntrinsics K(150.0, 150.0, 79.5, 59.5);
  ScalarMap depth(kW, kH, 1, 1.0f);
  EXPECT_THROW(
      depth_peers::opencvDepthNormals(depth, K, OpenCvNormalMethod::kFals, 4),
      InputError);
  EXPECT_THROW(depth_peers::opencvDepthNormals(ScalarMap(kW, kH, 2, 1.0f), K,
                                               OpenCvNormalMethod::kFals),
               InputError);
}

}  // namespace
}  // namespace normal_fusion
