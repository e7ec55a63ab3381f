// Registration through distorted cameras (registration.h): every depth pixel
// lands where the colour camera's model puts its point, the same distorted
// camera on both sides is the identity, and a model that folds back inside
// the colour image is refused.
#include <gtest/gtest.h>

#include <cmath>
#include <string>

#include "normal_fusion/errors.h"
#include "normal_fusion/lens_distortion.h"
#include "normal_fusion/registration.h"

namespace nf = normal_fusion;
namespace nd = normal_fusion::depth;

namespace {

constexpr int kW = 96, kH = 72;

nf::CameraIntrinsics intrinsics() {
  nf::CameraIntrinsics K;
  K.K = {80.0, 0, 47.5, 0, 80.0, 35.5, 0, 0, 1};
  return K;
}

nf::LensDistortion lens() {
  return nf::LensDistortion::fromCameraInfo(
      "plumb_bob", {0.11, -0.2, 0.002, -0.001, 0.05}, "/cam");
}

/// A fronto-parallel plane at 2 m facing the camera, and the pixel index as
/// the "confidence", so that the registered confidence tells each colour
/// pixel's source pixel.
struct Plane {
  nf::ScalarMap depth{kW, kH, 1};
  nf::NormalMap normals{kW, kH, 3};
  nf::ScalarMap index{kW, kH, 1};
  Plane() {
    for (int v = 0; v < kH; ++v) {
      for (int u = 0; u < kW; ++u) {
        depth.at(0, v, u) = 2.0f;
        normals.at(0, v, u) = 0.0f;
        normals.at(1, v, u) = 0.0f;
        normals.at(2, v, u) = -1.0f;
        index.at(0, v, u) = static_cast<float>(v * kW + u);
      }
    }
  }
};

TEST(RegistrationDistortion, PixelsLandWhereTheColourModelPutsThem) {
  const Plane plane;
  nd::DepthRegistration registration(
      nd::RegistrationSettings{nd::Splat::kNearest, true});
  const nd::TargetCamera depth_camera{intrinsics(), kW, kH, {}};
  const nd::TargetCamera rgb{intrinsics(), kW, kH, lens()};
  nf::NormalMap normals_rgb;
  nf::ScalarMap index_rgb;
  registration.registerNormals(plane.depth, plane.normals, &plane.index,
                               depth_camera, rgb, nf::Pose(), normals_rgb,
                               &index_rgb);
  const nf::CameraIntrinsics K = intrinsics();
  int hits = 0, mismatches = 0;
  for (int v = 0; v < kH; ++v) {
    for (int u = 0; u < kW; ++u) {
      if (!std::isfinite(normals_rgb.at(0, v, u))) continue;
      ++hits;
      const int source = static_cast<int>(index_rgb.at(0, v, u));
      const int su = source % kW, sv = source / kW;
      double xd, yd;
      lens().distort((su - K.cx()) / K.fx(), (sv - K.cy()) / K.fy(), &xd, &yd);
      const long pu = std::lround(K.fx() * xd + K.cx());
      const long pv = std::lround(K.fy() * yd + K.cy());
      if (pu != u || pv != v) ++mismatches;
    }
  }
  EXPECT_GT(hits, kW * kH / 2);
  EXPECT_EQ(mismatches, 0);
  // A pinhole colour camera would show the source pixel itself: the
  // distortion moved the border pixels.
  const int corner = static_cast<int>(index_rgb.at(0, 2, 2));
  EXPECT_TRUE(std::isfinite(normals_rgb.at(0, 2, 2)));
  EXPECT_NE(corner, 2 * kW + 2);
}

TEST(RegistrationDistortion, TheSameDistortedCameraIsTheIdentity) {
  const Plane plane;
  nd::DepthRegistration registration(
      nd::RegistrationSettings{nd::Splat::kNearest, true});
  const nd::TargetCamera camera{intrinsics(), kW, kH, lens()};
  nf::NormalMap normals_rgb;
  nf::ScalarMap index_rgb;
  // Twice: the second call reuses the undistorted rays.
  for (int call = 0; call < 2; ++call) {
    registration.registerNormals(plane.depth, plane.normals, &plane.index,
                                 camera, camera, nf::Pose(), normals_rgb,
                                 &index_rgb);
    for (int v = 0; v < kH; ++v) {
      for (int u = 0; u < kW; ++u) {
        ASSERT_EQ(index_rgb.at(0, v, u), plane.index.at(0, v, u))
            << u << " " << v;
        ASSERT_EQ(normals_rgb.at(2, v, u), -1.0f);
      }
    }
  }
}

TEST(RegistrationDistortion, AFoldingModelIsRefused) {
  const Plane plane;
  nf::LensDistortion folding = nf::LensDistortion::fromCameraInfo(
      "plumb_bob", {-1.5, 0, 0, 0, 0}, "/cam");
  const nd::TargetCamera depth_camera{intrinsics(), kW, kH, {}};
  const nd::TargetCamera rgb{intrinsics(), kW, kH, folding};
  nf::NormalMap normals_rgb;
  EXPECT_THROW(
      nd::registerNormals(plane.depth, plane.normals, nullptr, intrinsics(),
                          rgb, nf::Pose(), nd::RegistrationSettings(),
                          normals_rgb, nullptr),
      nf::InputError);
  // The depth camera's size must be the depth map's.
  nd::DepthRegistration registration;
  const nd::TargetCamera wrong{intrinsics(), kW + 1, kH, {}};
  EXPECT_THROW(
      registration.registerNormals(plane.depth, plane.normals, nullptr, wrong,
                                   nd::TargetCamera{intrinsics(), kW, kH, {}},
                                   nf::Pose(), normals_rgb, nullptr),
      nf::InputError);
}

}  // namespace
