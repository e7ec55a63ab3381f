// Tests of the synthetic scenes (ray caster) and the noise models.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

#include "eval/synthetic.h"
#include "normal_fusion/errors.h"
#include "test_util.h"

namespace normal_fusion {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kRadToDeg = 180.0 / kPi;
using Vec3 = std::array<double, 3>;
using synthetic::Frame;

Vec3 normalAt(const NormalMap& n, int y, int x) {
  return {n.at(0, y, x), n.at(1, y, x), n.at(2, y, x)};
}

bool valid(const NormalMap& n, int y, int x) {
  return isValidNormal(n.at(0, y, x), n.at(1, y, x), n.at(2, y, x));
}

double dot(const Vec3& a, const Vec3& b) {
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

double angleDeg(const Vec3& a, const Vec3& b) {
  const double c = dot(a, b) / std::sqrt(dot(a, a) * dot(b, b));
  return std::acos(std::max(-1.0, std::min(1.0, c))) * kRadToDeg;
}

Vec3 cross(const Vec3& a, const Vec3& b) {
  return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
          a[0] * b[1] - a[1] * b[0]};
}

double length(const Vec3& a) { return std::sqrt(dot(a, a)); }

/// r = K^-1 (u, v, 1) for a K without skew.
Vec3 rayOf(const CameraIntrinsics& K, int y, int x) {
  return {(x - K.cx()) / K.fx(), (y - K.cy()) / K.fy(), 1.0};
}

/// P = z K^-1 (u, v, 1).
Vec3 backProject(const Frame& frame, int y, int x) {
  const Vec3 r = rayOf(frame.K, y, x);
  const double z = frame.depth.at(0, y, x);
  return {z * r[0], z * r[1], z * r[2]};
}

/// World-frame normal R^T n_cam.
Vec3 toWorld(const synthetic::Pose& pose, const Vec3& n_cam) {
  const auto& R = pose.R;
  return {R[0] * n_cam[0] + R[3] * n_cam[1] + R[6] * n_cam[2],
          R[1] * n_cam[0] + R[4] * n_cam[1] + R[7] * n_cam[2],
          R[2] * n_cam[0] + R[5] * n_cam[1] + R[8] * n_cam[2]};
}

/// True when the 3x3 neighbourhood of (x, y) lies on one plane: identical
/// ground-truth normals, and an inverse depth 1/z that is affine in (u, v) (as
/// it is exactly on a plane: 1/z = (n . r) / c for the plane n . P = c). The
/// depth test is independent of the normals, so it rejects steps between
/// parallel planes.
bool planarInterior(const Frame& frame, int y, int x) {
  const int W = frame.depth.width(), H = frame.depth.height();
  if (x < 1 || y < 1 || x >= W - 1 || y >= H - 1) return false;
  const Vec3 n_centre = normalAt(frame.normals_gt, y, x);
  const auto w = [&](int yy, int xx) {
    return 1.0 / frame.depth.at(0, yy, xx);
  };
  const double gx = 0.5 * (w(y, x + 1) - w(y, x - 1));
  const double gy = 0.5 * (w(y + 1, x) - w(y - 1, x));
  for (int j = -1; j <= 1; ++j) {
    for (int i = -1; i <= 1; ++i) {
      const Vec3 n = normalAt(frame.normals_gt, y + j, x + i);
      for (int c = 0; c < 3; ++c) {
        if (std::abs(n[c] - n_centre[c]) > 1e-6) return false;
      }
      const double predicted = w(y, x) + i * gx + j * gy;
      if (std::abs(w(y + j, x + i) - predicted) > 1e-5 * w(y, x)) return false;
    }
  }
  return true;
}

/// True when (x, y) and its 3x3 neighbours sample one smooth surface: the
/// ground-truth normals stay within 10 degrees of the centre's (no crease), and
/// every chord from the centre's point to a neighbour's lies within 10 degrees
/// of the centre's tangent plane (no depth step, which runs along the ray).
/// `spread_deg` receives the largest normal angle in the neighbourhood.
bool smoothInterior(const Frame& frame, int y, int x, double* spread_deg) {
  const int W = frame.depth.width(), H = frame.depth.height();
  if (x < 1 || y < 1 || x >= W - 1 || y >= H - 1) return false;
  const Vec3 n_centre = normalAt(frame.normals_gt, y, x);
  const Vec3 p_centre = backProject(frame, y, x);
  const double sin_max = std::sin(10.0 / kRadToDeg);
  *spread_deg = 0.0;
  for (int j = -1; j <= 1; ++j) {
    for (int i = -1; i <= 1; ++i) {
      if (i == 0 && j == 0) continue;
      const Vec3 p = backProject(frame, y + j, x + i);
      const Vec3 chord{p[0] - p_centre[0], p[1] - p_centre[1],
                       p[2] - p_centre[2]};
      if (std::abs(dot(n_centre, chord)) > sin_max * length(chord)) {
        return false;
      }
      const double a =
          angleDeg(n_centre, normalAt(frame.normals_gt, y + j, x + i));
      if (a > 10.0) return false;
      *spread_deg = std::max(*spread_deg, a);
    }
  }
  return true;
}

double maxChannelDifference(const ColorImage& image, int y0, int x0, int y1,
                            int x1) {
  double d = 0.0;
  for (int c = 0; c < 3; ++c) {
    d = std::max(d, static_cast<double>(
                        std::abs(image.at(c, y0, x0) - image.at(c, y1, x1))));
  }
  return d;
}

/// Mean angle in degrees between valid pixels of `a` and `b`.
double meanAngleDeg(const NormalMap& a, const NormalMap& b) {
  double sum = 0.0;
  int count = 0;
  for (int y = 0; y < a.height(); ++y) {
    for (int x = 0; x < a.width(); ++x) {
      if (!valid(a, y, x) || !valid(b, y, x)) continue;
      sum += angleDeg(normalAt(a, y, x), normalAt(b, y, x));
      ++count;
    }
  }
  return count > 0 ? sum / count : 0.0;
}

/// Binomial 4-sigma half-width of a share p measured on n trials.
double binomialTolerance(double p, std::size_t n) {
  return 4.0 * std::sqrt(p * (1.0 - p) / static_cast<double>(n)) + 1e-12;
}

TEST(Synthetic, IntrinsicsHaveCentredPixelsAndAboutSixtyDegrees) {
  const Frame frame = synthetic::renderScene(0, 160, 120);
  EXPECT_DOUBLE_EQ(frame.K.fx(), 0.9 * 160);
  EXPECT_DOUBLE_EQ(frame.K.fy(), 0.9 * 160);
  EXPECT_DOUBLE_EQ(frame.K.cx(), 79.5);
  EXPECT_DOUBLE_EQ(frame.K.cy(), 59.5);
  // Field of view between the outer edges of the outer pixels.
  const double hfov = 2.0 * std::atan(80.0 / frame.K.fx()) * kRadToDeg;
  EXPECT_GT(hfov, 55.0);
  EXPECT_LT(hfov, 65.0);
}

TEST(Synthetic, GroundTruthNormalsAreUnitAndFaceTheCameraEverywhere) {
  for (int scene = 0; scene < synthetic::kNumScenes; ++scene) {
    const Frame frame = synthetic::renderScene(scene, 160, 120);
    ASSERT_EQ(frame.normals_gt.channels(), 3);
    ASSERT_EQ(frame.image.channels(), 3);
    ASSERT_EQ(frame.depth.channels(), 1);
    int bad_normal = 0, back_facing = 0, bad_depth = 0, bad_colour = 0;
    for (int y = 0; y < 120; ++y) {
      for (int x = 0; x < 160; ++x) {
        const Vec3 n = normalAt(frame.normals_gt, y, x);
        if (!valid(frame.normals_gt, y, x) ||
            std::abs(length(n) - 1.0) > 1e-5) {
          ++bad_normal;
        }
        if (!(dot(n, rayOf(frame.K, y, x)) <= 0.0)) ++back_facing;
        const float z = frame.depth.at(0, y, x);
        if (!std::isfinite(z) || !(z > 0.0f)) ++bad_depth;
        for (int c = 0; c < 3; ++c) {
          const float v = frame.image.at(c, y, x);
          if (!(v >= 0.0f && v <= 1.0f)) ++bad_colour;
        }
      }
    }
    EXPECT_EQ(bad_normal, 0) << "scene " << scene;
    EXPECT_EQ(back_facing, 0) << "scene " << scene;
    EXPECT_EQ(bad_depth, 0) << "scene " << scene;
    EXPECT_EQ(bad_colour, 0) << "scene " << scene;
  }
}

TEST(Synthetic, GroundTruthNormalsAgreeWithRenderedDepthOnPlanes) {
  for (int scene = 0; scene < synthetic::kNumScenes; ++scene) {
    const Frame frame = synthetic::renderScene(scene, 160, 120);
    int planar = 0;
    double worst_deg = 0.0;
    for (int y = 1; y < 119; ++y) {
      for (int x = 1; x < 159; ++x) {
        if (!planarInterior(frame, y, x)) continue;
        ++planar;
        const Vec3 n = normalAt(frame.normals_gt, y, x);
        const Vec3 p = backProject(frame, y, x);
        // The ground-truth normal is orthogonal to the plane's in-image steps.
        for (const auto& step :
             {std::array<int, 2>{{0, 1}}, std::array<int, 2>{{1, 0}},
              std::array<int, 2>{{1, 1}}}) {
          const Vec3 q = backProject(frame, y + step[0], x + step[1]);
          const Vec3 d{q[0] - p[0], q[1] - p[1], q[2] - p[2]};
          worst_deg = std::max(worst_deg, std::abs(90.0 - angleDeg(n, d)));
        }
      }
    }
    // Most of every scene is planar (room, boxes); the test is not vacuous.
    EXPECT_GT(planar, 160 * 120 / 2) << "scene " << scene;
    EXPECT_LT(worst_deg, 0.05) << "scene " << scene;
  }
}

TEST(Synthetic, ImageHasTextureEdgesAndWeakGeometricEdges) {
  constexpr int W = 320, H = 240;
  for (int scene = 0; scene < synthetic::kNumScenes; ++scene) {
    const Frame frame = synthetic::renderScene(scene, W, H);
    int texture_edges = 0, weak_creases = 0, creases = 0;
    double crease_contrast_sum = 0.0;
    for (int y = 1; y < H - 2; ++y) {
      for (int x = 1; x < W - 2; ++x) {
        for (const auto& step :
             {std::array<int, 2>{{0, 1}}, std::array<int, 2>{{1, 0}}}) {
          const int y1 = y + step[0], x1 = x + step[1];
          const double contrast =
              maxChannelDifference(frame.image, y, x, y1, x1);
          // Image edge inside a plane: no geometric edge at all.
          if (planarInterior(frame, y, x) && planarInterior(frame, y1, x1) &&
              contrast > 0.15) {
            ++texture_edges;
          }
          // Crease: normals turn by > 30 degrees, depth continuous.
          const double turn = angleDeg(normalAt(frame.normals_gt, y, x),
                                       normalAt(frame.normals_gt, y1, x1));
          const double z0 = frame.depth.at(0, y, x);
          const double z1 = frame.depth.at(0, y1, x1);
          if (turn > 30.0 && std::abs(z1 - z0) < 0.02 * z0) {
            ++creases;
            crease_contrast_sum += contrast;
            if (contrast < 0.02) ++weak_creases;
          }
        }
      }
    }
    // Texture edges worth at least one image width of pixels.
    EXPECT_GE(texture_edges, W) << "scene " << scene;
    // A weak crease at least an eighth of the image high, and far weaker than
    // the texture edges' contrast threshold.
    EXPECT_GE(weak_creases, H / 8) << "scene " << scene;
    ASSERT_GT(creases, 0) << "scene " << scene;
    // Creases in general do have contrast: the weak ones are the exception.
    EXPECT_GT(crease_contrast_sum / creases, 0.02) << "scene " << scene;
  }
}

TEST(Synthetic, RenderingIsDeterministicAndUsesTheDefaultPose) {
  const Frame a = synthetic::renderScene(2, 96, 72);
  const Frame b = synthetic::renderScene(2, 96, 72, synthetic::defaultPose(2));
  EXPECT_TRUE(test::identical(a.image, b.image));
  EXPECT_TRUE(test::identical(a.normals_gt, b.normals_gt));
  EXPECT_TRUE(test::identical(a.depth, b.depth));
  const Frame other = synthetic::renderScene(1, 96, 72);
  EXPECT_FALSE(test::identical(a.image, other.image));
}

TEST(Synthetic, RejectsBadArguments) {
  EXPECT_THROW(synthetic::renderScene(-1, 32, 24), ParameterError);
  EXPECT_THROW(synthetic::renderScene(synthetic::kNumSceneIds, 32, 24),
               ParameterError);
  EXPECT_THROW(synthetic::renderScene(0, 0, 24), ParameterError);
  synthetic::Pose outside;  // identity pose: camera centre at the world origin,
  outside.t = {{0.0, 0.0, 100.0}};  // moved 100 m away
  EXPECT_THROW(synthetic::renderScene(0, 32, 24, outside), ParameterError);
  synthetic::Pose skewed = synthetic::defaultPose(0);
  for (int i = 0; i < 3; ++i) skewed.R[i] *= 1.5;
  EXPECT_THROW(synthetic::renderScene(0, 32, 24, skewed), ParameterError);
  EXPECT_THROW(synthetic::renderSequence(0, 32, 24, 0), ParameterError);
  EXPECT_THROW(synthetic::renderSequence(0, 32, 24, 2, 0.3, 0.0),
               ParameterError);
  const Frame frame = synthetic::renderScene(0, 32, 24);
  EXPECT_THROW(synthetic::addPaperNoise(frame.depth, 0.1, 1), InputError);
  EXPECT_THROW(synthetic::addPaperNoise(frame.normals_gt, -0.1, 1),
               ParameterError);
  EXPECT_THROW(synthetic::normalsFromDepth(frame.normals_gt, frame.K),
               InputError);
  EXPECT_THROW(synthetic::normalsFromNoisyDepth(frame, -1.0, 0.0, 1),
               ParameterError);
  EXPECT_THROW(synthetic::normalsFromNoisyDepth(frame, 0.001, 1.5, 1),
               ParameterError);
  EXPECT_THROW(synthetic::sparseAccurate(frame.normals_gt, 1.2, 0.0, 1),
               ParameterError);
}

TEST(Synthetic, PaperNoiseGrowsWithSigmaAndIsReproducible) {
  const Frame frame = synthetic::renderScene(0, 160, 120);
  NormalMap gt = frame.normals_gt;
  // Two missing pixels, one NaN and one zero vector.
  for (int c = 0; c < 3; ++c) {
    gt.at(c, 10, 10) = std::numeric_limits<float>::quiet_NaN();
    gt.at(c, 20, 20) = 0.0f;
  }
  double previous = 0.0;
  for (const double sigma : {0.1, 0.3, 0.6, 0.9}) {
    const NormalMap noisy = synthetic::addPaperNoise(gt, sigma, 7);
    const double mean = meanAngleDeg(noisy, gt);
    EXPECT_GT(mean, previous) << "sigma " << sigma;
    previous = mean;
    EXPECT_FALSE(valid(noisy, 10, 10));
    EXPECT_FALSE(valid(noisy, 20, 20));
    EXPECT_TRUE(test::identical(noisy, synthetic::addPaperNoise(gt, sigma, 7)));
    EXPECT_FALSE(
        test::identical(noisy, synthetic::addPaperNoise(gt, sigma, 8)));
    int not_unit = 0;
    for (std::size_t i = 0; i < noisy.pixelCount(); ++i) {
      const Vec3 n{noisy.plane(0)[i], noisy.plane(1)[i], noisy.plane(2)[i]};
      if (isValidNormal(n[0], n[1], n[2]) && std::abs(length(n) - 1.0) > 1e-5) {
        ++not_unit;
      }
    }
    EXPECT_EQ(not_unit, 0);
  }
  // Small sigma: the tangential offset is 2-D Gaussian, so the angle is
  // Rayleigh distributed with mean sigma sqrt(pi / 2) = 7.18 degrees at 0.1.
  const double mean_01 = meanAngleDeg(synthetic::addPaperNoise(gt, 0.1, 3), gt);
  EXPECT_NEAR(mean_01, 0.1 * std::sqrt(kPi / 2.0) * kRadToDeg, 0.4);
  EXPECT_TRUE(test::identical(synthetic::addPaperNoise(gt, 0.0, 3), gt));
}

TEST(Synthetic, NormalsFromExactDepthMatchGroundTruth) {
  for (int scene = 0; scene < synthetic::kNumScenes; ++scene) {
    const Frame frame = synthetic::renderScene(scene, 160, 120);
    // Zero noise, no quantization, no dropout: the depth is unchanged.
    const ScalarMap depth =
        synthetic::addDepthNoise(frame.depth, 0.0, 0.0, 0.0, 5);
    EXPECT_TRUE(test::identical(depth, frame.depth));
    const NormalMap derived = synthetic::normalsFromDepth(depth, frame.K);
    int planar = 0, smooth = 0, planar_bad = 0, smooth_bad = 0;
    for (int y = 1; y < 119; ++y) {
      for (int x = 1; x < 159; ++x) {
        ASSERT_TRUE(valid(derived, y, x));
        const double error =
            angleDeg(normalAt(derived, y, x), normalAt(frame.normals_gt, y, x));
        double spread = 0.0;
        if (planarInterior(frame, y, x)) {
          ++planar;
          if (error > 0.05) ++planar_bad;
        } else if (smoothInterior(frame, y, x, &spread)) {
          // Curved: the chords are tangent somewhere in the neighbourhood.
          ++smooth;
          if (error > spread + 0.05) ++smooth_bad;
        }
      }
    }
    EXPECT_GT(planar, 160 * 120 / 2) << "scene " << scene;
    EXPECT_EQ(planar_bad, 0) << "scene " << scene;
    if (scene >= 1) {
      EXPECT_GT(smooth, 300) << "scene " << scene;  // spheres, cylinders
    }
    EXPECT_EQ(smooth_bad, 0) << "scene " << scene;
    // Border pixels have no central difference.
    EXPECT_FALSE(valid(derived, 0, 5));
    EXPECT_FALSE(valid(derived, 5, 159));
  }
}

TEST(Synthetic, NormalsFromZeroNoiseDepthMatchGroundTruthWithinQuantization) {
  const Frame frame = synthetic::renderScene(0, 160, 120);
  const NormalMap derived =
      synthetic::normalsFromNoisyDepth(frame, 0.0, 0.0, 9);
  const double q = synthetic::kDepthQuantizationM;
  int checked = 0, beyond_bound = 0, tight = 0;
  for (int y = 1; y < 119; ++y) {
    for (int x = 1; x < 159; ++x) {
      if (!planarInterior(frame, y, x)) continue;
      ASSERT_TRUE(valid(derived, y, x));
      // Each point moves by at most q/2 along its ray: the difference vectors
      // du, dv move by at most q |r|max, so N = du x dv moves by at most
      // e = q r (|du| + |dv|) + (q r)^2, and the normal turns by at most
      // asin(e / |N|).
      const Vec3 du_a = backProject(frame, y, x + 1);
      const Vec3 du_b = backProject(frame, y, x - 1);
      const Vec3 dv_a = backProject(frame, y + 1, x);
      const Vec3 dv_b = backProject(frame, y - 1, x);
      const Vec3 du{du_a[0] - du_b[0], du_a[1] - du_b[1], du_a[2] - du_b[2]};
      const Vec3 dv{dv_a[0] - dv_b[0], dv_a[1] - dv_b[1], dv_a[2] - dv_b[2]};
      double r_max = 0.0;
      for (const auto& p :
           {std::array<int, 2>{{y, x + 1}}, std::array<int, 2>{{y, x - 1}},
            std::array<int, 2>{{y + 1, x}}, std::array<int, 2>{{y - 1, x}}}) {
        r_max = std::max(r_max, length(rayOf(frame.K, p[0], p[1])));
      }
      const double e =
          q * r_max * (length(du) + length(dv)) + (q * r_max) * (q * r_max);
      const double n_len = length(cross(du, dv));
      if (e >= 0.5 * n_len) continue;  // bound not informative
      ++checked;
      const double bound_deg = std::asin(e / n_len) * kRadToDeg + 0.01;
      const double error =
          angleDeg(normalAt(derived, y, x), normalAt(frame.normals_gt, y, x));
      if (error > bound_deg) ++beyond_bound;
      if (bound_deg < 2.0) ++tight;
    }
  }
  EXPECT_GT(checked, 160 * 120 / 2);
  // The bound is tight (< 2 degrees) on most of the checked pixels.
  EXPECT_GT(tight, checked / 2);
  EXPECT_EQ(beyond_bound, 0);
}

TEST(Synthetic, NoisyDepthNormalsAreMissingExactlyWhereDepthIs) {
  const Frame frame = synthetic::renderScene(1, 160, 120);
  const double dropout = 0.05;
  const ScalarMap depth = synthetic::addDepthNoise(
      frame.depth, 0.002, synthetic::kDepthQuantizationM, dropout, 11);
  std::size_t lost = 0;
  for (std::size_t i = 0; i < depth.pixelCount(); ++i) {
    if (std::isnan(depth.data()[i])) ++lost;
  }
  const double share = static_cast<double>(lost) / depth.pixelCount();
  EXPECT_NEAR(share, dropout, binomialTolerance(dropout, depth.pixelCount()));
  // The composed function is the documented composition.
  const NormalMap normals =
      synthetic::normalsFromNoisyDepth(frame, 0.002, dropout, 11);
  EXPECT_TRUE(
      test::identical(normals, synthetic::normalsFromDepth(depth, frame.K)));
  int wrong_mask = 0, back_facing = 0;
  for (int y = 0; y < 120; ++y) {
    for (int x = 0; x < 160; ++x) {
      const bool inside = x > 0 && y > 0 && x < 159 && y < 119;
      const auto has = [&](int yy, int xx) {
        return !std::isnan(depth.at(0, yy, xx));
      };
      const bool expected = inside && has(y, x) && has(y, x - 1) &&
                            has(y, x + 1) && has(y - 1, x) && has(y + 1, x);
      if (valid(normals, y, x) != expected) ++wrong_mask;
      if (valid(normals, y, x) &&
          dot(normalAt(normals, y, x), rayOf(frame.K, y, x)) > 0.0) {
        ++back_facing;
      }
    }
  }
  EXPECT_EQ(wrong_mask, 0);
  EXPECT_EQ(back_facing, 0);
}

TEST(Synthetic, NoisyDepthNormalErrorGrowsWithDepthNoise) {
  const Frame frame = synthetic::renderScene(0, 160, 120);
  double previous = 0.0;
  for (const double sigma : {0.0005, 0.002, 0.008}) {
    const NormalMap noisy =
        synthetic::normalsFromNoisyDepth(frame, sigma, 0.0, 4);
    const double mean = meanAngleDeg(noisy, frame.normals_gt);
    EXPECT_GT(mean, previous) << "sigma " << sigma;
    previous = mean;
    EXPECT_TRUE(test::identical(
        noisy, synthetic::normalsFromNoisyDepth(frame, sigma, 0.0, 4)));
    EXPECT_FALSE(test::identical(
        noisy, synthetic::normalsFromNoisyDepth(frame, sigma, 0.0, 5)));
  }
}

TEST(Synthetic, SparseAccurateKeepsTheRequestedShareSpreadOverTheImage) {
  constexpr int W = 320, H = 240;
  const Frame frame = synthetic::renderScene(2, W, H);
  for (const double density : {0.02, 0.3}) {
    const NormalMap sparse =
        synthetic::sparseAccurate(frame.normals_gt, density, 0.0, 21);
    std::array<std::size_t, 4> kept_per_quadrant{{0, 0, 0, 0}};
    int changed = 0;
    for (int y = 0; y < H; ++y) {
      for (int x = 0; x < W; ++x) {
        if (!valid(sparse, y, x)) continue;
        ++kept_per_quadrant[(y < H / 2 ? 0 : 2) + (x < W / 2 ? 0 : 1)];
        for (int c = 0; c < 3; ++c) {
          if (sparse.at(c, y, x) != frame.normals_gt.at(c, y, x)) ++changed;
        }
      }
    }
    std::size_t kept = 0;
    for (std::size_t k : kept_per_quadrant) kept += k;
    const std::size_t n = static_cast<std::size_t>(W) * H;
    EXPECT_NEAR(static_cast<double>(kept) / n, density,
                binomialTolerance(density, n));
    for (std::size_t k : kept_per_quadrant) {
      EXPECT_NEAR(static_cast<double>(k) / (n / 4), density,
                  binomialTolerance(density, n / 4));
    }
    EXPECT_EQ(changed, 0);  // sigma = 0 keeps the ground truth exactly
    EXPECT_TRUE(test::identical(
        sparse, synthetic::sparseAccurate(frame.normals_gt, density, 0.0, 21)));
  }
  // With noise, the kept normals move; the mask does not depend on sigma.
  const NormalMap exact =
      synthetic::sparseAccurate(frame.normals_gt, 0.1, 0.0, 3);
  const NormalMap noisy =
      synthetic::sparseAccurate(frame.normals_gt, 0.1, 0.2, 3);
  int mask_differs = 0;
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      if (valid(exact, y, x) != valid(noisy, y, x)) ++mask_differs;
    }
  }
  EXPECT_EQ(mask_differs, 0);
  EXPECT_GT(meanAngleDeg(noisy, frame.normals_gt), 5.0);
  std::size_t none = 0, all = 0;
  const NormalMap empty =
      synthetic::sparseAccurate(frame.normals_gt, 0.0, 0.0, 1);
  const NormalMap full =
      synthetic::sparseAccurate(frame.normals_gt, 1.0, 0.0, 1);
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      none += valid(empty, y, x) ? 1 : 0;
      all += valid(full, y, x) ? 1 : 0;
    }
  }
  EXPECT_EQ(none, 0u);
  EXPECT_EQ(all, static_cast<std::size_t>(W) * H);
}

TEST(Synthetic, SequenceMovesSlowlyAndConsistently) {
  constexpr int W = 96, H = 72, kFrames = 5;
  const double degrees_per_frame = 0.5, fps = 30.0;
  const std::vector<Frame> frames =
      synthetic::renderSequence(0, W, H, kFrames, degrees_per_frame, fps);
  ASSERT_EQ(frames.size(), static_cast<std::size_t>(kFrames));
  const synthetic::Pose start = synthetic::defaultPose(0);
  for (int i = 0; i < 9; ++i) {
    EXPECT_DOUBLE_EQ(frames[0].pose.R[i], start.R[i]);
  }
  for (int i = 0; i < 3; ++i) {
    EXPECT_NEAR(frames[0].pose.t[i], start.t[i], 1e-12);
  }
  const auto centre = [](const synthetic::Pose& pose) {
    const Vec3 t{pose.t[0], pose.t[1], pose.t[2]};
    return Vec3{-toWorld(pose, t)[0], -toWorld(pose, t)[1],
                -toWorld(pose, t)[2]};
  };
  for (int k = 0; k + 1 < kFrames; ++k) {
    const Frame& a = frames[k];
    const Frame& b = frames[k + 1];
    EXPECT_NEAR(b.stamp - a.stamp, 1.0 / fps, 1e-12);
    EXPECT_NEAR(a.stamp, k / fps, 1e-12);
    // Relative rotation R_b R_a^T: angle from its trace.
    const auto& Ra = a.pose.R;
    const auto& Rb = b.pose.R;
    double trace = 0.0;
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) trace += Rb[3 * i + j] * Ra[3 * i + j];
    }
    const double angle =
        std::acos(std::max(-1.0, std::min(1.0, 0.5 * (trace - 1.0)))) *
        kRadToDeg;
    EXPECT_NEAR(angle, degrees_per_frame, 0.05 * degrees_per_frame);
    // A few millimetres of translation per frame.
    const Vec3 ca = centre(a.pose), cb = centre(b.pose);
    const double step = length({cb[0] - ca[0], cb[1] - ca[1], cb[2] - ca[2]});
    EXPECT_GT(step, 0.001);
    EXPECT_LT(step, 0.010);
    // Consistency: a surface point of frame a, seen again in frame b at its
    // projection, has the same world normal.
    int checked = 0, agree = 0;
    for (int y = 1; y < H - 1; ++y) {
      for (int x = 1; x < W - 1; ++x) {
        if (!planarInterior(a, y, x)) continue;
        const Vec3 p_a = backProject(a, y, x);
        // World point X = R_a^T (p_a - t_a); camera b: p_b = R_b X + t_b.
        const Vec3 rel{p_a[0] - a.pose.t[0], p_a[1] - a.pose.t[1],
                       p_a[2] - a.pose.t[2]};
        const Vec3 X = toWorld(a.pose, rel);
        Vec3 p_b{b.pose.t[0], b.pose.t[1], b.pose.t[2]};
        for (int i = 0; i < 3; ++i) {
          for (int j = 0; j < 3; ++j) p_b[i] += Rb[3 * i + j] * X[j];
        }
        const int u = static_cast<int>(
            std::lround(b.K.fx() * p_b[0] / p_b[2] + b.K.cx()));
        const int v = static_cast<int>(
            std::lround(b.K.fy() * p_b[1] / p_b[2] + b.K.cy()));
        if (!planarInterior(b, v, u)) continue;
        if (std::abs(b.depth.at(0, v, u) - p_b[2]) > 0.01 * p_b[2]) continue;
        ++checked;
        const double turn =
            angleDeg(toWorld(a.pose, normalAt(a.normals_gt, y, x)),
                     toWorld(b.pose, normalAt(b.normals_gt, v, u)));
        if (turn < 0.01) ++agree;
      }
    }
    EXPECT_GT(checked, W * H / 2);
    EXPECT_EQ(agree, checked);
    // The images change, but only a little.
    double mean_change = 0.0;
    for (std::size_t i = 0; i < a.image.pixelCount() * 3; ++i) {
      mean_change += std::abs(a.image.data()[i] - b.image.data()[i]);
    }
    mean_change /= a.image.pixelCount() * 3;
    EXPECT_GT(mean_change, 0.0);
    EXPECT_LT(mean_change, 0.1);
  }
}

}  // namespace
}  // namespace normal_fusion
