// The maths of one iteration: adjointness, proximal steps against their closed
// forms, the tangent-plane projection, and the fast backend against the
// reference.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <initializer_list>
#include <limits>
#include <utility>
#include <vector>

#include "normal_fusion/detail/solver_internal.h"
#include "test_util.h"

namespace normal_fusion {
namespace {

using internal::reference::clampVector;
using internal::reference::divergence;
using internal::reference::gradient;

double dot(const PlanarImage& a, const PlanarImage& b) {
  double sum = 0.0;
  for (std::size_t i = 0; i < a.pixelCount() * a.channels(); ++i) {
    sum += static_cast<double>(a.data()[i]) * b.data()[i];
  }
  return sum;
}

TEST(Kernels, DivergenceIsTheNegativeAdjointOfGradient) {
  for (const auto& size : {std::make_pair(17, 11), std::make_pair(1, 9),
                           std::make_pair(8, 1), std::make_pair(64, 48)}) {
    const int W = size.first, H = size.second;
    const PlanarImage n = test::randomImage(W, H, 3, 1);
    const PlanarImage p_h = test::randomImage(W, H, 3, 2);
    const PlanarImage p_v = test::randomImage(W, H, 3, 3);
    PlanarImage g_h(W, H, 3), g_v(W, H, 3), div(W, H, 3);
    gradient(n, g_h, g_v);
    divergence(p_h, p_v, div);
    // <grad n, p> = -<n, div p>, with p(W-1) and p(H-1) read as 0.
    PlanarImage p_h_masked = p_h, p_v_masked = p_v;
    for (int c = 0; c < 3; ++c) {
      for (int y = 0; y < H; ++y) {
        p_h_masked.at(c, y, W - 1) = 0.0f;
      }
      for (int x = 0; x < W; ++x) p_v_masked.at(c, H - 1, x) = 0.0f;
    }
    const double lhs = dot(g_h, p_h) + dot(g_v, p_v);
    const double rhs = -dot(n, div);
    EXPECT_NEAR(lhs, rhs, 1e-4 * (std::abs(lhs) + 1.0)) << W << "x" << H;
    // The last column/row of p never enters either side.
    const double lhs_masked = dot(g_h, p_h_masked) + dot(g_v, p_v_masked);
    EXPECT_NEAR(lhs, lhs_masked, 1e-6 * (std::abs(lhs) + 1.0));
  }
}

TEST(Kernels, GradientOfConstantIsZeroAndDetectsRamp) {
  PlanarImage n(5, 4, 3, 0.5f);
  PlanarImage g_h(5, 4, 3), g_v(5, 4, 3);
  gradient(n, g_h, g_v);
  for (std::size_t i = 0; i < g_h.pixelCount() * 3; ++i) {
    EXPECT_EQ(g_h.data()[i], 0.0f);
    EXPECT_EQ(g_v.data()[i], 0.0f);
  }
  for (int x = 0; x < 5; ++x) n.at(0, 2, x) = static_cast<float>(x);
  gradient(n, g_h, g_v);
  EXPECT_FLOAT_EQ(g_h.at(0, 2, 1), 1.0f);
  EXPECT_FLOAT_EQ(g_h.at(0, 2, 4), 0.0f);  // Neumann end
}

TEST(Kernels, ClampIsTheProjectionOntoTheBall) {
  float v[3] = {3.0f, 4.0f, 0.0f};
  clampVector(v, 1.0f);
  EXPECT_NEAR(v[0], 0.6f, 1e-6);
  EXPECT_NEAR(v[1], 0.8f, 1e-6);
  float inside[3] = {0.1f, 0.2f, 0.2f};
  clampVector(inside, 1.0f);
  EXPECT_FLOAT_EQ(inside[1], 0.2f);
  float zero_radius[3] = {1.0f, 2.0f, 3.0f};
  clampVector(zero_radius, 0.0f);
  EXPECT_EQ(zero_radius[0], 0.0f);
  EXPECT_EQ(zero_radius[2], 0.0f);
}

/// prox of sigma (w huber_eps)^* at v is argmin_p |p - v|^2 / (2 sigma) +
/// eps / (2w) |p|^2 over |p| <= w; compare with a brute-force minimization
/// along the ray of v (the minimizer is a multiple of v).
TEST(Kernels, HuberDualProxMatchesItsDefinition) {
  const float sigma = 0.3f, eps = 0.05f;
  for (float w : {0.01f, 0.5f, 1.0f}) {
    for (float len : {0.001f, 0.2f, 0.9f, 3.0f}) {
      PlanarImage p(1, 1, 3, 0.0f), grad(1, 1, 3, 0.0f);
      const float dir[3] = {0.48f, -0.6f, 0.64f};
      for (int c = 0; c < 3; ++c) grad.plane(c)[0] = dir[c] * len / sigma;
      internal::reference::proxHuberDual(p, grad, &w, sigma, eps);
      // Brute force: p = t dir, t in [0, w].
      double best_t = 0.0, best = 1e300;
      for (int k = 0; k <= 200000; ++k) {
        const double t = w * k / 200000.0;
        const double obj =
            (t - len) * (t - len) / (2.0 * sigma) + eps / (2.0 * w) * t * t;
        if (obj < best) {
          best = obj;
          best_t = t;
        }
      }
      for (int c = 0; c < 3; ++c) {
        EXPECT_NEAR(p.plane(c)[0], best_t * dir[c], 1e-4)
            << "w=" << w << " len=" << len;
      }
    }
  }
}

TEST(Kernels, DataDualProxMatchesClosedForms) {
  const float sigma = 0.25f;
  for (DataPenalty penalty : {DataPenalty::kL2, DataPenalty::kSquaredL2}) {
    for (float c_w : {0.0f, 0.3f, 2.0f}) {
      PlanarImage q(1, 1, 3), nbar(1, 1, 3), f(1, 1, 3);
      const float q0[3] = {0.2f, -0.1f, 0.4f}, nb[3] = {0.0f, 0.6f, -0.8f},
                  f0[3] = {0.6f, 0.0f, -0.8f};
      for (int c = 0; c < 3; ++c) {
        q.plane(c)[0] = q0[c];
        nbar.plane(c)[0] = nb[c];
        f.plane(c)[0] = f0[c];
      }
      internal::reference::proxDataDual(q, nbar, f, &c_w, nullptr, sigma,
                                        penalty);
      float v[3];
      for (int c = 0; c < 3; ++c) v[c] = q0[c] + sigma * (nb[c] - f0[c]);
      const float len = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
      for (int c = 0; c < 3; ++c) {
        // unsquared: projection onto |q| <= c; squared: argmin |q - v|^2/(2
        // sigma) + |q|^2/(2c).
        const float expected =
            penalty == DataPenalty::kL2
                ? (len > c_w ? v[c] * c_w / len : v[c])
                : (c_w > 0 ? v[c] * c_w / (c_w + sigma) : 0.0f);
        EXPECT_NEAR(q.plane(c)[0], expected, 1e-6);
      }
    }
  }
}

/// prox of sigma F^*, F(z) = c huber_delta(|z - f|): q = argmin |q - v|^2 /
/// (2 sigma) + delta |q|^2 / (2 c) over |q| <= c, v = q0 + sigma (nbar - f);
/// the minimizer lies along v: searched on a fine grid of lengths.
TEST(Kernels, DataHuberDualProxMatchesItsDefinition) {
  const float sigma = 0.7f;
  for (float c_w : {0.3f, 1.5f}) {
    for (float delta : {0.0f, 0.1f, 0.8f, 2.0f}) {
      for (float scale : {0.05f, 1.0f, 4.0f}) {
        PlanarImage q(1, 1, 3), nbar(1, 1, 3), f(1, 1, 3);
        const float q0[3] = {0.2f * scale, -0.1f * scale, 0.4f * scale},
                    nb[3] = {0.0f, 0.6f, -0.8f}, f0[3] = {0.6f, 0.0f, -0.8f};
        for (int c = 0; c < 3; ++c) {
          q.plane(c)[0] = q0[c];
          nbar.plane(c)[0] = nb[c];
          f.plane(c)[0] = f0[c];
        }
        internal::reference::proxDataDual(q, nbar, f, &c_w, &delta, sigma,
                                          DataPenalty::kL2);
        double v[3], len = 0.0;
        for (int c = 0; c < 3; ++c) {
          v[c] = q0[c] + sigma * (nb[c] - f0[c]);
          len += v[c] * v[c];
        }
        len = std::sqrt(len);
        double best = 1e30, best_t = 0.0;
        for (int k = 0; k <= 200000; ++k) {
          const double t = c_w * k / 200000.0;
          const double obj = (t - len) * (t - len) / (2.0 * sigma) +
                             delta / (2.0 * c_w) * t * t;
          if (obj < best) {
            best = obj;
            best_t = t;
          }
        }
        for (int c = 0; c < 3; ++c) {
          EXPECT_NEAR(q.plane(c)[0], best_t * v[c] / len, 1e-4)
              << "c=" << c_w << " delta=" << delta << " scale=" << scale;
        }
      }
    }
  }
}

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
  for (VisibilityMode mode : {VisibilityMode::kSoft, VisibilityMode::kHard}) {
    SolverSettings settings;
    settings.lambda = 0.5;
    settings.visibility = mode;
    settings.data_eps_local = 0.0;
    settings.density_power = 0.0;
    const internal::PreparedLevel level =
        internal::prepareFinest(problem, settings);
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
        EXPECT_NEAR(level.data_weight[0].at(0, y, x), c, 1e-6) << x << "," << y;
        for (int k = 0; k < 3; ++k) {
          EXPECT_NEAR(level.data[0].at(k, y, x), f[k], 1e-6)
              << x << "," << y << " component " << k;
        }
      }
    }
    EXPECT_EQ(level.valid_pixels, valid);
    EXPECT_GT(valid, 0);
    EXPECT_LT(valid, W * H);
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

TEST(Kernels, TangentProjectionLandsOnPlaneAndVisibleSet) {
  const float n0[3] = {0.0f, 0.6f, -0.8f};
  const float r[3] = {0.3f, -0.2f, 1.0f};
  float v[3] = {0.9f, 1.2f, 0.5f};
  internal::projectTangentFeasible(n0, r, true, v);
  EXPECT_NEAR(n0[0] * v[0] + n0[1] * v[1] + n0[2] * v[2], 1.0f, 1e-5);
  EXPECT_LE(r[0] * v[0] + r[1] * v[1] + r[2] * v[2], 1e-5);
  // It is the closest such point: compare with random feasible points.
  const float y[3] = {0.9f, 1.2f, 0.5f};
  const double d_proj = std::pow(v[0] - y[0], 2) + std::pow(v[1] - y[1], 2) +
                        std::pow(v[2] - y[2], 2);
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(-3, 3);
  for (int k = 0; k < 2000; ++k) {
    float z[3] = {u(rng), u(rng), u(rng)};
    internal::projectTangentFeasible(n0, r, false, z);  // onto the plane
    if (r[0] * z[0] + r[1] * z[1] + r[2] * z[2] > 0) continue;
    const double d = std::pow(z[0] - y[0], 2) + std::pow(z[1] - y[1], 2) +
                     std::pow(z[2] - y[2], 2);
    EXPECT_GE(d, d_proj - 1e-5);
  }
}

TEST(Kernels, VisibleProjectionIsOnTheBoundary) {
  const float r[3] = {0.1f, 0.2f, 1.0f};
  float n[3] = {0.0f, 0.0f, 1.0f};  // facing away
  internal::projectVisible(r, n);
  EXPECT_NEAR(r[0] * n[0] + r[1] * n[1] + r[2] * n[2], 0.0f, 1e-5);
  EXPECT_NEAR(n[0] * n[0] + n[1] * n[1] + n[2] * n[2], 1.0f, 1e-5);
}

/// Builds a random level with L inputs (some missing) for backend comparisons;
/// with `data_huber`, random per-pixel data thresholds delta in [0, 0.6].
internal::PreparedLevel randomLevel(int W, int H, int L, std::uint64_t seed,
                                    bool data_huber = false) {
  internal::PreparedLevel level;
  level.width = W;
  level.height = H;
  level.num_inputs = L;
  level.K = CameraIntrinsics(0.9 * W, 0.9 * W, W / 2.0, H / 2.0);
  level.K_inv = level.K.inverse();
  level.edge_weight = test::randomImage(W, H, 2, seed);
  for (std::size_t i = 0; i < level.edge_weight.pixelCount() * 2; ++i) {
    level.edge_weight.data()[i] = 0.01f + std::abs(level.edge_weight.data()[i]);
  }
  for (int l = 0; l < L; ++l) {
    PlanarImage f = test::randomImage(W, H, 3, seed + 10 + l);
    PlanarImage c = test::randomImage(W, H, 1, seed + 20 + l);
    for (std::size_t i = 0; i < f.pixelCount(); ++i) {
      float v[3] = {f.plane(0)[i], f.plane(1)[i],
                    -std::abs(f.plane(2)[i]) - 0.2f};
      const float len = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
      const bool missing = c.plane(0)[i] < -0.7f;
      for (int k = 0; k < 3; ++k) f.plane(k)[i] = missing ? 0.0f : v[k] / len;
      c.plane(0)[i] = missing ? 0.0f : std::abs(c.plane(0)[i]);
    }
    level.data.push_back(f);
    level.data_weight.push_back(c);
    PlanarImage delta = test::randomImage(W, H, 1, seed + 30 + l);
    for (std::size_t i = 0; i < delta.pixelCount(); ++i) {
      delta.plane(0)[i] =
          data_huber ? 0.6f * std::abs(delta.plane(0)[i]) : 0.0f;
    }
    level.data_eps.push_back(delta);
  }
  level.data_huber = data_huber;
  return level;
}

/// Diagonally preconditioned steps for L data terms (tau = 1 / (4 + L),
/// sigma = 1/2 for the differences, 1 for the data terms), Huber threshold
/// 0.05, soft visibility.
internal::InnerParams preconditionedParams(int L, int threads) {
  internal::InnerParams params;
  params.tau = 1.0f / (4.0f + L);
  params.sigma = 0.5f;
  params.sigma_data = 1.0f;
  params.huber_eps = 0.05f;
  params.soft_visibility = true;
  params.num_threads = threads;
  return params;
}

void initState(const internal::PreparedLevel& level,
               internal::IterationState& s) {
  s.resize(level.width, level.height, level.num_inputs);
  s.n0 = level.data[0];
  for (std::size_t i = 0; i < s.n0.pixelCount(); ++i) {
    if (level.data_weight[0].plane(0)[i] <= 0.0f) {
      s.n0.plane(0)[i] = 0.0f;
      s.n0.plane(1)[i] = 0.0f;
      s.n0.plane(2)[i] = -1.0f;
    }
  }
  s.n = s.n0;
  s.nbar = s.n0;
  s.p_h.fill(0.0f);
  s.p_v.fill(0.0f);
  for (auto& q : s.q) q.fill(0.0f);
}

/// Largest |a - b| over all values of the pairs of images.
double maxAbsDiff(
    std::initializer_list<std::pair<const PlanarImage*, const PlanarImage*>>
        pairs) {
  double max_diff = 0.0;
  for (const auto& pair : pairs) {
    const std::size_t n = pair.first->pixelCount() * pair.first->channels();
    for (std::size_t i = 0; i < n; ++i) {
      max_diff = std::max(
          max_diff, static_cast<double>(std::abs(pair.first->data()[i] -
                                                 pair.second->data()[i])));
    }
  }
  return max_diff;
}

class FastMatchesReference
    : public ::testing::TestWithParam<std::tuple<int, DataPenalty, bool>> {};

TEST_P(FastMatchesReference, SameIteratesAfterManyIterations) {
  const int L = std::get<0>(GetParam());
  const auto level = randomLevel(37, 23, L, 42 + L);
  internal::InnerParams params;
  params.tau = params.sigma = params.sigma_data =
      static_cast<float>(0.99 / std::sqrt(8.0 + L));
  params.huber_eps = 0.05f;
  params.penalty = std::get<1>(GetParam());
  params.soft_visibility = std::get<2>(GetParam());
  params.num_threads = 2;
  internal::IterationState ref, fast;
  initState(level, ref);
  initState(level, fast);
  internal::runInnerReference(level, params, ref, 60);
  internal::runInnerFast(level, params, fast, 60);
  EXPECT_LT(maxAbsDiff({{&ref.n, &fast.n},
                        {&ref.p_h, &fast.p_h},
                        {&ref.p_v, &fast.p_v},
                        {&ref.q[L - 1], &fast.q[L - 1]}}),
            1e-4);
  const double e_ref = internal::energy(level, 0.05, params.penalty, ref.n, 1);
  const double e_fast =
      internal::energy(level, 0.05, params.penalty, fast.n, 1);
  EXPECT_NEAR(e_fast, e_ref, 1e-4 * std::abs(e_ref));
}

/// Plain TV (eps = 0) on the smoothness terms: the fast Huber dual step
/// a w / max(w + sigma eps, |a|) becomes the clamp to w.
TEST(FastMatchesReferencePlainTv, SameIteratesAfterManyIterations) {
  for (int L : {1, 2}) {
    const auto level = randomLevel(37, 23, L, 70 + L, /*data_huber=*/true);
    internal::InnerParams params = preconditionedParams(L, 2);
    params.huber_eps = 0.0f;
    internal::IterationState ref, fast;
    initState(level, ref);
    initState(level, fast);
    internal::runInnerReference(level, params, ref, 60);
    internal::runInnerFast(level, params, fast, 60);
    EXPECT_LT(
        maxAbsDiff(
            {{&ref.n, &fast.n}, {&ref.p_h, &fast.p_h}, {&ref.p_v, &fast.p_v}}),
        1e-4)
        << "L " << L;
    const double e_ref =
        internal::energy(level, 0.0, DataPenalty::kL2, ref.n, 1);
    const double e_fast =
        internal::energyFast(level, 0.0, DataPenalty::kL2, fast.n, 2);
    EXPECT_NEAR(e_fast, e_ref, 1e-4 * std::abs(e_ref)) << "L " << L;
    // The smoothness duals reach the clamp somewhere (|p| = w), so the test
    // sees the eps = 0 case of the step, not only its interior.
    bool clamped = false;
    for (int i = 0; i < 37 * 23 && !clamped; ++i) {
      const float w = level.edge_weight.plane(0)[i];
      const float len = std::sqrt(fast.p_h.plane(0)[i] * fast.p_h.plane(0)[i] +
                                  fast.p_h.plane(1)[i] * fast.p_h.plane(1)[i] +
                                  fast.p_h.plane(2)[i] * fast.p_h.plane(2)[i]);
      clamped = w > 0.0f && std::abs(len - w) < 1e-5f * w;
    }
    EXPECT_TRUE(clamped) << "L " << L;
  }
}

/// The same with per-pixel Huber thresholds on the data terms.
TEST(FastMatchesReferenceDataHuber, SameIteratesAfterManyIterations) {
  for (int L : {1, 2, 3}) {
    const auto level = randomLevel(37, 23, L, 90 + L, /*data_huber=*/true);
    const internal::InnerParams params = preconditionedParams(L, 2);
    internal::IterationState ref, fast;
    initState(level, ref);
    initState(level, fast);
    internal::runInnerReference(level, params, ref, 60);
    internal::runInnerFast(level, params, fast, 60);
    EXPECT_LT(maxAbsDiff({{&ref.n, &fast.n}, {&ref.q[L - 1], &fast.q[L - 1]}}),
              1e-4)
        << "L " << L;
    // The thresholds change the iterates: a run without them differs.
    auto plain = level;
    plain.data_huber = false;
    internal::IterationState other;
    initState(plain, other);
    internal::runInnerReference(plain, params, other, 60);
    EXPECT_GT(maxAbsDiff({{&other.q[0], &ref.q[0]}}), 1e-2) << "L " << L;
    const double e_ref =
        internal::energy(level, 0.05, DataPenalty::kL2, ref.n, 1);
    const double e_fast =
        internal::energyFast(level, 0.05, DataPenalty::kL2, fast.n, 2);
    EXPECT_NEAR(e_fast, e_ref, 1e-4 * std::abs(e_ref));
  }
}

/// The temporal-blocking pipeline gives the same iterates for any thread
/// count, block depth and iteration count (rounds that do not divide evenly,
/// threads with nothing to do in a round).
TEST(FastPipeline, SameIteratesForAnyThreadsDepthAndCount) {
  const auto level = randomLevel(29, 17, 2, 7, /*data_huber=*/true);
  // Diagonal preconditioning steps (different dual steps per term).
  internal::InnerParams params = preconditionedParams(2, 1);
  for (int iterations : {1, 5, 13, 40}) {
    internal::IterationState ref;
    initState(level, ref);
    internal::runInnerReference(level, params, ref, iterations);
    for (int threads : {1, 2, 3}) {
      for (int depth : {1, 4, 32}) {
        params.num_threads = threads;
        params.block_depth = depth;
        internal::IterationState fast;
        initState(level, fast);
        internal::runInnerFast(level, params, fast, iterations);
        const double max_diff =
            maxAbsDiff({{&fast.n, &ref.n}, {&fast.p_v, &ref.p_v}});
        EXPECT_LT(max_diff, 1e-5) << "iterations " << iterations << " threads "
                                  << threads << " depth " << depth;
      }
    }
  }
}

TEST(FastEnergy, MatchesTheReferenceEnergy) {
  for (int L : {1, 3}) {
    for (bool data_huber : {false, true}) {
      const auto level = randomLevel(45, 31, L, 3 + L, data_huber);
      const PlanarImage n = test::randomImage(45, 31, 3, 77);
      for (DataPenalty penalty : {DataPenalty::kL2, DataPenalty::kSquaredL2}) {
        for (double eps : {0.0, 0.05, 0.5}) {
          const double e_ref = internal::energy(level, eps, penalty, n, 1);
          const double e_fast = internal::energyFast(level, eps, penalty, n, 2);
          EXPECT_NEAR(e_fast, e_ref, 1e-5 * e_ref)
              << "L " << L << " eps " << eps << " data_huber " << data_huber;
        }
      }
    }
  }
}

INSTANTIATE_TEST_SUITE_P(
    Backends, FastMatchesReference,
    ::testing::Combine(::testing::Values(1, 2, 3),
                       ::testing::Values(DataPenalty::kL2,
                                         DataPenalty::kSquaredL2),
                       ::testing::Values(false, true)));

}  // namespace
}  // namespace normal_fusion

namespace normal_fusion {
namespace {

/// Seeds of a local refinement: each pixel with probability `density`.
std::vector<unsigned char> randomSeeds(int W, int H, double density,
                                       std::uint64_t seed) {
  const PlanarImage u = test::randomImage(W, H, 1, seed);
  std::vector<unsigned char> seeds(static_cast<std::size_t>(W) * H);
  for (std::size_t i = 0; i < seeds.size(); ++i) {
    seeds[i] = std::abs(u.data()[i]) < density ? 1 : 0;
  }
  return seeds;
}

TEST(ActiveSet, DilatesTheSeedsAndListsEachTouchingLinkOnce) {
  const int W = 23, H = 17;
  const auto seeds = randomSeeds(W, H, 0.04, 5);
  internal::ActiveSet active;
  for (int radius : {0, 1, 2}) {
    active.build(seeds, W, H, radius);
    // The mask against a brute-force dilation.
    std::vector<int> expected_pixels;
    for (int y = 0; y < H; ++y) {
      for (int x = 0; x < W; ++x) {
        bool near = false;
        for (int v = y - radius; v <= y + radius; ++v) {
          for (int u = x - radius; u <= x + radius; ++u) {
            near = near || (u >= 0 && v >= 0 && u < W && v < H &&
                            seeds[v * W + u] != 0);
          }
        }
        ASSERT_EQ(active.mask[y * W + x], near ? 1 : 0)
            << x << "," << y << " r " << radius;
        if (near) expected_pixels.push_back(y * W + x);
      }
    }
    EXPECT_EQ(active.pixels, expected_pixels);
    // Links with an active end, each once, in order.
    std::vector<int> expected_h, expected_v;
    for (int y = 0; y < H; ++y) {
      for (int x = 0; x < W; ++x) {
        const int i = y * W + x;
        if (x + 1 < W && (active.mask[i] || active.mask[i + 1]))
          expected_h.push_back(i);
        if (y + 1 < H && (active.mask[i] || active.mask[i + W]))
          expected_v.push_back(i);
      }
    }
    EXPECT_EQ(active.links_h, expected_h) << "r " << radius;
    EXPECT_EQ(active.links_v, expected_v) << "r " << radius;
  }
  // Radius 2 reaches further than 0.
  active.build(seeds, W, H, 0);
  const std::size_t seeds_only = active.pixels.size();
  active.build(seeds, W, H, 2);
  EXPECT_GT(active.pixels.size(), 3 * seeds_only);
}

/// With every pixel active, the active iteration is the whole-image one.
TEST(ActiveIterations, AllActiveEqualsTheWholeImageIteration) {
  const int W = 21, H = 13, L = 2;
  const auto level = randomLevel(W, H, L, 61, /*data_huber=*/true);
  const internal::InnerParams params = preconditionedParams(L, 1);
  internal::ActiveSet active;
  active.build(std::vector<unsigned char>(W * H, 1), W, H, 0);
  ASSERT_EQ(active.pixels.size(), static_cast<std::size_t>(W * H));
  internal::IterationState whole, local;
  initState(level, whole);
  initState(level, local);
  internal::runInnerReference(level, params, whole, 40);
  internal::runInnerActive(level, params, local, active, 40);
  EXPECT_LT(maxAbsDiff({{&whole.n, &local.n},
                        {&whole.nbar, &local.nbar},
                        {&whole.p_h, &local.p_h},
                        {&whole.p_v, &local.p_v},
                        {&whole.q[1], &local.q[1]}}),
            1e-6);
}

/// The gathered fast path against the reference active iteration, and the
/// pixels outside the set untouched.
TEST(ActiveIterations, FastMatchesReferenceAndLeavesOtherPixelsAlone) {
  const int W = 41, H = 29;
  for (int L : {1, 2, 3}) {
    for (DataPenalty penalty : {DataPenalty::kL2, DataPenalty::kSquaredL2}) {
      const auto level = randomLevel(W, H, L, 70 + L, /*data_huber=*/true);
      internal::InnerParams params = preconditionedParams(L, 2);
      params.penalty = penalty;
      internal::ActiveSet active;
      active.build(randomSeeds(W, H, 0.03, 80 + L), W, H, 1);
      internal::IterationState start, ref, fast;
      for (internal::IterationState* s : {&start, &ref, &fast}) {
        initState(level, *s);
        // Nonzero duals everywhere, as a warm start carries them.
        s->p_h = test::randomImage(W, H, 3, 90, 0.01f);
        s->p_v = test::randomImage(W, H, 3, 91, 0.01f);
      }
      internal::runInnerActive(level, params, ref, active, 50);
      internal::ActiveBuffers buffers;
      buffers.gather(level, fast, active);
      internal::runInnerActiveFast(level, params, buffers, 50);
      buffers.scatter(fast);
      double n_diff = 0.0;
      for (int k = 0; k < buffers.num_active; ++k) {
        const int i = active.pixels[k];
        for (int c = 0; c < 3; ++c) {
          n_diff = std::max(n_diff, static_cast<double>(std::abs(
                                        buffers.n[c][k] - ref.n.plane(c)[i])));
        }
      }
      EXPECT_LT(n_diff, 1e-4) << "L " << L;
      EXPECT_LT(maxAbsDiff({{&ref.p_h, &fast.p_h},
                            {&ref.p_v, &fast.p_v},
                            {&ref.q[L - 1], &fast.q[L - 1]}}),
                1e-4)
          << "L " << L;
      // The iterations did move the active pixels, and nothing else.
      double moved = 0.0;
      for (int y = 0; y < H; ++y) {
        for (int x = 0; x < W; ++x) {
          const int i = y * W + x;
          for (int c = 0; c < 3; ++c) {
            const float d = std::abs(ref.n.plane(c)[i] - start.n.plane(c)[i]);
            if (active.mask[i]) {
              moved = std::max(moved, static_cast<double>(d));
            } else {
              ASSERT_EQ(d, 0.0f) << x << "," << y;
              ASSERT_EQ(ref.q[0].plane(c)[i], start.q[0].plane(c)[i]);
              // A link between two inactive pixels keeps its dual.
              if (x + 1 < W && !active.mask[i + 1]) {
                ASSERT_EQ(ref.p_h.plane(c)[i], start.p_h.plane(c)[i]);
              }
            }
          }
        }
      }
      EXPECT_GT(moved, 1e-2);
    }
  }
}

/// The active terms of E change exactly as E does when only active pixels
/// change, and the gathered energy is the same sum.
TEST(ActiveEnergy, ChangesAsTheWholeEnergy) {
  const int W = 33, H = 21, L = 2;
  const auto level = randomLevel(W, H, L, 17, /*data_huber=*/true);
  internal::ActiveSet active;
  active.build(randomSeeds(W, H, 0.05, 18), W, H, 1);
  internal::IterationState s;
  initState(level, s);
  PlanarImage changed = s.n0;
  const PlanarImage noise = test::randomImage(W, H, 3, 19);
  for (int i : active.pixels) {
    float v[3];
    for (int c = 0; c < 3; ++c) v[c] = changed.plane(c)[i] + noise.plane(c)[i];
    const float len = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    for (int c = 0; c < 3; ++c) changed.plane(c)[i] = v[c] / len;
  }
  for (DataPenalty penalty : {DataPenalty::kL2, DataPenalty::kSquaredL2}) {
    for (double eps : {0.0, 0.05}) {
      const double whole = internal::energy(level, eps, penalty, changed, 1) -
                           internal::energy(level, eps, penalty, s.n0, 1);
      const double local =
          internal::energyActive(level, eps, penalty, changed, active, 2) -
          internal::energyActive(level, eps, penalty, s.n0, active, 2);
      EXPECT_NEAR(local, whole, 1e-9 * (1.0 + std::abs(whole)));
      EXPECT_GT(std::abs(whole), 1.0);
      // Gathered at n0 = changed: the same terms (float sums).
      internal::IterationState at_changed;
      initState(level, at_changed);
      at_changed.n0 = changed;
      internal::ActiveBuffers buffers;
      buffers.gather(level, at_changed, active);
      const double expected =
          internal::energyActive(level, eps, penalty, changed, active, 1);
      EXPECT_NEAR(buffers.energy(eps, penalty), expected, 1e-5 * expected);
    }
  }
}

/// The gathered refinement gives the same bits on 1, 2 and 3 threads, its
/// energy included: the premise of RefineThreadChooser, which switches the
/// count between steps. The set is large enough for every thread to work.
TEST(ActiveIterations, SameBitsForAnyThreadCount) {
  const int W = 160, H = 120, L = 2;
  const auto level = randomLevel(W, H, L, 31, /*data_huber=*/true);
  internal::ActiveSet active;
  active.build(randomSeeds(W, H, 0.15, 32), W, H, 1);
  internal::IterationState start;
  initState(level, start);
  start.p_h = test::randomImage(W, H, 3, 33, 0.01f);
  start.p_v = test::randomImage(W, H, 3, 34, 0.01f);
  std::vector<internal::ActiveBuffers> runs(3);
  std::vector<double> energies;
  for (int threads = 1; threads <= 3; ++threads) {
    internal::ActiveBuffers& b = runs[threads - 1];
    b.gather(level, start, active, threads);
    ASSERT_GT(b.num_active, 3 * 4096) << "too small to use every thread";
    internal::InnerParams params = preconditionedParams(L, threads);
    // Steps on alternating counts end where steps on one count do.
    for (int step = 0; step < 4; ++step) {
      params.num_threads = step % 2 == 0 ? threads : 1;
      internal::runInnerActiveFast(level, params, b, 5);
    }
    b.normalizeCandidate();
    energies.push_back(b.energy(0.05, DataPenalty::kL2, threads));
  }
  for (int t = 1; t < 3; ++t) {
    EXPECT_EQ(energies[t], energies[0]) << t + 1 << " threads";
    for (int ch = 0; ch < 3; ++ch) {
      EXPECT_EQ(runs[t].node_n[ch], runs[0].node_n[ch]) << t + 1 << " threads";
      EXPECT_EQ(runs[t].p[ch], runs[0].p[ch]) << t + 1 << " threads";
    }
    EXPECT_EQ(runs[t].q, runs[0].q) << t + 1 << " threads";
  }
  // And the steps did move the pixels.
  double moved = 0.0;
  for (int k = 0; k < runs[0].num_active; ++k) {
    moved = std::max(moved, static_cast<double>(std::abs(runs[0].node_n[0][k] -
                                                         runs[0].n0[0][k])));
  }
  EXPECT_GT(moved, 1e-2);
}

/// The refinement's thread count: each count measured first, then the
/// cheaper one, the other re-measured every kProbeInterval steps; a change
/// of load turns the choice.
TEST(RefineThreadChooser, RunsTheCheaperCountAndProbesTheOther) {
  using Chooser = internal::RefineThreadChooser;
  Chooser chooser;
  chooser.reset(1);
  for (int step = 0; step < 20; ++step) EXPECT_EQ(chooser.choose(), 1);

  chooser.reset(2);
  EXPECT_EQ(chooser.choose(), 2);  // nothing measured: all threads first
  chooser.record(2, 8e-9);
  EXPECT_EQ(chooser.choose(), 1);  // then one
  chooser.record(1, 12e-9);
  EXPECT_EQ(chooser.cost(1), 12e-9);
  EXPECT_EQ(chooser.cost(2), 8e-9);
  // Two threads cheaper: two, and one every kProbeInterval-th step.
  int ones = 0;
  for (int step = 0; step < 4 * Chooser::kProbeInterval; ++step) {
    const int threads = chooser.choose();
    chooser.record(threads, threads == 1 ? 12e-9 : 8e-9);
    ones += threads == 1 ? 1 : 0;
  }
  EXPECT_EQ(ones, 4);
  // The machine gets loaded: two threads now cost 20e-9, one still 12e-9.
  // The next step on two threads measures it, and one thread runs from then
  // on (two probed every kProbeInterval-th step).
  int first_one = -1, twos = 0;
  for (int step = 0; step < 4 * Chooser::kProbeInterval; ++step) {
    const int threads = chooser.choose();
    chooser.record(threads, threads == 1 ? 12e-9 : 20e-9);
    if (threads == 1 && first_one < 0) first_one = step;
    if (first_one >= 0 && threads == 2) ++twos;
  }
  EXPECT_LE(first_one, 1);
  EXPECT_GE(twos, 3);
  EXPECT_LE(twos, 4);
  // Unusable measurements are ignored.
  chooser.record(1, std::numeric_limits<double>::quiet_NaN());
  chooser.record(1, 0.0);
  chooser.record(1, -1.0);
  int ones_after = 0;
  for (int step = 0; step < Chooser::kProbeInterval; ++step) {
    ones_after += chooser.choose() == 1 ? 1 : 0;
  }
  EXPECT_EQ(ones_after, Chooser::kProbeInterval - 1);
}

/// Map edges: the pixels on both sides of a crease, not those next to an
/// unknown pixel only, and never an unknown one.
TEST(MarkMapEdges, MarksBothSidesOfACrease) {
  const int W = 12, H = 5;
  PlanarImage n(W, H, 3);
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const float s = x < 6 ? 0.6f : -0.6f;  // 74 degrees apart
      n.at(0, y, x) = s;
      n.at(2, y, x) = -0.8f;
    }
  }
  std::vector<unsigned char> unknown(W * H, 0), scratch;
  unknown[2 * W + 1] = 1;  // an unknown pixel away from the crease
  const int marked = internal::markMapEdges(n, unknown, scratch, 2);
  EXPECT_EQ(marked, 2 * H);
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const int expected = (y == 2 && x == 1) ? 1 : (x == 5 || x == 6) ? 2 : 0;
      EXPECT_EQ(unknown[y * W + x], expected) << x << "," << y;
    }
  }
}

/// Unknown pixels between two planes take the side their data supports.
TEST(FillUnknownPixels, TakesTheNeighbourThatFitsTheData) {
  const int W = 20, H = 8;
  internal::PreparedLevel level;
  level.width = W;
  level.height = H;
  level.num_inputs = 1;
  level.K = CameraIntrinsics(20, 20, W / 2.0, H / 2.0);
  level.K_inv = level.K.inverse();
  level.edge_weight = PlanarImage(W, H, 2, 1.0f);
  const float a[3] = {0.6f, 0.0f, -0.8f}, b[3] = {-0.6f, 0.0f, -0.8f};
  PlanarImage f(W, H, 3), n(W, H, 3);
  std::vector<unsigned char> known(W * H, 1), unknown(W * H, 0);
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const float* side = x < 10 ? a : b;
      for (int c = 0; c < 3; ++c) {
        f.at(c, y, x) = side[c];
        n.at(c, y, x) = x >= 7 && x < 13 ? 0.0f : side[c];
      }
      if (x >= 7 && x < 13) {
        known[y * W + x] = 0;
        unknown[y * W + x] = 1;
      }
    }
  }
  level.data = {f};
  level.data_weight = {PlanarImage(W, H, 1, 0.5f)};
  level.data_eps = {PlanarImage(W, H, 1, 0.0f)};
  internal::ActiveSet active;
  active.build(unknown, W, H, 0);
  std::vector<unsigned char> scratch;
  std::vector<int> pending;
  internal::fillUnknownPixels(level, 0.0, DataPenalty::kL2, true, n, known,
                              active, 16, scratch, pending, 2);
  for (int y = 0; y < H; ++y) {
    for (int x = 7; x < 13; ++x) {
      const float* side = x < 10 ? a : b;
      for (int c = 0; c < 3; ++c) {
        ASSERT_NEAR(n.at(c, y, x), side[c], 1e-6) << x << "," << y;
      }
      EXPECT_EQ(known[y * W + x], 1);
    }
  }
}

}  // namespace
}  // namespace normal_fusion
