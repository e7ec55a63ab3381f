// The prepared finest level: local statistics (data thresholds, density
// correction), the conversion of every kind of input value, the warm start's
// sanitizing, and the links inside holes.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include "normal_fusion/detail/solver_internal.h"
#include "test_util.h"

namespace normal_fusion {
namespace {

/// The local statistics of the prepared inputs: delta = data_eps_local * the
/// RMS spread in the 3x3 window (0 on a clean plane, large on noise), and the
/// density correction (window / valid) on a sparse input only.
TEST(LocalStatistics, ThresholdsFollowTheSpreadAndSparseSamplesCountMore) {
  const int W = 40, H = 30;
  NormalMap gt;
  FusionProblem problem = test::twoPlaneScene(W, H, &gt);
  // Dense input: exact on the left half, very noisy on the right half.
  NormalInput dense;
  dense.normals = gt;
  const NormalMap noisy = test::noisy(gt, 0.8, 5);
  for (int y = 0; y < H; ++y) {
    for (int x = W / 2; x < W; ++x) {
      for (int c = 0; c < 3; ++c) {
        dense.normals.at(c, y, x) = noisy.at(c, y, x);
      }
    }
  }
  // Sparse input: one isolated sample at (5, 5) and a 3x3 block at 30..32.
  NormalInput sparse;
  sparse.normals.resize(W, H, 3);
  sparse.normals.fill(std::numeric_limits<float>::quiet_NaN());
  for (int c = 0; c < 3; ++c) sparse.normals.at(c, 5, 5) = gt.at(c, 5, 5);
  for (int y = 10; y < 13; ++y) {
    for (int x = 30; x < 33; ++x) {
      for (int c = 0; c < 3; ++c) sparse.normals.at(c, y, x) = gt.at(c, y, x);
    }
  }
  problem.inputs = {dense, sparse};
  SolverSettings settings;
  settings.lambda = 0.5;
  settings.data_eps = 0.0;
  settings.data_eps_local = 1.0;
  settings.density_power = 1.0;
  settings.local_radius = 1;
  settings.noise_radius = 0;  // the 3x3 statistics alone
  const internal::PreparedLevel level =
      internal::prepareFinest(problem, settings);
  ASSERT_TRUE(level.data_huber);
  const PlanarImage& delta_dense = level.data_eps[0];
  // Clean plane (away from the crease of the two planes): delta ~ 0.
  EXPECT_LT(delta_dense.at(0, 15, 3), 1e-3f);
  // Heavy noise: the spread of sigma 0.8 noise is far above 0.3.
  float mean_noisy = 0.0f;
  for (int x = W / 2 + 2; x < W - 2; ++x)
    mean_noisy += delta_dense.at(0, 15, x);
  EXPECT_GT(mean_noisy / (W / 2 - 4), 0.3f);
  // Dense weights keep lambda in the interior (window fully valid).
  EXPECT_NEAR(level.data_weight[0].at(0, 15, 10), 0.5f, 1e-6f);
  // The isolated sample: 9 window pixels, 1 valid: weight 9 lambda, delta 0.
  EXPECT_NEAR(level.data_weight[1].at(0, 5, 5), 4.5f, 1e-5f);
  EXPECT_EQ(level.data_eps[1].at(0, 5, 5), 0.0f);
  // The block's centre sees 9 of 9: lambda; its corner 4 of 9: 9/4 lambda.
  EXPECT_NEAR(level.data_weight[1].at(0, 11, 31), 0.5f, 1e-6f);
  EXPECT_NEAR(level.data_weight[1].at(0, 10, 30), 0.5f * 9.0f / 4.0f, 1e-5f);
  // Missing pixels keep weight 0.
  EXPECT_EQ(level.data_weight[1].at(0, 20, 20), 0.0f);

  // Off: no thresholds, no correction.
  settings.data_eps_local = 0.0;
  settings.density_power = 0.0;
  const internal::PreparedLevel plain =
      internal::prepareFinest(problem, settings);
  EXPECT_FALSE(plain.data_huber);
  EXPECT_NEAR(plain.data_weight[1].at(0, 5, 5), 0.5f, 1e-6f);
  // The squared penalty has no threshold.
  settings.data_eps_local = 1.0;
  settings.penalty = DataPenalty::kSquaredL2;
  EXPECT_FALSE(internal::prepareFinest(problem, settings).data_huber);
}

/// The conversion of an input (orientation, validity, confidence, hard
/// visibility) against a per-pixel oracle, on every kind of bad value: NaN,
/// infinite, zero, tiny and huge normals; NaN, infinite, negative and > 1
/// confidences.
TEST(PreparedData, ConversionOfEveryKindOfValue) {
  const int W = 16, H = 4;
  const float inf = std::numeric_limits<float>::infinity();
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const float normals[][3] = {{0.2f, -0.3f, -0.9f}, {nan, 0.0f, -1.0f},
                              {inf, 0.0f, -1.0f},   {0.0f, 0.0f, 0.0f},
                              {1e-7f, 0.0f, 0.0f},  {3e15f, 0.0f, -3e15f},
                              {0.0f, 0.0f, 2.0f},   {0.5f, 0.5f, -0.1f}};
  const float confidences[] = {1.0f, 0.5f, 0.0f, -0.2f, 1.7f, nan, inf, 0.25f};
  FusionProblem problem;
  problem.image = ColorImage(W, H, 1, 0.5f);
  problem.K = CameraIntrinsics(20.0, 20.0, (W - 1) / 2.0, (H - 1) / 2.0);
  NormalInput input;
  input.normals = NormalMap(W, H, 3);
  input.confidence = ScalarMap(W, H, 1);
  input.weight = 2.0;
  input.orientation = Orientation::opengl();
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const float* n = normals[(x + 3 * y) % 8];
      for (int c = 0; c < 3; ++c) input.normals.at(c, y, x) = n[c];
      input.confidence.at(0, y, x) = confidences[(2 * x + y) % 8];
    }
  }
  problem.inputs = {input};
  for (const bool relative : {false, true}) {
    for (VisibilityMode mode : {VisibilityMode::kSoft, VisibilityMode::kHard}) {
      SolverSettings settings;
      settings.lambda = 0.5;
      settings.visibility = mode;
      settings.data_eps_local = 0.0;
      settings.density_power = 0.0;
      settings.confidence_relative = relative;
      const internal::PreparedLevel level =
          internal::prepareFinest(problem, settings);
      std::vector<double> expected_c(static_cast<std::size_t>(W) * H, 0.0);
      std::vector<double> expected_f(3 * expected_c.size(), 0.0);
      double sum_c = 0.0;
      int valid = 0;
      for (int y = 0; y < H; ++y) {
        for (int x = 0; x < W; ++x) {
          // Oracle: usable = finite and not (nearly) zero; f = M n / |M n|;
          // c = lambda * weight * clamp(confidence, 0, 1), a non-finite
          // confidence counting 0; in hard mode 0 where f faces away (r . f >
          // 0); f = 0 wherever c = 0.
          const float* n = normals[(x + 3 * y) % 8];
          const double s =
              double(n[0]) * n[0] + double(n[1]) * n[1] + double(n[2]) * n[2];
          const bool usable = std::isfinite(s) && s > 1e-12 && s < 1e30;
          float conf = confidences[(2 * x + y) % 8];
          conf =
              std::isfinite(conf) ? std::min(std::max(conf, 0.0f), 1.0f) : 0.0f;
          double f[3] = {0.0, 0.0, 0.0};
          double c = 0.0;
          if (usable) {
            const auto& M = input.orientation.M;
            double len = 0.0;
            for (int r = 0; r < 3; ++r) {
              f[r] = double(M[3 * r]) * n[0] + double(M[3 * r + 1]) * n[1] +
                     double(M[3 * r + 2]) * n[2];
              len += f[r] * f[r];
            }
            for (double& v : f) v /= std::sqrt(len);
            c = 0.5 * 2.0 * conf;
            if (mode == VisibilityMode::kHard) {
              const double ray[3] = {(x - (W - 1) / 2.0) / 20.0,
                                     (y - (H - 1) / 2.0) / 20.0, 1.0};
              if (ray[0] * f[0] + ray[1] * f[1] + ray[2] * f[2] > 0.0) c = 0.0;
            }
          }
          if (!(c > 0.0)) f[0] = f[1] = f[2] = c = 0.0;
          valid += c > 0.0 ? 1 : 0;
          sum_c += c;
          const std::size_t i = static_cast<std::size_t>(y) * W + x;
          expected_c[i] = c;
          for (int k = 0; k < 3; ++k) expected_f[3 * i + k] = f[k];
        }
      }
      // Relative: c times lambda * weight / (the mean of c where c > 0).
      const double scale = relative ? 0.5 * 2.0 * valid / sum_c : 1.0;
      for (int y = 0; y < H; ++y) {
        for (int x = 0; x < W; ++x) {
          const std::size_t i = static_cast<std::size_t>(y) * W + x;
          EXPECT_NEAR(level.data_weight[0].at(0, y, x), scale * expected_c[i],
                      1e-6)
              << x << "," << y << (relative ? " relative" : "");
          for (int k = 0; k < 3; ++k) {
            EXPECT_NEAR(level.data[0].at(k, y, x), expected_f[3 * i + k], 1e-6)
                << x << "," << y << " component " << k;
          }
        }
      }
      EXPECT_EQ(level.valid_pixels, valid);
      EXPECT_GT(valid, 0);
      EXPECT_LT(valid, W * H);
      // The confidences are not all equal, so relative changes the weights.
      if (relative) {
        EXPECT_GT(std::abs(scale - 1.0), 0.1);
      }
    }
  }
}

/// The warm start's sanitizing against a per-pixel oracle (normalize, then
/// projectVisible() in soft mode; unusable normals flagged and replaced by a
/// unit cold-start normal).
TEST(WarmStart, SanitizingOfEveryKindOfValue) {
  const int W = 37, H = 5;
  const float inf = std::numeric_limits<float>::infinity();
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const float normals[][3] = {
      {0.2f, -0.3f, -0.9f}, {nan, 0.0f, -1.0f},   {inf, 0.0f, -1.0f},
      {0.0f, 0.0f, 0.0f},   {1e-7f, 0.0f, 0.0f},  {0.0f, 0.0f, 2.0f},
      {0.3f, 0.1f, 0.4f},   {-3.0f, 1.0f, -0.5f}, {0.05f, 0.0f, 1.0f}};
  FusionProblem problem;
  problem.image = ColorImage(W, H, 1, 0.5f);
  problem.K = CameraIntrinsics(10.0, 10.0, (W - 1) / 2.0, (H - 1) / 2.0);
  NormalInput input;
  input.normals = NormalMap(W, H, 3);
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) input.normals.at(2, y, x) = -1.0f;
  }
  problem.inputs = {input};
  for (VisibilityMode mode : {VisibilityMode::kSoft, VisibilityMode::kHard}) {
    SolverSettings settings;
    settings.visibility = mode;
    const internal::PreparedLevel level =
        internal::prepareFinest(problem, settings);
    NormalMap warm(W, H, 3);
    for (int y = 0; y < H; ++y) {
      for (int x = 0; x < W; ++x) {
        for (int c = 0; c < 3; ++c) {
          warm.at(c, y, x) = normals[(x + 2 * y) % 9][c];
        }
      }
    }
    std::vector<unsigned char> unknown;
    NormalMap sanitized = warm;
    internal::sanitizeWarmStart(level, mode, sanitized, unknown, 2);
    for (int y = 0; y < H; ++y) {
      for (int x = 0; x < W; ++x) {
        const float* n = normals[(x + 2 * y) % 9];
        const double s =
            double(n[0]) * n[0] + double(n[1]) * n[1] + double(n[2]) * n[2];
        const bool usable = std::isfinite(s) && s > 1e-12;
        const std::size_t i = static_cast<std::size_t>(y) * W + x;
        ASSERT_EQ(unknown[i], usable ? 0 : 1) << x << "," << y;
        float v[3];
        double len2 = 0.0;
        for (int c = 0; c < 3; ++c) {
          v[c] = sanitized.at(c, y, x);
          len2 += double(v[c]) * v[c];
        }
        EXPECT_NEAR(len2, 1.0, 1e-5) << x << "," << y;
        if (!usable) continue;
        float e[3];
        const float len = static_cast<float>(std::sqrt(s));
        for (int c = 0; c < 3; ++c) e[c] = n[c] / len;
        if (mode == VisibilityMode::kSoft) {
          float r[3];
          level.ray(x, y, r);
          internal::projectVisible(r, e);
        }
        for (int c = 0; c < 3; ++c) {
          EXPECT_NEAR(v[c], e[c], 2e-6f) << x << "," << y << " component " << c;
        }
      }
    }
  }
}

/// Links between two unobserved pixels are weakened by hole_link_weight; links
/// with an observed end are not.
TEST(HoleLinks, OnlyLinksInsideAHoleAreWeakened) {
  const int W = 24, H = 16;
  NormalMap gt;
  FusionProblem problem = test::twoPlaneScene(W, H, &gt);
  NormalInput input;
  input.normals = gt;
  // A hole of columns 5..8, rows 4..7.
  for (int y = 4; y <= 7; ++y) {
    for (int x = 5; x <= 8; ++x) {
      for (int c = 0; c < 3; ++c) {
        input.normals.at(c, y, x) = std::numeric_limits<float>::quiet_NaN();
      }
    }
  }
  problem.inputs = {input};
  SolverSettings settings;
  settings.hole_link_weight = 1.0;
  const internal::PreparedLevel plain =
      internal::prepareFinest(problem, settings);
  settings.hole_link_weight = 0.25;
  const internal::PreparedLevel weak =
      internal::prepareFinest(problem, settings);
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const bool in = x >= 5 && x <= 8 && y >= 4 && y <= 7;
      const bool right_in = x + 1 >= 5 && x + 1 <= 8 && y >= 4 && y <= 7;
      const bool below_in = x >= 5 && x <= 8 && y + 1 >= 4 && y + 1 <= 7;
      EXPECT_FLOAT_EQ(
          weak.edge_weight.at(0, y, x),
          plain.edge_weight.at(0, y, x) * (in && right_in ? 0.25f : 1.0f))
          << x << "," << y;
      EXPECT_FLOAT_EQ(
          weak.edge_weight.at(1, y, x),
          plain.edge_weight.at(1, y, x) * (in && below_in ? 0.25f : 1.0f))
          << x << "," << y;
    }
  }
}

/// confidence_relative: a confidence of 0.1 and 0.3 in two halves becomes
/// 0.5 and 1.5 (mean 1 over the observed pixels), so the input keeps its
/// level and the halves their ratio; a pixel of confidence 0 stays out; as
/// it is, the confidence scales the weight.
TEST(PreparedData, RelativeConfidenceRanksAndKeepsTheLevel) {
  const int W = 20, H = 10;
  NormalMap gt;
  FusionProblem problem = test::twoPlaneScene(W, H, &gt);
  NormalInput input;
  input.normals = gt;
  input.weight = 2.0;
  input.confidence.resize(W, H, 1);
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      input.confidence.at(0, y, x) = x < W / 2 ? 0.1f : 0.3f;
    }
  }
  input.confidence.at(0, 3, 3) = 0.0f;
  // The mean over the other pixels stays 0.2: one pixel of each half out.
  input.confidence.at(0, 3, W - 3) = 0.0f;
  problem.inputs = {input};
  SolverSettings settings;
  settings.lambda = 0.5;
  settings.data_eps_local = 0.0;
  settings.density_power = 0.0;
  settings.noise_radius = 0;
  settings.confidence_relative = false;
  const internal::PreparedLevel as_is =
      internal::prepareFinest(problem, settings);
  EXPECT_NEAR(as_is.data_weight[0].at(0, 5, 2), 0.1f, 1e-6f);
  EXPECT_NEAR(as_is.data_weight[0].at(0, 5, W - 2), 0.3f, 1e-6f);
  settings.confidence_relative = true;
  const internal::PreparedLevel relative =
      internal::prepareFinest(problem, settings);
  EXPECT_NEAR(relative.data_weight[0].at(0, 5, 2), 0.5f, 1e-5f);
  EXPECT_NEAR(relative.data_weight[0].at(0, 5, W - 2), 1.5f, 1e-5f);
  EXPECT_EQ(relative.data_weight[0].at(0, 3, 3), 0.0f);
  EXPECT_EQ(relative.data_weight[0].at(0, 3, W - 3), 0.0f);
  // Without a confidence the setting changes nothing.
  problem.inputs[0].confidence = ScalarMap();
  const internal::PreparedLevel none =
      internal::prepareFinest(problem, settings);
  EXPECT_NEAR(none.data_weight[0].at(0, 5, 2), 1.0f, 1e-6f);
}

}  // namespace
}  // namespace normal_fusion
