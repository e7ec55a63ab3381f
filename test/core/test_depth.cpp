// Depth to normals (depth.h): each method against the exact normals of
// synthetic depth, REP 118 units, the confidence and its noise model.
#include "normal_fusion/depth.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <random>
#include <vector>

#include "eval/synthetic.h"
#include "normal_fusion/errors.h"
#include "normal_fusion/metrics.h"

namespace nf = normal_fusion;
namespace nd = normal_fusion::depth;

namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
constexpr double kPi = 3.14159265358979323846;

nf::CameraIntrinsics cameraFor(int W, int H) {
  return nf::CameraIntrinsics(0.9 * W, 0.9 * W, (W - 1) / 2.0, (H - 1) / 2.0);
}

struct Vec {
  double x, y, z;
};
Vec ray(const nf::CameraIntrinsics& K, int u, int v) {
  const double y = (v - K.cy()) / K.fy();
  return {(u - K.cx()) / K.fx(), y, 1.0};
}
double dot(const Vec& a, const Vec& b) {
  return a.x * b.x + a.y * b.y + a.z * b.z;
}
Vec unit(const Vec& a) {
  const double l = std::sqrt(dot(a, a));
  return {a.x / l, a.y / l, a.z / l};
}

/// Depth and exact normals of the plane n . P = -d (n unit, facing the
/// camera, d > 0).
struct Scene {
  nf::ScalarMap depth;
  nf::NormalMap normals;
};
Scene planeScene(int W, int H, const nf::CameraIntrinsics& K, Vec n, double d) {
  n = unit(n);
  Scene s{nf::ScalarMap(W, H, 1), nf::NormalMap(W, H, 3)};
  for (int v = 0; v < H; ++v) {
    for (int u = 0; u < W; ++u) {
      s.depth.at(0, v, u) = static_cast<float>(-d / dot(n, ray(K, u, v)));
      s.normals.at(0, v, u) = static_cast<float>(n.x);
      s.normals.at(1, v, u) = static_cast<float>(n.y);
      s.normals.at(2, v, u) = static_cast<float>(n.z);
    }
  }
  return s;
}

/// A sphere of radius rho at c in front of a frontal wall at z = wall.
Scene sphereScene(int W, int H, const nf::CameraIntrinsics& K, Vec c,
                  double rho, double wall, nf::ScalarMap* on_sphere) {
  Scene s{nf::ScalarMap(W, H, 1), nf::NormalMap(W, H, 3)};
  *on_sphere = nf::ScalarMap(W, H, 1, 0.0f);
  for (int v = 0; v < H; ++v) {
    for (int u = 0; u < W; ++u) {
      const Vec r = ray(K, u, v);
      // |t r - c|^2 = rho^2, nearest t.
      const double a = dot(r, r), b = -2.0 * dot(r, c),
                   q = dot(c, c) - rho * rho;
      const double disc = b * b - 4 * a * q;
      double z = wall;
      Vec n{0, 0, -1};
      if (disc > 0) {
        const double t = (-b - std::sqrt(disc)) / (2 * a);
        if (t < wall) {
          z = t;
          n = unit({t * r.x - c.x, t * r.y - c.y, t * r.z - c.z});
          on_sphere->at(0, v, u) = 1.0f;
        }
      }
      s.depth.at(0, v, u) = static_cast<float>(z);
      s.normals.at(0, v, u) = static_cast<float>(n.x);
      s.normals.at(1, v, u) = static_cast<float>(n.y);
      s.normals.at(2, v, u) = static_cast<float>(n.z);
    }
  }
  return s;
}

/// Pixels whose whole (2 radius + 1)^2 window lies inside `mask` (and the
/// image).
nf::ScalarMap eroded(const nf::ScalarMap& mask, int radius) {
  const int W = mask.width(), H = mask.height();
  nf::ScalarMap out(W, H, 1, 0.0f);
  for (int v = radius; v < H - radius; ++v) {
    for (int u = radius; u < W - radius; ++u) {
      bool all = true;
      for (int dv = -radius; dv <= radius; ++dv) {
        for (int du = -radius; du <= radius; ++du) {
          all = all && mask.at(0, v + dv, u + du) > 0.5f;
        }
      }
      out.at(0, v, u) = all ? 1.0f : 0.0f;
    }
  }
  return out;
}

double angleDeg(const nf::NormalMap& a, const nf::NormalMap& b, int v, int u) {
  double d = 0.0;
  for (int c = 0; c < 3; ++c) d += a.at(c, v, u) * b.at(c, v, u);
  return std::acos(std::min(1.0, std::max(-1.0, d))) * 180.0 / kPi;
}

bool validAt(const nf::NormalMap& n, int v, int u) {
  return nf::isValidNormal(n.at(0, v, u), n.at(1, v, u), n.at(2, v, u));
}

nd::DepthNormalSettings withMethod(nd::NormalMethod method) {
  nd::DepthNormalSettings s;
  s.method = method;
  return s;
}

const nd::NormalMethod kMethods[] = {nd::NormalMethod::kCentralDifference,
                                     nd::NormalMethod::kPlaneFit};

TEST(DepthNormals, TiltedPlaneIsExactForBothMethods) {
  const int W = 80, H = 60;
  const nf::CameraIntrinsics K = cameraFor(W, H);
  const Scene s = planeScene(W, H, K, {0.45, -0.3, -0.84}, 1.2);
  for (nd::NormalMethod method : kMethods) {
    nf::NormalMap n;
    nf::ScalarMap c;
    nd::depthToNormals(s.depth, K, withMethod(method), n, &c);
    const int border = method == nd::NormalMethod::kPlaneFit ? 0 : 1;
    double worst = 0.0;
    int valid = 0;
    for (int v = border; v < H - border; ++v) {
      for (int u = border; u < W - border; ++u) {
        ASSERT_TRUE(validAt(n, v, u))
            << nd::toString(method) << " " << u << ", " << v;
        worst = std::max(worst, angleDeg(n, s.normals, v, u));
        ++valid;
      }
    }
    EXPECT_LT(worst, 0.05) << nd::toString(method);
    EXPECT_EQ(valid, (W - 2 * border) * (H - 2 * border));
  }
}

TEST(DepthNormals, NormalsFaceTheCamera) {
  const int W = 40, H = 30;
  const nf::CameraIntrinsics K = cameraFor(W, H);
  // A plane seen from either side gives normals facing the camera.
  const Scene s = planeScene(W, H, K, {-0.6, 0.2, -0.77}, 0.8);
  for (nd::NormalMethod method : kMethods) {
    nf::NormalMap n;
    nd::depthToNormals(s.depth, K, withMethod(method), n);
    for (int v = 1; v < H - 1; ++v) {
      for (int u = 1; u < W - 1; ++u) {
        const Vec r = ray(K, u, v);
        EXPECT_LE(n.at(0, v, u) * r.x + n.at(1, v, u) * r.y + n.at(2, v, u),
                  0.0);
      }
    }
  }
}

TEST(DepthNormals, SpherePlaneFitWithinABound) {
  const int W = 160, H = 120;
  const nf::CameraIntrinsics K = cameraFor(W, H);
  nf::ScalarMap on_sphere;
  const Scene s =
      sphereScene(W, H, K, {0.05, -0.02, 1.5}, 0.35, 2.5, &on_sphere);
  nd::DepthNormalSettings settings = withMethod(nd::NormalMethod::kPlaneFit);
  nf::NormalMap n;
  nd::depthToNormals(s.depth, K, settings, n);
  const nf::ScalarMap inside = eroded(on_sphere, settings.window_radius);
  const nf::AngularErrorStats stats = nf::angularError(n, s.normals, inside);
  ASSERT_GT(stats.pixel_count, 1000);
  EXPECT_LT(stats.mean_deg, 0.5);
  double worst = 0.0;
  for (int v = 0; v < H; ++v) {
    for (int u = 0; u < W; ++u) {
      if (inside.at(0, v, u) > 0.5f) {
        worst = std::max(worst, angleDeg(n, s.normals, v, u));
      }
    }
  }
  EXPECT_LT(worst, 3.0);
}

TEST(DepthNormals, StepPlaneFitAveragesNothingAcrossIt) {
  const int W = 60, H = 40;
  const nf::CameraIntrinsics K = cameraFor(W, H);
  Scene s = planeScene(W, H, K, {0, 0, -1}, 1.0);
  for (int v = 0; v < H; ++v) {
    for (int u = W / 2; u < W; ++u) s.depth.at(0, v, u) = 1.5f;
  }
  nf::NormalMap fit, diff;
  nd::depthToNormals(s.depth, K, withMethod(nd::NormalMethod::kPlaneFit), fit);
  nd::depthToNormals(s.depth, K,
                     withMethod(nd::NormalMethod::kCentralDifference), diff);
  double worst_fit = 0.0, worst_diff = 0.0;
  int valid_fit = 0;
  for (int v = 1; v < H - 1; ++v) {
    for (int u = 1; u < W - 1; ++u) {
      if (validAt(fit, v, u)) {
        ++valid_fit;
        worst_fit = std::max(worst_fit, angleDeg(fit, s.normals, v, u));
      }
      if (validAt(diff, v, u)) {
        worst_diff = std::max(worst_diff, angleDeg(diff, s.normals, v, u));
      }
    }
  }
  EXPECT_EQ(valid_fit, (W - 2) * (H - 2)) << "the step's columns are fitted";
  EXPECT_LT(worst_fit, 0.05);
  // Central differences mix the two sides at the step (why plane_fit exists).
  EXPECT_GT(worst_diff, 30.0);
}

TEST(DepthNormals, Rep118MillimetresAndMetresGiveTheSameNormals) {
  const int W = 48, H = 36;
  const nf::CameraIntrinsics K = cameraFor(W, H);
  const Scene s = planeScene(W, H, K, {0.3, 0.2, -0.93}, 1.4);
  std::vector<std::uint16_t> mm(W * H);
  std::vector<float> m(W * H);
  for (int i = 0; i < W * H; ++i) {
    mm[i] = static_cast<std::uint16_t>(std::lround(s.depth.data()[i] * 1000));
    m[i] = mm[i] / 1000.0f;
  }
  nf::ScalarMap from_mm, from_m;
  EXPECT_EQ(nd::depthFromMillimetres(mm.data(), W, H, W * 2, from_mm),
            static_cast<std::size_t>(W * H));
  EXPECT_EQ(nd::depthFromMetres(m.data(), W, H, W * 4, from_m),
            static_cast<std::size_t>(W * H));
  for (nd::NormalMethod method : kMethods) {
    nf::NormalMap a, b;
    nd::depthToNormals(from_mm, K, withMethod(method), a);
    nd::depthToNormals(from_m, K, withMethod(method), b);
    double worst = 0.0;
    for (int c = 0; c < 3; ++c) {
      for (std::size_t i = 0; i < a.pixelCount(); ++i) {
        const float x = a.plane(c)[i], y = b.plane(c)[i];
        if (std::isnan(x) != std::isnan(y)) worst = 1.0;
        if (!std::isnan(x)) worst = std::max(worst, double(std::abs(x - y)));
      }
    }
    EXPECT_LT(worst, 1e-5) << nd::toString(method);
  }
}

TEST(DepthNormals, Rep118RowStepAndMissingValues) {
  // 3x2 pixels in rows of 8 bytes (16UC1) and 16 bytes (32FC1).
  const std::uint16_t mm[2][4] = {{1000, 0, 65535, 7}, {1, 2, 3, 9}};
  nf::ScalarMap d;
  EXPECT_EQ(nd::depthFromMillimetres(mm, 3, 2, 8, d), 5u);
  EXPECT_FLOAT_EQ(d.at(0, 0, 0), 1.0f);
  EXPECT_TRUE(std::isnan(d.at(0, 0, 1)));
  EXPECT_FLOAT_EQ(d.at(0, 0, 2), 65.535f);
  EXPECT_FLOAT_EQ(d.at(0, 1, 0), 0.001f);
  const float inf = std::numeric_limits<float>::infinity();
  const float m[2][4] = {{1.5f, kNaN, 0.0f, 7}, {-1.0f, inf, -inf, 9}};
  EXPECT_EQ(nd::depthFromMetres(m, 3, 2, 16, d), 1u);
  EXPECT_FLOAT_EQ(d.at(0, 0, 0), 1.5f);
  for (int i = 1; i < 6; ++i) EXPECT_TRUE(std::isnan(d.data()[i])) << i;
  EXPECT_THROW(nd::depthFromMetres(m, 3, 2, 8, d), nf::InputError);
  EXPECT_THROW(nd::depthFromMillimetres(mm, 0, 2, 8, d), nf::InputError);
}

TEST(DepthNormals, MissingDepthGivesNaNNormalsAndZeroConfidence) {
  const int W = 40, H = 30;
  const nf::CameraIntrinsics K = cameraFor(W, H);
  Scene s = planeScene(W, H, K, {0.1, 0.1, -0.99}, 1.0);
  s.depth.at(0, 10, 10) = kNaN;
  s.depth.at(0, 20, 25) = 0.0f;
  for (nd::NormalMethod method : kMethods) {
    nf::NormalMap n;
    nf::ScalarMap c;
    nd::depthToNormals(s.depth, K, withMethod(method), n, &c);
    for (auto p : {std::make_pair(10, 10), std::make_pair(20, 25)}) {
      EXPECT_FALSE(validAt(n, p.first, p.second)) << nd::toString(method);
      EXPECT_EQ(c.at(0, p.first, p.second), 0.0f) << nd::toString(method);
    }
    // The neighbours: central differences lose them, the plane fit keeps
    // them.
    const bool kept = validAt(n, 10, 11);
    EXPECT_EQ(kept, method == nd::NormalMethod::kPlaneFit)
        << nd::toString(method);
    for (std::size_t i = 0; i < c.pixelCount(); ++i) {
      const bool valid =
          nf::isValidNormal(n.plane(0)[i], n.plane(1)[i], n.plane(2)[i]);
      if (!valid) {
        EXPECT_EQ(c.plane(0)[i], 0.0f);
      }
    }
  }
  nf::NormalMap n;
  const nf::ScalarMap none(W, H, 1, kNaN);
  nd::depthToNormals(none, K, nd::DepthNormalSettings(), n);
  for (std::size_t i = 0; i < n.pixelCount(); ++i) {
    ASSERT_TRUE(std::isnan(n.plane(0)[i]));
  }
}

/// Confidence at the image centre of a plane.
double centreConfidence(const nd::DepthNormalSettings& settings, Vec normal,
                        double distance) {
  const int W = 64, H = 48;
  const nf::CameraIntrinsics K = cameraFor(W, H);
  const Scene s = planeScene(W, H, K, normal, distance);
  nf::NormalMap n;
  nf::ScalarMap c;
  nd::depthToNormals(s.depth, K, settings, n, &c);
  return c.at(0, H / 2, W / 2);
}

TEST(DepthNormals, ConfidenceFallsWithDepth) {
  for (nd::NormalMethod method : kMethods) {
    nd::DepthNormalSettings settings = withMethod(method);
    if (method == nd::NormalMethod::kCentralDifference) {
      settings.noise_coefficient = 0.0005;  // else ~0 already at 1 m
    }
    double previous = 1.0;
    for (double z : {0.5, 1.0, 2.0, 4.0}) {
      const double c = centreConfidence(settings, {0, 0, -1}, z);
      EXPECT_LT(c, previous) << nd::toString(method) << " z = " << z;
      EXPECT_GT(c, 0.0) << nd::toString(method) << " z = " << z;
      previous = c;
    }
  }
}

TEST(DepthNormals, ConfidenceFallsWithTheGrazingAngle) {
  for (nd::NormalMethod method : kMethods) {
    nd::DepthNormalSettings settings = withMethod(method);
    settings.noise_coefficient = 0.0005;
    double previous = 1.0;
    for (double deg : {0.0, 30.0, 60.0, 80.0}) {
      const double t = deg * kPi / 180.0;
      const double c = centreConfidence(
          settings, {std::sin(t), 0, -std::cos(t)}, 1.0 * std::cos(t));
      EXPECT_LT(c, previous) << nd::toString(method) << " " << deg << " deg";
      previous = c;
    }
    // Without noise the view factor alone: |n . v| at the centre.
    settings.noise_coefficient = 0.0;
    const double t = 60.0 * kPi / 180.0;
    EXPECT_NEAR(centreConfidence(settings, {std::sin(t), 0, -std::cos(t)}, 0.5),
                0.5, 0.01);
  }
}

TEST(DepthNormals, ConfidenceRisesWithTheDistanceToADiscontinuity) {
  const int W = 60, H = 40;
  const nf::CameraIntrinsics K = cameraFor(W, H);
  Scene s = planeScene(W, H, K, {0, 0, -1}, 1.0);
  for (int v = 0; v < H; ++v) {
    for (int u = W / 2; u < W; ++u) s.depth.at(0, v, u) = 1.0f;
    for (int u = 0; u < W / 2; ++u) s.depth.at(0, v, u) = 0.8f;
  }
  nd::DepthNormalSettings settings = withMethod(nd::NormalMethod::kPlaneFit);
  settings.noise_coefficient = 0.0;  // the edge factor alone (and |n . v|)
  nf::NormalMap n;
  nf::ScalarMap c;
  nd::depthToNormals(s.depth, K, settings, n, &c);
  const int v = H / 2;
  // Columns W/2 - 1 and W/2 touch the step: d_edge = 0.5, then 1.5, 2.5, 3.5.
  std::vector<double> right;
  for (int k = 0; k < 5; ++k) {
    const int u = W / 2 + k;
    const Vec r = unit(ray(K, u, v));
    right.push_back(c.at(0, v, u) / std::abs(r.z));  // without |n . v|
  }
  EXPECT_NEAR(right[0], 0.5 / 3.0, 1e-3);
  EXPECT_NEAR(right[1], 1.5 / 3.0, 1e-3);
  EXPECT_NEAR(right[2], 2.5 / 3.0, 1e-3);
  EXPECT_NEAR(right[3], 1.0, 1e-3);
  EXPECT_NEAR(right[4], 1.0, 1e-3);
  EXPECT_GT(c.at(0, v, W / 2 - 3), c.at(0, v, W / 2 - 1));
  // edge_distance 0 turns the factor off.
  settings.edge_distance = 0.0;
  nd::depthToNormals(s.depth, K, settings, n, &c);
  EXPECT_NEAR(c.at(0, v, W / 2), std::abs(unit(ray(K, W / 2, v)).z), 1e-3);
}

/// The view factor is min(1, |n . v| + sigma_n): on an exact plane 60
/// degrees from the view, with the noise term's exp made flat (s0 large),
/// c - |n . v| is sigma_n, which grows in proportion to a.
TEST(DepthNormals, ViewFactorIsRaisedBySigmaN) {
  for (nd::NormalMethod method : kMethods) {
    nd::DepthNormalSettings settings = withMethod(method);
    settings.normal_sigma_scale = 100.0;
    const double t = 60.0 * kPi / 180.0;
    const Vec n{std::sin(t), 0, -std::cos(t)};
    settings.noise_coefficient = 0.0;
    const double view = centreConfidence(settings, n, 0.5);
    settings.noise_coefficient = 0.0005;
    const double raise_1 = centreConfidence(settings, n, 0.5) - view;
    settings.noise_coefficient = 0.001;
    const double raise_2 = centreConfidence(settings, n, 0.5) - view;
    EXPECT_GT(raise_1, 0.002) << nd::toString(method);
    EXPECT_LT(raise_2, 0.4) << nd::toString(method);  // below the cap at 1
    EXPECT_NEAR(raise_2 / raise_1, 2.0, 0.02) << nd::toString(method);
  }
}

/// The noise model's sigma_n against the spread of the normals of noisy
/// depth: a frontal wall with sigma_z = a z^2, many seeds.
TEST(DepthNormals, SigmaNMatchesTheMeasuredSpread) {
  const int W = 64, H = 48;
  const nf::CameraIntrinsics K = cameraFor(W, H);
  for (nd::NormalMethod method : kMethods) {
    nd::DepthNormalSettings settings = withMethod(method);
    settings.noise_coefficient = 0.001;
    settings.edge_distance = 0.0;
    settings.discontinuity_ratio = 0.5;  // no neighbour left out by noise
    const Scene s = planeScene(W, H, K, {0, 0, -1}, 1.5);
    std::mt19937_64 rng(7);
    std::normal_distribution<double> gauss(0.0, 1.0);
    double sum_sq = 0.0, predicted_sq = 0.0;
    int count = 0;
    for (int trial = 0; trial < 20; ++trial) {
      nf::ScalarMap noisy = s.depth;
      for (std::size_t i = 0; i < noisy.pixelCount(); ++i) {
        const double z = noisy.data()[i];
        noisy.data()[i] = static_cast<float>(z + settings.noise_coefficient *
                                                     z * z * gauss(rng));
      }
      nf::NormalMap n;
      nf::ScalarMap c;
      nd::depthToNormals(noisy, K, settings, n, &c);
      // Within 5 pixels of the principal point the rays are within 0.13 rad
      // of the axis, so min(1, |n . v| + sigma_n) is 1 (sigma_n about 0.02 -
      // 0.09 rad here) and c = exp(-(sigma_n / s0)^2).
      for (int v = H / 2 - 5; v <= H / 2 + 5; ++v) {
        for (int u = W / 2 - 5; u <= W / 2 + 5; ++u) {
          const double angle = angleDeg(n, s.normals, v, u) * kPi / 180.0;
          sum_sq += angle * angle;
          const double q = -std::log(c.at(0, v, u));
          predicted_sq +=
              q * settings.normal_sigma_scale * settings.normal_sigma_scale;
          ++count;
        }
      }
    }
    const double measured = std::sqrt(sum_sq / count);
    const double predicted = std::sqrt(predicted_sq / count);
    EXPECT_NEAR(measured / predicted, 1.0, 0.15)
        << nd::toString(method) << ": measured " << measured
        << " rad, predicted " << predicted << " rad";
  }
}

TEST(DepthNormals, ConfidenceIsInTheUnitIntervalOnNoisyScenes) {
  for (int scene = 0; scene < nf::synthetic::kNumScenes; ++scene) {
    const nf::synthetic::Frame f = nf::synthetic::renderScene(scene, 96, 72);
    const nf::ScalarMap noisy =
        nf::synthetic::addDepthNoise(f.depth, 0.0025, 0.001, 0.02, 3);
    for (nd::NormalMethod method : kMethods) {
      nf::NormalMap n;
      nf::ScalarMap c;
      nd::depthToNormals(noisy, f.K, withMethod(method), n, &c);
      for (std::size_t i = 0; i < c.pixelCount(); ++i) {
        ASSERT_GE(c.data()[i], 0.0f) << scene;
        ASSERT_LE(c.data()[i], 1.0f) << scene;
      }
    }
  }
}

TEST(DepthNormals, PlaneFitBeatsCentralDifferencesOnNoisyDepth) {
  for (int scene = 0; scene < nf::synthetic::kNumScenes; ++scene) {
    const nf::synthetic::Frame f = nf::synthetic::renderScene(scene, 160, 120);
    const nf::ScalarMap noisy =
        nf::synthetic::addDepthNoise(f.depth, 0.0025, 0.001, 0.0, 5);
    nf::NormalMap fit, diff;
    nd::depthToNormals(noisy, f.K, withMethod(nd::NormalMethod::kPlaneFit),
                       fit);
    nd::depthToNormals(noisy, f.K,
                       withMethod(nd::NormalMethod::kCentralDifference), diff);
    const auto e_fit = nf::angularError(fit, f.normals_gt);
    const auto e_diff = nf::angularError(diff, f.normals_gt);
    EXPECT_LT(e_fit.mean_deg, 0.7 * e_diff.mean_deg) << scene;
    EXPECT_GT(e_fit.within_11_25, e_diff.within_11_25) << scene;
  }
}

TEST(DepthNormals, ThreadCountDoesNotChangeTheResult) {
  const nf::synthetic::Frame f = nf::synthetic::renderScene(2, 96, 72);
  for (nd::NormalMethod method : kMethods) {
    nd::DepthNormalSettings one = withMethod(method), two = one;
    two.num_threads = 2;
    nf::NormalMap n1, n2;
    nf::ScalarMap c1, c2;
    nd::depthToNormals(f.depth, f.K, one, n1, &c1);
    nd::depthToNormals(f.depth, f.K, two, n2, &c2);
    EXPECT_EQ(std::memcmp(n1.data(), n2.data(), n1.pixelCount() * 12), 0);
    EXPECT_EQ(std::memcmp(c1.data(), c2.data(), c1.pixelCount() * 4), 0);
  }
}

TEST(DepthNormals, SettingsAndInputsAreChecked) {
  EXPECT_EQ(nd::normalMethodFromString("plane_fit"),
            nd::NormalMethod::kPlaneFit);
  EXPECT_EQ(nd::normalMethodFromString("central_difference"),
            nd::NormalMethod::kCentralDifference);
  EXPECT_THROW(nd::normalMethodFromString("sobel"), nf::ParameterError);
  EXPECT_NO_THROW(nd::DepthNormalSettings().validate());
  const auto bad = [](auto spoil) {
    nd::DepthNormalSettings s;
    spoil(s);
    return s;
  };
  const double nan = std::nan("");
  for (const nd::DepthNormalSettings& s :
       {bad([](auto& s) { s.window_radius = 0; }),
        bad([](auto& s) { s.window_radius = 11; }),
        bad([](auto& s) { s.discontinuity_ratio = 0.0; }),
        bad([nan](auto& s) { s.discontinuity_ratio = nan; }),
        bad([](auto& s) { s.noise_coefficient = -1e-3; }),
        bad([](auto& s) { s.normal_sigma_scale = 0.0; }),
        bad([](auto& s) { s.edge_distance = -1.0; }),
        bad([](auto& s) { s.num_threads = 0; })}) {
    EXPECT_THROW(s.validate(), nf::ParameterError);
    EXPECT_THROW(nd::DepthNormalEstimator estimator(s), nf::ParameterError);
  }
  const nf::ScalarMap depth(8, 6, 1, 1.0f);
  nf::NormalMap n;
  nd::DepthNormalEstimator estimator;
  EXPECT_THROW(estimator.compute(nf::ScalarMap(8, 6, 3), cameraFor(8, 6), n),
               nf::InputError);
  EXPECT_THROW(estimator.compute(nf::ScalarMap(), cameraFor(8, 6), n),
               nf::InputError);
  nf::CameraIntrinsics projective = cameraFor(8, 6);
  projective.K[6] = 0.01;
  EXPECT_THROW(estimator.compute(depth, projective, n), nf::InputError);
  nf::CameraIntrinsics negative = cameraFor(8, 6);
  negative.K[0] = -5.0;
  EXPECT_THROW(estimator.compute(depth, negative, n), nf::InputError);
  nf::CameraIntrinsics tiny(1e-150, 1e-150, 3, 2);
  EXPECT_THROW(estimator.compute(depth, tiny, n), nf::InputError);
}

}  // namespace
