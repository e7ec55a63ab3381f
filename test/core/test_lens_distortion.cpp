// Lens distortion (lens_distortion.h): the models' equations at known points,
// undistort as the inverse of distort, the CameraInfo rules and the
// fold-back check.
#include "normal_fusion/lens_distortion.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include "normal_fusion/errors.h"

namespace nf = normal_fusion;
using Model = nf::LensDistortion::Model;

namespace {

nf::LensDistortion plumbBob(double k1, double k2, double p1, double p2,
                            double k3) {
  return nf::LensDistortion::fromCameraInfo("plumb_bob", {k1, k2, p1, p2, k3},
                                            "/cam");
}

TEST(LensDistortion, EquationsAtKnownPoints) {
  // Radial only: r^2 = 0.25, radial = 1 + 0.1 * 0.25 = 1.025.
  double xd, yd;
  plumbBob(0.1, 0, 0, 0, 0).distort(0.5, 0.0, &xd, &yd);
  EXPECT_NEAR(xd, 0.5125, 1e-15);
  EXPECT_NEAR(yd, 0.0, 1e-15);
  // Tangential only at (0.2, 0.1): r^2 = 0.05;
  // x_d = 0.2 + 2 p1 x y + p2 (r^2 + 2 x^2), y_d = 0.1 + p1 (r^2 + 2 y^2) +
  // 2 p2 x y.
  plumbBob(0, 0, 0.01, 0.02, 0).distort(0.2, 0.1, &xd, &yd);
  EXPECT_NEAR(xd, 0.2 + 2 * 0.01 * 0.02 + 0.02 * (0.05 + 0.08), 1e-15);
  EXPECT_NEAR(yd, 0.1 + 0.01 * (0.05 + 0.02) + 2 * 0.02 * 0.02, 1e-15);
  // Rational: radial = (1 + k1 r^2) / (1 + k4 r^2) at r^2 = 0.25.
  const nf::LensDistortion rational = nf::LensDistortion::fromCameraInfo(
      "rational_polynomial", {0.2, 0, 0, 0, 0, 0.4, 0, 0}, "/cam");
  EXPECT_EQ(rational.model, Model::kRationalPolynomial);
  rational.distort(0.0, -0.5, &xd, &yd);
  EXPECT_NEAR(yd, -0.5 * 1.05 / 1.1, 1e-15);
}

TEST(LensDistortion, UndistortInvertsDistort) {
  const std::vector<nf::LensDistortion> lenses = {
      plumbBob(0.12, -0.25, 0.001, -0.0005, 0.1),
      plumbBob(-0.28, 0.07, 0.0002, 0.0003, 0.0),
      nf::LensDistortion::fromCameraInfo(
          "rational_polynomial",
          {2.1, 0.8, 0.0004, -0.0002, 0.02, 2.4, 1.3, 0.1}, "/cam")};
  for (const nf::LensDistortion& lens : lenses) {
    for (double x = -0.6; x <= 0.6; x += 0.05) {
      for (double y = -0.45; y <= 0.45; y += 0.05) {
        double xd, yd, xu, yu;
        lens.distort(x, y, &xd, &yd);
        ASSERT_TRUE(lens.undistort(xd, yd, &xu, &yu)) << x << " " << y;
        EXPECT_NEAR(xu, x, 1e-9);
        EXPECT_NEAR(yu, y, 1e-9);
      }
    }
  }
}

TEST(LensDistortion, CameraInfoRules) {
  EXPECT_TRUE(nf::LensDistortion::fromCameraInfo("", {}, "/c").isIdentity());
  EXPECT_EQ(
      nf::LensDistortion::fromCameraInfo("plumb_bob", {0, 0, 0, 0, 0}, "/c")
          .model,
      Model::kNone);
  // Nothing to undo, whatever the model's name.
  EXPECT_TRUE(
      nf::LensDistortion::fromCameraInfo("equidistant", {0, 0, 0, 0}, "/c")
          .isIdentity());
  EXPECT_EQ(plumbBob(0.1, 0, 0, 0, 0).model, Model::kPlumbBob);
  const auto message = [](const std::string& model,
                          const std::vector<double>& D) {
    try {
      nf::LensDistortion::fromCameraInfo(model, D, "/camera/color/camera_info");
    } catch (const nf::InputError& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  EXPECT_NE(message("equidistant", {0.1, 0, 0, 0}).find("not supported"),
            std::string::npos);
  EXPECT_NE(message("plumb_bob", {0.1, 0, 0, 0}).find("expected 5"),
            std::string::npos);
  EXPECT_NE(
      message("rational_polynomial", {0.1, 0, 0, 0, 0}).find("expected 8"),
      std::string::npos);
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const std::string not_finite = message("plumb_bob", {nan, 0, 0, 0, 0});
  EXPECT_NE(not_finite.find("/camera/color/camera_info"), std::string::npos);
  EXPECT_NE(not_finite.find("D[0]"), std::string::npos);
}

TEST(LensDistortion, FoldBackIsFound) {
  // r_d = r (1 - 0.5 r^2) turns at r = sqrt(2 / 3).
  const nf::LensDistortion lens = plumbBob(-0.5, 0, 0, 0, 0);
  EXPECT_TRUE(lens.monotonicUpTo(0.8));
  EXPECT_FALSE(lens.monotonicUpTo(0.85));
  EXPECT_TRUE(nf::LensDistortion().monotonicUpTo(100.0));
  EXPECT_EQ(nf::toString(Model::kRationalPolynomial), "rational_polynomial");
}

}  // namespace
