// Tests of the accuracy metrics: PSNR and angular-error statistics.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <limits>
#include <vector>

#include "normal_fusion/errors.h"
#include "normal_fusion/metrics.h"

namespace normal_fusion {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kDegToRad = kPi / 180.0;
using Vec3 = std::array<double, 3>;

Vec3 normalized(const Vec3& v) {
  const double len = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
  return {v[0] / len, v[1] / len, v[2] / len};
}

Vec3 cross(const Vec3& a, const Vec3& b) {
  return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
          a[0] * b[1] - a[1] * b[0]};
}

/// A unit vector at exactly `angle_deg` from the unit vector n (rotation of n
/// about an axis perpendicular to it).
Vec3 tiltedBy(const Vec3& n, double angle_deg) {
  const Vec3 helper = std::fabs(n[0]) < 0.9 ? Vec3{1, 0, 0} : Vec3{0, 1, 0};
  const Vec3 u = normalized(cross(n, helper));
  const double a = angle_deg * kDegToRad;
  return {std::cos(a) * n[0] + std::sin(a) * u[0],
          std::cos(a) * n[1] + std::sin(a) * u[1],
          std::cos(a) * n[2] + std::sin(a) * u[2]};
}

void setNormal(NormalMap* map, int y, int x, const Vec3& n) {
  for (int c = 0; c < 3; ++c) map->at(c, y, x) = static_cast<float>(n[c]);
}

/// A W x H map of smoothly varying unit normals facing the camera.
NormalMap groundTruth(int W, int H) {
  NormalMap gt(W, H, 3);
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      setNormal(
          &gt, y, x,
          normalized({0.6 * (x - W / 2.0) / W, 0.4 * (y - H / 2.0) / H, -1.0}));
    }
  }
  return gt;
}

Vec3 normalAt(const NormalMap& map, int y, int x) {
  return {map.at(0, y, x), map.at(1, y, x), map.at(2, y, x)};
}

/// The ground truth with every pixel tilted by angle_deg.
NormalMap tiltedMap(const NormalMap& gt, double angle_deg) {
  NormalMap out(gt.width(), gt.height(), 3);
  for (int y = 0; y < gt.height(); ++y) {
    for (int x = 0; x < gt.width(); ++x) {
      setNormal(&out, y, x, tiltedBy(normalAt(gt, y, x), angle_deg));
    }
  }
  return out;
}

/// Closed-form PSNR for a constant angular error a: MSE = 2 (1 - cos a).
double psnrOfConstantAngle(double angle_deg) {
  return 10.0 *
         std::log10(4.0 / (2.0 * (1.0 - std::cos(angle_deg * kDegToRad))));
}

TEST(Psnr, IdenticalMapsGivePositiveInfinity) {
  const NormalMap gt = groundTruth(16, 12);
  const double value = psnr(gt, gt);
  EXPECT_TRUE(std::isinf(value));
  EXPECT_GT(value, 0.0);
}

TEST(Psnr, ConstantAngleErrorMatchesClosedForm) {
  const NormalMap gt = groundTruth(24, 16);
  for (double angle_deg : {1.0, 10.0, 45.0, 90.0, 170.0}) {
    const NormalMap estimate = tiltedMap(gt, angle_deg);
    EXPECT_NEAR(psnr(estimate, gt), psnrOfConstantAngle(angle_deg), 1e-3)
        << "angle " << angle_deg << " deg";
  }
}

TEST(Psnr, OppositeNormalsGiveZeroDecibels) {
  // |n - (-n)|^2 = 4 = d_max^2 everywhere.
  const NormalMap gt = groundTruth(8, 8);
  NormalMap flipped = gt;
  for (std::size_t i = 0; i < flipped.pixelCount() * 3; ++i) {
    flipped.data()[i] = -flipped.data()[i];
  }
  EXPECT_NEAR(psnr(flipped, gt), 0.0, 1e-5);
}

TEST(Psnr, MeanIsOverPixelsNotSumOfSquares) {
  // Half the pixels exact, half at 60 degrees: MSE = (0 + 1) / 2.
  const NormalMap gt = groundTruth(10, 10);
  NormalMap estimate = gt;
  for (int y = 0; y < 10; ++y) {
    for (int x = 0; x < 5; ++x) {
      setNormal(&estimate, y, x, tiltedBy(normalAt(gt, y, x), 60.0));
    }
  }
  EXPECT_NEAR(psnr(estimate, gt), 10.0 * std::log10(4.0 / 0.5), 1e-4);
}

/// A 1 x N pair of maps whose i-th pixel is off by angles_deg[i].
void mapsWithAngles(const std::vector<double>& angles_deg, NormalMap* estimate,
                    NormalMap* gt) {
  const int n = static_cast<int>(angles_deg.size());
  *gt = groundTruth(n, 1);
  estimate->resize(n, 1, 3);
  for (int x = 0; x < n; ++x) {
    setNormal(estimate, 0, x, tiltedBy(normalAt(*gt, 0, x), angles_deg[x]));
  }
}

TEST(AngularError, StatisticsOfKnownAngles) {
  NormalMap estimate, gt;
  // Unsorted on purpose; sorted: 5, 10, 20, 25, 40.
  mapsWithAngles({25.0, 5.0, 40.0, 10.0, 20.0}, &estimate, &gt);
  const AngularErrorStats stats = angularError(estimate, gt);
  EXPECT_EQ(stats.pixel_count, 5);
  EXPECT_NEAR(stats.mean_deg, 20.0, 1e-4);
  EXPECT_NEAR(stats.median_deg, 20.0, 1e-4);
  EXPECT_DOUBLE_EQ(stats.within_11_25, 2.0 / 5.0);
  EXPECT_DOUBLE_EQ(stats.within_22_5, 3.0 / 5.0);
  EXPECT_DOUBLE_EQ(stats.within_30, 4.0 / 5.0);
}

TEST(AngularError, MedianOfEvenCountIsMeanOfMiddlePair) {
  NormalMap estimate, gt;
  mapsWithAngles({40.0, 5.0, 20.0, 10.0, 3.0, 90.0}, &estimate, &gt);
  const AngularErrorStats stats = angularError(estimate, gt);
  EXPECT_EQ(stats.pixel_count, 6);
  EXPECT_NEAR(stats.median_deg, 15.0, 1e-4);
  EXPECT_NEAR(stats.mean_deg, 168.0 / 6.0, 1e-4);
}

TEST(AngularError, AccurateAtSmallAngles) {
  // An acos of the dot product in float inputs would be off by tens of percent.
  for (double angle_deg : {0.05, 0.01}) {
    NormalMap estimate, gt;
    mapsWithAngles({angle_deg, angle_deg, angle_deg}, &estimate, &gt);
    const AngularErrorStats stats = angularError(estimate, gt);
    EXPECT_NEAR(stats.mean_deg, angle_deg, 0.01 * angle_deg);
  }
}

TEST(AngularError, ObtuseAnglesUpTo180) {
  NormalMap estimate, gt;
  mapsWithAngles({120.0, 179.0}, &estimate, &gt);
  const ScalarMap error_deg = angularErrorMap(estimate, gt);
  EXPECT_NEAR(error_deg.at(0, 0, 0), 120.0, 1e-3);
  EXPECT_NEAR(error_deg.at(0, 0, 1), 179.0, 1e-3);
}

TEST(AngularError, ErrorMapMatchesAnglesAndMarksInvalidPixels) {
  NormalMap estimate, gt;
  mapsWithAngles({7.0, 33.0, 12.0, 50.0}, &estimate, &gt);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  setNormal(&estimate, 0, 1, {nan, nan, nan});
  setNormal(&gt, 0, 3, {0.0, 0.0, 0.0});
  const ScalarMap error_deg = angularErrorMap(estimate, gt);
  ASSERT_EQ(error_deg.channels(), 1);
  ASSERT_TRUE(error_deg.sameSize(gt));
  EXPECT_NEAR(error_deg.at(0, 0, 0), 7.0, 1e-3);
  EXPECT_TRUE(std::isnan(error_deg.at(0, 0, 1)));
  EXPECT_NEAR(error_deg.at(0, 0, 2), 12.0, 1e-3);
  EXPECT_TRUE(std::isnan(error_deg.at(0, 0, 3)));
}

TEST(Metrics, InvalidPixelsAndMaskAreSkipped) {
  // Pixels: 10 deg, 20 deg, invalid estimate (NaN), invalid truth (zero),
  // 80 deg (masked out), 29 deg.
  NormalMap estimate, gt;
  mapsWithAngles({10.0, 20.0, 50.0, 60.0, 80.0, 29.0}, &estimate, &gt);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  setNormal(&estimate, 0, 2, {nan, 0.0, 1.0});
  setNormal(&gt, 0, 3, {0.0, 0.0, 0.0});
  ScalarMap mask(6, 1, 1, 1.0f);
  mask.at(0, 0, 4) = 0.2f;

  const AngularErrorStats stats = angularError(estimate, gt, mask);
  EXPECT_EQ(stats.pixel_count, 3);
  EXPECT_NEAR(stats.mean_deg, 59.0 / 3.0, 1e-4);
  EXPECT_NEAR(stats.median_deg, 20.0, 1e-4);
  EXPECT_DOUBLE_EQ(stats.within_11_25, 1.0 / 3.0);
  EXPECT_DOUBLE_EQ(stats.within_30, 1.0);

  // PSNR over the same three pixels: MSE = mean of 2 (1 - cos a).
  double mse = 0.0;
  for (double a : {10.0, 20.0, 29.0})
    mse += 2.0 * (1.0 - std::cos(a * kDegToRad));
  mse /= 3.0;
  EXPECT_NEAR(psnr(estimate, gt, mask), 10.0 * std::log10(4.0 / mse), 1e-4);

  // Without the mask the 80-degree pixel counts.
  const AngularErrorStats unmasked = angularError(estimate, gt);
  EXPECT_EQ(unmasked.pixel_count, 4);
  EXPECT_NEAR(unmasked.mean_deg, 139.0 / 4.0, 1e-4);
}

TEST(Metrics, MismatchedInputsThrow) {
  const NormalMap gt = groundTruth(8, 6);
  const NormalMap smaller = groundTruth(8, 5);
  const ScalarMap one_plane(8, 6, 1, 1.0f);
  EXPECT_THROW(psnr(smaller, gt), InputError);
  EXPECT_THROW(angularError(smaller, gt), InputError);
  EXPECT_THROW(angularErrorMap(smaller, gt), InputError);
  // A 1-plane "normal map".
  EXPECT_THROW(psnr(one_plane, gt), InputError);
  EXPECT_THROW(angularError(gt, one_plane), InputError);
  // A mask of the wrong size or with three planes.
  EXPECT_THROW(psnr(gt, gt, ScalarMap(8, 5, 1, 1.0f)), InputError);
  EXPECT_THROW(angularError(gt, gt, ScalarMap(8, 6, 3, 1.0f)), InputError);
}

TEST(Metrics, NothingEvaluatedThrows) {
  const NormalMap gt = groundTruth(8, 6);
  const ScalarMap mask_none(8, 6, 1, 0.0f);
  EXPECT_THROW(psnr(gt, gt, mask_none), InputError);
  EXPECT_THROW(angularError(gt, gt, mask_none), InputError);
  const NormalMap missing(8, 6, 3, std::numeric_limits<float>::quiet_NaN());
  EXPECT_THROW(psnr(missing, gt), InputError);
  EXPECT_THROW(angularError(gt, missing), InputError);
  EXPECT_THROW(psnr(NormalMap(0, 0, 3), NormalMap(0, 0, 3)), InputError);
}

}  // namespace
}  // namespace normal_fusion
