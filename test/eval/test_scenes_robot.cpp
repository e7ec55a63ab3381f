// Tests of the textured and curved scenes: exact normals (the torus's against
// a finite difference of its depth), texture without geometry, and the
// depth-camera simulation.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <utility>
#include <vector>

#include "eval/depth_camera.h"
#include "eval/scene_model.h"
#include "eval/synthetic.h"
#include "eval/synthetic_internal.h"
#include "normal_fusion/errors.h"
#include "test_util.h"

namespace normal_fusion {
namespace {

constexpr double kRadToDeg = 180.0 / 3.14159265358979323846;
using synthetic::Frame;
namespace model = synthetic::model;
using synthetic::internal::normalized;
using synthetic::internal::sub;

double angleDeg(const Vec3& a, const Vec3& b) {
  const double c = dot(a, b) / std::sqrt(dot(a, a) * dot(b, b));
  return std::acos(std::max(-1.0, std::min(1.0, c))) * kRadToDeg;
}

constexpr std::array<int, 4> kNewScenes{
    {synthetic::kTexturedRoomScene, synthetic::kTexturedCornerScene,
     synthetic::kCurvedLargeScene, synthetic::kCurvedSmallScene}};

TEST(RobotScenes, TextureChangesTheImageButNotTheGeometry) {
  for (int id : kNewScenes) {
    const Frame textured = synthetic::renderScene(id, 96, 72);
    const Frame plain =
        synthetic::renderUntextured(id, 96, 72, synthetic::defaultPose(id));
    EXPECT_TRUE(test::identical(textured.normals_gt, plain.normals_gt)) << id;
    EXPECT_TRUE(test::identical(textured.depth, plain.depth)) << id;
    EXPECT_FALSE(test::identical(textured.image, plain.image)) << id;
  }
}

TEST(RobotScenes, EveryPixelSeesAUnitNormalFacingTheCamera) {
  for (int id : kNewScenes) {
    const Frame frame = synthetic::renderScene(id, 96, 72);
    int bad = 0;
    for (int y = 0; y < 72; ++y) {
      for (int x = 0; x < 96; ++x) {
        const Vec3 n{{frame.normals_gt.at(0, y, x),
                      frame.normals_gt.at(1, y, x),
                      frame.normals_gt.at(2, y, x)}};
        const Vec3 ray{{(x - frame.K.cx()) / frame.K.fx(),
                        (y - frame.K.cy()) / frame.K.fy(), 1.0}};
        const bool ok = std::abs(std::sqrt(dot(n, n)) - 1.0) < 1e-5 &&
                        dot(n, ray) <= 1e-6 && frame.depth.at(0, y, x) > 0.0f;
        if (!ok) ++bad;
      }
    }
    EXPECT_EQ(bad, 0) << "scene " << id;
  }
}

/// A torus standing across the view of a camera at the origin looking
/// along +z (rays o + s d, d = (u, v, 1)): s is the z-depth.
model::Torus testTorus() {
  model::Torus torus;
  torus.center = {{0.05, -0.02, 1.5}};
  torus.axis = normalized(Vec3{{0.3, -0.5, -1.0}});
  torus.major = 0.3;
  torus.minor = 0.1;
  return torus;
}

model::SurfaceHit castAt(const model::Torus& torus, double u, double v) {
  model::SurfaceHit hit;
  model::intersectTorus(torus, {{0.0, 0.0, 0.0}}, {{u, v, 1.0}}, &hit);
  return hit;
}

TEST(RobotScenes, TorusHitsLieOnTheQuarticAndItsNormalIsTheGradient) {
  const model::Torus torus = testTorus();
  int hits = 0;
  for (int j = -40; j <= 40; ++j) {
    for (int i = -40; i <= 40; ++i) {
      const double u = i * 0.007, v = j * 0.007;
      const model::SurfaceHit hit = castAt(torus, u, v);
      if (!std::isfinite(hit.s)) continue;
      ++hits;
      // The quartic in the torus frame: (|p|^2 + R^2 - r^2)^2 = 4 R^2 rho^2.
      const Vec3 p{{u * hit.s - torus.center[0], v * hit.s - torus.center[1],
                    hit.s - torus.center[2]}};
      const double h = dot(p, torus.axis);
      const double rho2 = dot(p, p) - h * h;
      const double R2 = torus.major * torus.major;
      const double k = dot(p, p) + R2 - torus.minor * torus.minor;
      EXPECT_NEAR(k * k, 4.0 * R2 * rho2, 1e-6);
      // Its gradient: 4 k p - 8 R^2 (p - h a).
      const Vec3 grad{{4 * k * p[0] - 8 * R2 * (p[0] - h * torus.axis[0]),
                       4 * k * p[1] - 8 * R2 * (p[1] - h * torus.axis[1]),
                       4 * k * p[2] - 8 * R2 * (p[2] - h * torus.axis[2])}};
      EXPECT_LT(std::min(angleDeg(grad, hit.normal),
                         180.0 - angleDeg(grad, hit.normal)),
                1e-3);
    }
  }
  EXPECT_GT(hits, 1000);
}

TEST(RobotScenes, TorusNormalsMatchAFiniteDifferenceOfItsDepth) {
  const model::Torus torus = testTorus();
  constexpr double kStep = 2e-4;
  int compared = 0, far_off = 0;
  double worst = 0.0;
  for (int j = -30; j <= 30; ++j) {
    for (int i = -30; i <= 30; ++i) {
      const double u = i * 0.01, v = j * 0.01;
      const model::SurfaceHit c = castAt(torus, u, v);
      const model::SurfaceHit xp = castAt(torus, u + kStep, v);
      const model::SurfaceHit xm = castAt(torus, u - kStep, v);
      const model::SurfaceHit yp = castAt(torus, u, v + kStep);
      const model::SurfaceHit ym = castAt(torus, u, v - kStep);
      bool all = true;
      for (const auto* h : {&c, &xp, &xm, &yp, &ym}) {
        all = all && std::isfinite(h->s);
      }
      // Only where the four neighbours hit the same side of the tube.
      if (!all || std::abs(xp.s - xm.s) > 0.01 || std::abs(yp.s - ym.s) > 0.01)
        continue;
      const auto point = [](double uu, double vv, double s) {
        return Vec3{{uu * s, vv * s, s}};
      };
      const Vec3 du = sub(point(u + kStep, v, xp.s), point(u - kStep, v, xm.s));
      const Vec3 dv = sub(point(u, v + kStep, yp.s), point(u, v - kStep, ym.s));
      const Vec3 n_fd = cross(du, dv);
      const double a =
          std::min(angleDeg(n_fd, c.normal), 180.0 - angleDeg(n_fd, c.normal));
      worst = std::max(worst, a);
      if (a > 0.5) ++far_off;
      ++compared;
    }
  }
  EXPECT_GT(compared, 500);
  // Central differences are exact to first order: a small share of grazing
  // pixels may deviate, none by much.
  EXPECT_LE(far_off, compared / 100);
  EXPECT_LT(worst, 5.0);
}

TEST(RobotScenes, CurvedScenesHaveNormalsOfTheirRenderedDepth) {
  for (int id : {synthetic::kCurvedLargeScene, synthetic::kCurvedSmallScene}) {
    const Frame frame = synthetic::renderScene(id, 640, 480);
    const NormalMap fd = synthetic::normalsFromDepth(frame.depth, frame.K);
    std::vector<double> angles;
    for (int y = 2; y < 478; ++y) {
      for (int x = 2; x < 638; ++x) {
        // Smooth surroundings: no depth jump in the 5x5 window.
        const double zc = frame.depth.at(0, y, x);
        bool smooth = true;
        for (int j = -2; j <= 2 && smooth; ++j) {
          for (int i = -2; i <= 2 && smooth; ++i) {
            smooth =
                std::abs(frame.depth.at(0, y + j, x + i) - zc) < 0.004 * zc;
          }
        }
        if (!smooth || !std::isfinite(fd.at(0, y, x))) continue;
        const Vec3 a{{fd.at(0, y, x), fd.at(1, y, x), fd.at(2, y, x)}};
        const Vec3 b{{frame.normals_gt.at(0, y, x),
                      frame.normals_gt.at(1, y, x),
                      frame.normals_gt.at(2, y, x)}};
        angles.push_back(angleDeg(a, b));
      }
    }
    ASSERT_GT(angles.size(), 100000u);
    std::sort(angles.begin(), angles.end());
    EXPECT_LT(angles[angles.size() / 2], 0.05) << id;
    EXPECT_LT(angles[angles.size() * 99 / 100], 2.0) << id;
  }
}

TEST(DepthCamera, NoiseGrowsWithDepthSquaredAndStaysOnTheSteps) {
  const Frame frame =
      synthetic::renderScene(synthetic::kTexturedRoomScene, 160, 120);
  synthetic::DepthCameraModel camera = synthetic::structuredLightCamera();
  camera.flying_share = 0.0;
  camera.random_dropout = 0.0;
  camera.grazing_cos = 0.0;
  camera.dark_luminance = 0.0;
  const ScalarMap noisy = synthetic::simulateDepthCamera(frame, camera, 7);
  double sum2 = 0.0;
  int n = 0, off_step = 0;
  for (std::size_t i = 0; i < noisy.pixelCount(); ++i) {
    const double z = noisy.data()[i], t = frame.depth.data()[i];
    ASSERT_TRUE(std::isfinite(z));
    const double steps = z / camera.quantization_m;
    if (std::abs(steps - std::round(steps)) > 1e-3) ++off_step;
    const double e = (z - t) / (camera.noise_coefficient * t * t);
    sum2 += e * e;
    ++n;
  }
  EXPECT_EQ(off_step, 0);
  // Standard deviation of the error in units of a z^2 (steps add q^2 / 12).
  EXPECT_NEAR(std::sqrt(sum2 / n), 1.0, 0.15);
  EXPECT_TRUE(
      test::identical(noisy, synthetic::simulateDepthCamera(frame, camera, 7)));
  EXPECT_FALSE(
      test::identical(noisy, synthetic::simulateDepthCamera(frame, camera, 8)));
}

TEST(DepthCamera, FlyingPixelsOnlyAtDepthEdgesAndLossesWhereExpected) {
  const Frame frame =
      synthetic::renderScene(synthetic::kCurvedLargeScene, 160, 120);
  synthetic::DepthCameraModel camera = synthetic::timeOfFlightCamera();
  camera.noise_coefficient = 0.0;
  camera.quantization_m = 0.0;
  camera.random_dropout = 0.0;
  camera.grazing_cos = 0.0;
  camera.dark_luminance = 0.0;
  camera.flying_share = 1.0;
  const ScalarMap flying = synthetic::simulateDepthCamera(frame, camera, 3);
  int moved = 0, moved_inside = 0;
  for (int y = 1; y < 119; ++y) {
    for (int x = 1; x < 159; ++x) {
      const double z = frame.depth.at(0, y, x);
      if (flying.at(0, y, x) == frame.depth.at(0, y, x)) continue;
      ++moved;
      double jump = 0.0;
      for (const auto& o : {std::make_pair(0, 1), std::make_pair(0, -1),
                            std::make_pair(1, 0), std::make_pair(-1, 0)}) {
        jump = std::max(
            jump, std::abs(frame.depth.at(0, y + o.first, x + o.second) - z));
      }
      if (jump <= camera.edge_ratio * z * 0.5) ++moved_inside;
    }
  }
  EXPECT_GT(moved, 100);
  EXPECT_EQ(moved_inside, 0);
  // Losses: with every pixel lost at random, nothing is left.
  camera.flying_share = 0.0;
  camera.random_dropout = 1.0;
  const ScalarMap none = synthetic::simulateDepthCamera(frame, camera, 3);
  for (std::size_t i = 0; i < none.pixelCount(); ++i) {
    EXPECT_TRUE(std::isnan(none.data()[i]));
  }
  camera.random_dropout = 2.0;
  EXPECT_THROW(synthetic::simulateDepthCamera(frame, camera, 3),
               ParameterError);
}

}  // namespace
}  // namespace normal_fusion
