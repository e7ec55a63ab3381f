// The maths of one iteration: adjointness, proximal steps against their closed
// forms, the tangent-plane and visibility projections.
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <utility>

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

}  // namespace
}  // namespace normal_fusion
