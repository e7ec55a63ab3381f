// Tests of the stereo pieces (the rendered pair, disparity and depth, SGBM)
// and of the Middlebury Aloe loader.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <random>
#include <vector>

#include "eval/aloe.h"
#include "eval/stereo.h"
#include "eval/synthetic.h"
#include "normal_fusion/metrics.h"

namespace normal_fusion {
namespace {

TEST(Stereo, ConstantDisparityIsAFrontoParallelPlaneAtFbOverD) {
  ScalarMap disparity(40, 30, 1, 12.5f);
  disparity.at(0, 3, 4) = 0.0f;  // no match
  disparity.at(0, 5, 6) = std::numeric_limits<float>::quiet_NaN();
  const double f = 250.0, b = 0.08;
  const ScalarMap depth = stereo::depthFromDisparity(disparity, f, b);
  for (int y = 0; y < 30; ++y) {
    for (int x = 0; x < 40; ++x) {
      if ((y == 3 && x == 4) || (y == 5 && x == 6)) {
        EXPECT_TRUE(std::isnan(depth.at(0, y, x)));
      } else {
        EXPECT_FLOAT_EQ(depth.at(0, y, x), static_cast<float>(f * b / 12.5));
      }
    }
  }
  const ScalarMap back = stereo::disparityFromDepth(depth, f, b);
  EXPECT_FLOAT_EQ(back.at(0, 10, 10), 12.5f);
}

TEST(Stereo, RightCameraSitsOneBaselineAlongTheLeftCamerasX) {
  const synthetic::Pose left =
      synthetic::defaultPose(synthetic::kTexturedRoomScene);
  const synthetic::Pose right = stereo::rightCameraPose(left, 0.1);
  // Centres C = -R^T t.
  const auto centre = [](const synthetic::Pose& p) {
    const auto& R = p.R;
    return Vec3{{-(R[0] * p.t[0] + R[3] * p.t[1] + R[6] * p.t[2]),
                 -(R[1] * p.t[0] + R[4] * p.t[1] + R[7] * p.t[2]),
                 -(R[2] * p.t[0] + R[5] * p.t[1] + R[8] * p.t[2])}};
  };
  const Vec3 cl = centre(left), cr = centre(right);
  // The left camera's x axis in the world is the first row of R.
  for (int a = 0; a < 3; ++a) {
    EXPECT_NEAR(cr[a] - cl[a], 0.1 * left.R[a], 1e-12);
  }
}

TEST(Stereo, SgbmOfARenderedFrontoParallelWallGivesItsDepth) {
  // Looking along -y at the noise-textured right wall of the corner scene,
  // 1.5 m away, nothing in between.
  synthetic::Pose pose;
  pose.R = {{-1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, -1.0, 0.0}};
  const Vec3 centre{{1.5, -1.0, 2.0}};
  for (int r = 0; r < 3; ++r) {
    pose.t[r] = -(pose.R[3 * r] * centre[0] + pose.R[3 * r + 1] * centre[1] +
                  pose.R[3 * r + 2] * centre[2]);
  }
  const double b = 0.08;
  const stereo::StereoPair pair = stereo::renderStereoPair(
      synthetic::kTexturedCornerScene, 320, 240, b, pose);
  const double f = pair.left.K.fx();
  stereo::SgbmSettings settings;
  settings.num_disparities = 32;
  const ScalarMap depth = stereo::depthFromDisparity(
      stereo::sgbmDisparity(pair.left.image, pair.right.image, settings), f, b);
  // In disparity: SGBM's sub-pixel estimate leans to whole pixels.
  const double d_true = f * b / 1.5;
  std::vector<double> error_px;
  for (int y = 0; y < 240; ++y) {
    for (int x = settings.num_disparities; x < 320; ++x) {
      ASSERT_NEAR(pair.left.depth.at(0, y, x), 1.5, 1e-4);
      const double z = depth.at(0, y, x);
      if (std::isfinite(z)) error_px.push_back(std::abs(f * b / z - d_true));
    }
  }
  ASSERT_GT(error_px.size(), 0.8 * 240 * (320 - settings.num_disparities));
  std::sort(error_px.begin(), error_px.end());
  EXPECT_LT(error_px[error_px.size() / 2], 0.5);
  EXPECT_LT(error_px[error_px.size() * 9 / 10], 1.0);
}

TEST(Stereo, ReducedDisparityIsTheBlockMeanOverTheFactor) {
  ScalarMap d(4, 2, 1, 10.0f);
  d.at(0, 0, 1) = 10.5f;  // block 0: 10, 10.5, 10, 10
  d.at(0, 1, 3) = 14.0f;  // block 1 spans a jump
  const ScalarMap r = stereo::reduceDisparity(d, 2);
  ASSERT_EQ(r.width(), 2);
  EXPECT_FLOAT_EQ(r.at(0, 0, 0), (10.0f * 3 + 10.5f) / 4 / 2);
  EXPECT_TRUE(std::isnan(r.at(0, 0, 1)));
}

TEST(Stereo, ErrorCorrelationTellsPerPixelNoiseFromBlobs) {
  ScalarMap truth(200, 100, 1, 2.0f), speckle = truth, blobs = truth;
  std::mt19937_64 rng(5);
  std::normal_distribution<double> gauss(0.0, 0.01);
  for (int y = 0; y < 100; ++y) {
    double blob = 0.0;
    for (int x = 0; x < 200; ++x) {
      if (x % 25 == 0) blob = gauss(rng);  // one offset per 25-pixel run
      speckle.at(0, y, x) += static_cast<float>(gauss(rng));
      blobs.at(0, y, x) += static_cast<float>(blob);
    }
  }
  EXPECT_LT(std::abs(stereo::errorCorrelation(speckle, truth, 1)), 0.1);
  EXPECT_GT(stereo::errorCorrelation(blobs, truth, 1), 0.8);
}

TEST(Aloe, MissingFilesGiveANoteNotAnError) {
  aloe::AloeSettings settings;
  settings.directory = "/nonexistent/aloe";
  EXPECT_FALSE(aloe::available(settings.directory));
  const aloe::AloeData data = aloe::load(settings);
  EXPECT_FALSE(data.found);
  EXPECT_NE(data.note.find("aloeL.jpg"), std::string::npos);
  EXPECT_NE(data.note.find("opencv-doc"), std::string::npos);
  settings.downscale = 0;
  EXPECT_THROW(aloe::load(settings), ParameterError);
}

TEST(Aloe, LoadsThePairReducedWithGroundTruthNormals) {
  if (!aloe::available(aloe::kDefaultDirectory)) {
    GTEST_SKIP() << "Middlebury Aloe not installed (Debian package opencv-doc)";
  }
  const aloe::AloeData data = aloe::load();
  ASSERT_TRUE(data.found);
  EXPECT_EQ(data.left.width(), 641);
  EXPECT_EQ(data.left.height(), 555);
  EXPECT_EQ(data.right.width(), 641);
  EXPECT_EQ(data.normals_gt.width(), 641);
  std::size_t known = 0, with_normal = 0;
  float lo = 1e9f, hi = 0.0f;
  for (std::size_t i = 0; i < data.disparity_gt.pixelCount(); ++i) {
    const float d = data.disparity_gt.data()[i];
    if (!std::isfinite(d)) continue;
    ++known;
    lo = std::min(lo, d);
    hi = std::max(hi, d);
    const float* n = data.normals_gt.data();
    const std::size_t np = data.normals_gt.pixelCount();
    if (std::isfinite(n[i]) && std::isfinite(n[np + i])) ++with_normal;
  }
  // Whole pixels at full size, halved: the plant and its backdrop.
  EXPECT_GT(known, 0.85 * data.disparity_gt.pixelCount());
  EXPECT_GT(with_normal, 0.9 * known);
  EXPECT_GT(lo, 15.0f);
  EXPECT_LT(hi, 120.0f);
  // SGBM's disparity of the real pair agrees with the ground truth.
  stereo::SgbmSettings settings;
  settings.num_disparities = 128;
  const ScalarMap sgbm = stereo::sgbmDisparity(data.left, data.right, settings);
  std::vector<double> ratio;
  for (std::size_t i = 0; i < sgbm.pixelCount(); ++i) {
    const double a = sgbm.data()[i], g = data.disparity_gt.data()[i];
    if (std::isfinite(a) && std::isfinite(g)) ratio.push_back(a / g);
  }
  ASSERT_GT(ratio.size(), 100000u);
  std::sort(ratio.begin(), ratio.end());
  EXPECT_NEAR(ratio[ratio.size() / 2], 1.0, 0.01);
}

}  // namespace
}  // namespace normal_fusion
