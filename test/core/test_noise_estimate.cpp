// The per-input noise estimate across scales: white noise reads alike at
// every radius, noise shared by neighbouring pixels grows with the radius;
// the prepared data terms follow its gain only when it is on.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
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

/// A stream's warm frames use the gains estimated on an earlier frame for
/// up to NoiseGainMemory::kFrames frames, then estimate them again; a cold
/// frame always estimates them.
TEST(NoiseEstimate, WarmFramesUseTheKeptGainsForAFewFrames) {
  const int W = 80, H = 60;
  NormalMap gt;
  FusionProblem white = test::twoPlaneScene(W, H, &gt);
  white.inputs.resize(1);
  white.inputs[0].normals = noiseField(W, H, 1, 0.1, 6);
  FusionProblem shared = white;
  shared.inputs[0].normals = noiseField(W, H, 5, 0.1, 7);
  SolverSettings settings;
  settings.noise_radius = 8;
  settings.noise_plane_residual = false;
  const float white_gain =
      internal::estimateNoise(white.inputs[0].normals, 1, 8, 1).gain;
  const float shared_gain =
      internal::estimateNoise(shared.inputs[0].normals, 1, 8, 1).gain;
  ASSERT_GT(shared_gain, white_gain + 0.3f);
  const internal::PreparedLevel shared_alone =
      internal::prepareFinest(shared, settings);

  internal::PreparedLevel level;
  internal::EdgeWeightScratch scratch;
  internal::NoiseGainMemory memory;
  auto prepare = [&](const FusionProblem& problem, bool warm) {
    ASSERT_TRUE(internal::prepareFinestInto(problem, settings, level, scratch,
                                            1, nullptr, &memory, warm));
  };
  // A cold frame estimates and keeps the gain.
  prepare(white, false);
  ASSERT_EQ(memory.gains.size(), 1u);
  EXPECT_NEAR(memory.gains[0], white_gain, 1e-5f);
  // The warm frames after it use it: the shared noise's frame is prepared
  // as white noise, unlike the same frame alone.
  for (int frame = 0; frame < internal::NoiseGainMemory::kFrames; ++frame) {
    prepare(shared, true);
    EXPECT_NEAR(memory.gains[0], white_gain, 1e-5f) << "frame " << frame;
    EXPECT_GT(level.data_weight[0].at(0, 30, 40),
              1.2f * shared_alone.data_weight[0].at(0, 30, 40))
        << "frame " << frame;
  }
  // Then it is estimated again, and the frame is prepared as it is alone.
  prepare(shared, true);
  EXPECT_NEAR(memory.gains[0], shared_gain, 1e-5f);
  EXPECT_EQ(level.data_weight[0].at(0, 30, 40),
            shared_alone.data_weight[0].at(0, 30, 40));
  EXPECT_EQ(level.data_eps[0].at(0, 30, 40),
            shared_alone.data_eps[0].at(0, 30, 40));
  // A cold frame estimates at once.
  prepare(white, true);
  EXPECT_NEAR(memory.gains[0], shared_gain, 1e-5f);
  prepare(white, false);
  EXPECT_NEAR(memory.gains[0], white_gain, 1e-5f);
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

/// sigma_r of one window computed the long way, the oracle of
/// windowSpreadAt(): the valid pixels gathered; around the mean, the mean
/// squared distance from the normalized mean; around the plane, each
/// component's least-squares coefficients from the 3x3 normal equations
/// (Gaussian elimination) and the residuals summed one by one.
float referenceSpread(const PlanarImage& f, int r, int x0, int y0, bool plane) {
  std::vector<std::array<double, 5>> samples;  // u, v, f_x, f_y, f_z
  for (int y = std::max(0, y0 - r); y <= std::min(f.height() - 1, y0 + r);
       ++y) {
    for (int x = std::max(0, x0 - r); x <= std::min(f.width() - 1, x0 + r);
         ++x) {
      const double v[3] = {f.at(0, y, x), f.at(1, y, x), f.at(2, y, x)};
      if (v[0] * v[0] + v[1] * v[1] + v[2] * v[2] > 0.0) {
        samples.push_back({double(x - x0), double(y - y0), v[0], v[1], v[2]});
      }
    }
  }
  const double n = static_cast<double>(samples.size());
  if (!plane) {
    if (n < 2.0) return -1.0f;
    double m[3] = {0.0, 0.0, 0.0};
    for (const auto& s : samples) {
      for (int c = 0; c < 3; ++c) m[c] += s[2 + c];
    }
    const double len = std::sqrt(m[0] * m[0] + m[1] * m[1] + m[2] * m[2]);
    double s2 = 0.0;
    for (const auto& s : samples) {
      for (int c = 0; c < 3; ++c) {
        s2 += (s[2 + c] - m[c] / len) * (s[2 + c] - m[c] / len) / n;
      }
    }
    return static_cast<float>(std::sqrt(s2 / std::max(1.0 - 1.0 / n, 0.5)));
  }
  if (n < 4.0) return -1.0f;
  double rss = 0.0;
  for (int c = 0; c < 3; ++c) {
    // [A | b] of a + b u + c v, A = sum phi phi^T, phi = (1, u, v).
    double a[3][4] = {};
    for (const auto& s : samples) {
      const double phi[3] = {1.0, s[0], s[1]};
      for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) a[i][j] += phi[i] * phi[j];
        a[i][3] += phi[i] * s[2 + c];
      }
    }
    for (int i = 0; i < 3; ++i) {
      if (std::abs(a[i][i]) < 1e-9) return -1.0f;
      for (int k = i + 1; k < 3; ++k) {
        const double q = a[k][i] / a[i][i];
        for (int j = i; j < 4; ++j) a[k][j] -= q * a[i][j];
      }
    }
    double beta[3];
    for (int i = 2; i >= 0; --i) {
      double t = a[i][3];
      for (int j = i + 1; j < 3; ++j) t -= a[i][j] * beta[j];
      beta[i] = t / a[i][i];
    }
    for (const auto& s : samples) {
      const double e = s[2 + c] - beta[0] - beta[1] * s[0] - beta[2] * s[1];
      rss += e * e;
    }
  }
  return static_cast<float>(std::sqrt(rss / (n - 3.0)) /
                            std::pow(1.0 - 1.0 / (9.0 * (n - 3.0)), 1.5));
}

TEST(NoiseEstimate, PlaneResidualOfAPlaneIsZeroAndHolesAreRead) {
  // Noise-free tilted normals are their own plane: every spread 0 where
  // the plane is determined, even with a column of holes through it.
  PlanarImage f = noisyCylinder(40, 30, 80.0, 0.0, 7);
  for (int y = 0; y < 30; ++y) {
    for (int c = 0; c < 3; ++c) f.at(c, y, 20) = 0.0f;
  }
  for (int y : {0, 15, 29}) {
    for (int x : {0, 19, 21, 39}) {
      EXPECT_LT(internal::windowSpreadAt(f, 2, x, y, true), 2e-3f)
          << x << ", " << y;
    }
  }
  // A pixel whose window holds a single valid pixel reads no spread.
  PlanarImage lone(9, 9, 3);
  lone.at(2, 4, 4) = -1.0f;
  EXPECT_EQ(internal::windowSpreadAt(lone, 1, 4, 4, true), -1.0f);
  EXPECT_EQ(internal::windowSpreadAt(lone, 1, 4, 4, false), -1.0f);
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

TEST(NoiseEstimate, WindowAtOnePixelMatchesTheExplicitFit) {
  // With holes and at the borders, under both models.
  PlanarImage f = noiseField(50, 40, 3, 0.1, 9);
  for (int y = 0; y < 40; y += 3) {
    for (int c = 0; c < 3; ++c) f.at(c, y, (7 * y) % 50) = 0.0f;
  }
  for (int r : {1, 3}) {
    for (int y : {0, 1, 13, 38, 39}) {
      for (int x : {0, 2, 21, 48, 49}) {
        for (bool plane : {false, true}) {
          EXPECT_NEAR(internal::windowSpreadAt(f, r, x, y, plane),
                      referenceSpread(f, r, x, y, plane), 2e-4f)
              << r << ": " << x << ", " << y << (plane ? " plane" : " mean");
        }
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
    std::vector<float> all;
    all.reserve(f.pixelCount());
    for (int y = 0; y < 480; ++y) {
      for (int x = 0; x < 640; ++x) {
        all.push_back(internal::windowSpreadAt(f, e.radius[k], x, y, true));
      }
    }
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
