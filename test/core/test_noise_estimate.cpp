// The per-input noise estimate across scales: white noise reads alike at
// every radius, noise shared by neighbouring pixels grows with the radius;
// the prepared data terms follow its gain only when it is on.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "normal_fusion/detail/noise_estimate.h"
#include "normal_fusion/detail/solver_internal.h"
#include "test_util.h"

namespace normal_fusion {
namespace {

/// Unit normals around (0, 0, -1) tilted by a noise field of RMS `sigma`
/// per tangent axis: independent per pixel (k = 1) or the mean over a
/// k x k box of independent values (shared by neighbours over k pixels),
/// rescaled to the same RMS.
PlanarImage noiseField(int W, int H, int k, double sigma, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> gauss(0.0, 1.0);
  std::vector<double> white[2];
  for (auto& plane : white) {
    plane.resize(static_cast<std::size_t>(W + k) * (H + k));
    for (double& v : plane) v = gauss(rng);
  }
  PlanarImage f(W, H, 3);
  const double scale = sigma * k;  // the box mean of k^2 values: RMS 1 / k
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      double t[2] = {0.0, 0.0};
      for (int a = 0; a < 2; ++a) {
        for (int v = 0; v < k; ++v) {
          for (int u = 0; u < k; ++u) {
            t[a] += white[a][static_cast<std::size_t>(y + v) * (W + k) + x + u];
          }
        }
        t[a] *= scale / (k * k);
      }
      const double len = std::sqrt(t[0] * t[0] + t[1] * t[1] + 1.0);
      f.at(0, y, x) = static_cast<float>(t[0] / len);
      f.at(1, y, x) = static_cast<float>(t[1] / len);
      f.at(2, y, x) = static_cast<float>(-1.0 / len);
    }
  }
  return f;
}

TEST(NoiseEstimate, WhiteNoiseReadsAlikeAtEveryScale) {
  const PlanarImage f = noiseField(120, 90, 1, 0.1, 1);
  const internal::NoiseEstimate e = internal::estimateNoise(f, 1, 8, 1);
  ASSERT_EQ(e.scales, 4);
  EXPECT_EQ(e.radius[0], 1);
  EXPECT_EQ(e.radius[3], 8);
  // RMS tilt 0.1 per axis: |f - mean| about 0.1 sqrt(2) at every radius.
  for (int k = 0; k < e.scales; ++k) {
    EXPECT_NEAR(e.sigma[k], 0.1f * std::sqrt(2.0f), 0.006f) << "scale " << k;
  }
  EXPECT_LT(e.gain, 1.1f);
}

TEST(NoiseEstimate, SharedNoiseGrowsWithTheRadius) {
  // Shared over 5 pixels: a 3x3 window sees a small part of it.
  const PlanarImage f = noiseField(120, 90, 5, 0.1, 2);
  const internal::NoiseEstimate e = internal::estimateNoise(f, 1, 8, 1);
  ASSERT_EQ(e.scales, 4);
  for (int k = 1; k < e.scales; ++k) EXPECT_GT(e.sigma[k], e.sigma[k - 1]);
  EXPECT_GT(e.gain, 1.4f);
  // At most the side ratio of the widest and the base window.
  EXPECT_LE(e.gain, 17.0f / 3.0f);
  // The widest window reads nearly all of it.
  EXPECT_GT(e.sigma[3], 0.1f);
  // A wider correlation hides more from the base window.
  const internal::NoiseEstimate wider =
      internal::estimateNoise(noiseField(120, 90, 9, 0.1, 2), 1, 8, 1);
  EXPECT_GT(wider.gain, e.gain);
}

TEST(NoiseEstimate, CleanAndEmptyInputsKeepGainOne) {
  PlanarImage clean = noiseField(40, 30, 1, 0.0, 3);
  EXPECT_EQ(internal::estimateNoise(clean, 1, 8, 1).gain, 1.0f);
  PlanarImage empty(40, 30, 3);
  const internal::NoiseEstimate none = internal::estimateNoise(empty, 1, 8, 1);
  EXPECT_EQ(none.scales, 0);
  EXPECT_EQ(none.gain, 1.0f);
}

TEST(NoiseEstimate, ThresholdAndWeightFollowTheGainOnlyWhenOn) {
  const int W = 80, H = 60;
  NormalMap gt;
  FusionProblem problem = test::twoPlaneScene(W, H, &gt);
  NormalInput shared;
  shared.normals = noiseField(W, H, 5, 0.1, 4);
  problem.inputs = {shared};
  SolverSettings settings;
  settings.noise_radius = 0;
  settings.noise_plane_residual = false;
  const internal::PreparedLevel off =
      internal::prepareFinest(problem, settings);
  settings.noise_radius = 8;
  settings.noise_weight_power = 1.0;
  const internal::PreparedLevel on = internal::prepareFinest(problem, settings);
  const float gain = internal::estimateNoise(off.data[0], 1, 8, 1).gain;
  ASSERT_GT(gain, 1.4f);
  for (int y : {10, 30, 50}) {
    for (int x : {10, 40, 70}) {
      EXPECT_NEAR(on.data_eps[0].at(0, y, x),
                  std::min(2.0f, gain * off.data_eps[0].at(0, y, x)), 1e-5f);
      EXPECT_NEAR(on.data_weight[0].at(0, y, x),
                  off.data_weight[0].at(0, y, x) / gain, 1e-6f);
    }
  }
  // White noise: nearly untouched.
  problem.inputs[0].normals = noiseField(W, H, 1, 0.1, 5);
  const internal::PreparedLevel white =
      internal::prepareFinest(problem, settings);
  EXPECT_GT(white.data_weight[0].at(0, 30, 40), 0.5f / 1.1f);
}

/// A cylinder of radius `radius` pixels with its axis along y (normals
/// turning with x, facing -z at the centre column), tilted by white noise of
/// RMS `sigma` per tangent axis.
PlanarImage noisyCylinder(int W, int H, double radius, double sigma,
                          unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> gauss(0.0, sigma);
  PlanarImage f(W, H, 3);
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const double s = (x - 0.5 * (W - 1)) / radius;
      const double n[3] = {s, 0.0, -std::sqrt(1.0 - s * s)};
      // Tangent axes: along the turn and along the axis.
      const double t1[3] = {-n[2], 0.0, n[0]};
      const double a = gauss(rng), b = gauss(rng);
      const double v[3] = {n[0] + a * t1[0], b, n[2] + a * t1[2]};
      const double len = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
      for (int c = 0; c < 3; ++c) {
        f.at(c, y, x) = static_cast<float>(v[c] / len);
      }
    }
  }
  return f;
}

TEST(NoiseEstimate, PlaneResidualDoesNotReadABendAsNoise) {
  // A 17 x 17 window spans 17 / 80 rad of the turn, about twice the noise's
  // spread about the window mean; about a plane the turn is gone.
  const PlanarImage f = noisyCylinder(120, 90, 80.0, 0.02, 6);
  const internal::NoiseEstimate mean = internal::estimateNoise(f, 1, 8, 1);
  const internal::NoiseEstimate plane =
      internal::estimateNoise(f, 1, 8, 1, true);
  EXPECT_GT(mean.gain, 1.5f);
  EXPECT_LT(plane.gain, 1.1f);
  // The base window reads the noise itself under both models.
  EXPECT_NEAR(plane.sigma[0], 0.02f * std::sqrt(2.0f), 0.003f);
  EXPECT_NEAR(mean.sigma[0], 0.02f * std::sqrt(2.0f), 0.003f);
}

TEST(NoiseEstimate, PlaneResidualKeepsWhiteAndSharedNoise) {
  const internal::NoiseEstimate white =
      internal::estimateNoise(noiseField(120, 90, 1, 0.1, 1), 1, 8, 1, true);
  ASSERT_EQ(white.scales, 4);
  for (int k = 0; k < white.scales; ++k) {
    EXPECT_NEAR(white.sigma[k], 0.1f * std::sqrt(2.0f), 0.006f)
        << "scale " << k;
  }
  EXPECT_LT(white.gain, 1.1f);
  const internal::NoiseEstimate shared =
      internal::estimateNoise(noiseField(120, 90, 5, 0.1, 2), 1, 8, 1, true);
  EXPECT_GT(shared.gain, 1.4f);
  EXPECT_LE(shared.gain, 17.0f / 3.0f);
}

TEST(NoiseEstimate, PlaneResidualOfAPlaneIsZeroAndHolesAreRead) {
  // Noise-free tilted normals are their own plane: every spread 0 where
  // the plane is determined, even with a column of holes through it.
  PlanarImage f = noisyCylinder(40, 30, 80.0, 0.0, 7);
  for (int y = 0; y < 30; ++y) {
    for (int c = 0; c < 3; ++c) f.at(c, y, 20) = 0.0f;
  }
  std::vector<float> spread(f.pixelCount());
  internal::planeResidualSpreadInto(f, 2, spread.data(), 1);
  for (int y : {0, 15, 29}) {
    for (int x : {0, 19, 21, 39}) {
      EXPECT_LT(spread[y * 40 + x], 2e-3f) << x << ", " << y;
    }
  }
  // A pixel whose window holds a single valid pixel reads no spread.
  PlanarImage lone(9, 9, 3);
  lone.at(2, 4, 4) = -1.0f;
  std::vector<float> lone_spread(lone.pixelCount());
  internal::planeResidualSpreadInto(lone, 1, lone_spread.data(), 1);
  EXPECT_EQ(lone_spread[4 * 9 + 4], -1.0f);
}

TEST(NoiseEstimate, SettingSelectsThePlaneResidual) {
  const int W = 120, H = 90;
  NormalMap gt;
  FusionProblem problem = test::twoPlaneScene(W, H, &gt);
  NormalInput cylinder;
  cylinder.normals = noisyCylinder(W, H, 80.0, 0.02, 8);
  problem.inputs = {cylinder};
  SolverSettings settings;
  settings.noise_radius = 8;
  settings.noise_weight_power = 1.0;
  settings.noise_plane_residual = false;
  const internal::PreparedLevel mean =
      internal::prepareFinest(problem, settings);
  settings.noise_plane_residual = true;
  const internal::PreparedLevel plane =
      internal::prepareFinest(problem, settings);
  // The mean model divides the weight by its gain (> 1.5), the plane model
  // by about 1.
  EXPECT_LT(mean.data_weight[0].at(0, 45, 60),
            plane.data_weight[0].at(0, 45, 60) / 1.4f);
  EXPECT_GT(plane.data_weight[0].at(0, 45, 60), 0.5f / 1.1f);
}

TEST(NoiseEstimate, WindowAtOnePixelMatchesTheRowKernels) {
  // With holes and at the borders, under both models.
  PlanarImage f = noiseField(50, 40, 3, 0.1, 9);
  for (int y = 0; y < 40; y += 3) {
    for (int c = 0; c < 3; ++c) f.at(c, y, (7 * y) % 50) = 0.0f;
  }
  for (int r : {1, 3}) {
    std::vector<float> mean(f.pixelCount()), plane(f.pixelCount());
    internal::whiteNoiseSpreadInto(f, r, mean.data(), 1);
    internal::planeResidualSpreadInto(f, r, plane.data(), 1);
    for (int y : {0, 1, 13, 38, 39}) {
      for (int x : {0, 2, 21, 48, 49}) {
        const std::size_t i = static_cast<std::size_t>(y) * 50 + x;
        EXPECT_NEAR(internal::windowSpreadAt(f, r, x, y, false), mean[i], 2e-4f)
            << r << ": " << x << ", " << y;
        EXPECT_NEAR(internal::windowSpreadAt(f, r, x, y, true), plane[i], 2e-4f)
            << r << ": " << x << ", " << y;
      }
    }
  }
}

TEST(NoiseEstimate, GridOfCentresReadsTheMedianOfEveryPixel) {
  // 640 x 480 is read at about kNoiseSamples centres.
  const PlanarImage f = noiseField(640, 480, 3, 0.1, 10);
  const int stride = internal::noiseSampleStride(640, 480);
  EXPECT_GE(stride, 8);
  EXPECT_EQ(internal::noiseSampleStride(120, 90), 3);
  EXPECT_EQ(internal::noiseSampleStride(40, 30), 1);
  const internal::NoiseEstimate e = internal::estimateNoise(f, 1, 4, 1, true);
  ASSERT_EQ(e.scales, 3);
  for (int k = 0; k < e.scales; ++k) {
    std::vector<float> all(f.pixelCount());
    internal::planeResidualSpreadInto(f, e.radius[k], all.data(), 1);
    std::nth_element(all.begin(), all.begin() + all.size() / 2, all.end());
    EXPECT_NEAR(e.sigma[k], all[all.size() / 2], 0.02f * all[all.size() / 2])
        << "radius " << e.radius[k];
  }
}

TEST(NoiseEstimate, SparseInputKeepsTheMeanModel) {
  // 5 % of the pixels: few 3x3 windows determine a plane.
  PlanarImage f = noiseField(160, 120, 1, 0.1, 11);
  std::mt19937 rng(12);
  std::uniform_real_distribution<double> keep(0.0, 1.0);
  for (int y = 0; y < 120; ++y) {
    for (int x = 0; x < 160; ++x) {
      if (keep(rng) < 0.05) continue;
      for (int c = 0; c < 3; ++c) f.at(c, y, x) = 0.0f;
    }
  }
  const internal::NoiseEstimate mean = internal::estimateNoise(f, 1, 4, 1);
  const internal::NoiseEstimate plane =
      internal::estimateNoise(f, 1, 4, 1, true);
  ASSERT_EQ(plane.scales, mean.scales);
  for (int k = 0; k < mean.scales; ++k) {
    EXPECT_EQ(plane.sigma[k], mean.sigma[k]) << "scale " << k;
  }
  EXPECT_EQ(plane.gain, mean.gain);
}

}  // namespace
}  // namespace normal_fusion
