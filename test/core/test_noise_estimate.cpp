// The per-input noise estimate across scales: white noise reads alike at
// every radius, noise shared by neighbouring pixels grows with the radius;
// the prepared data terms follow its gain only when it is on.
#include <gtest/gtest.h>

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

}  // namespace
}  // namespace normal_fusion
