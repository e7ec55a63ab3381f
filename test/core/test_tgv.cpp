// The second-order smoothness term (tgv_alpha0): the symmetrized gradient and
// its adjoint, the operator norm behind the steps, what the term keeps on a
// curved surface that total variation flattens, and the monotone outer loop.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <utility>

#include "normal_fusion/detail/tgv.h"
#include "solver_test_util.h"
#include "test_util.h"

namespace normal_fusion {
namespace {

using internal::tgv::symmetrizedDivergence;
using internal::tgv::symmetrizedGradient;

double dot(const PlanarImage& a, const PlanarImage& b) {
  double sum = 0.0;
  for (std::size_t i = 0; i < a.pixelCount() * a.channels(); ++i) {
    sum += static_cast<double>(a.data()[i]) * b.data()[i];
  }
  return sum;
}

/// v_h on the last column and v_v on the last row set to 0 (no link there).
void zeroMissingLinks(PlanarImage& v_h, PlanarImage& v_v) {
  const int W = v_h.width(), H = v_h.height();
  for (int c = 0; c < 3; ++c) {
    for (int y = 0; y < H; ++y) v_h.at(c, y, W - 1) = 0.0f;
    for (int x = 0; x < W; ++x) v_v.at(c, H - 1, x) = 0.0f;
  }
}

/// <e, r> of the symmetric 2x2 fields: the off-diagonal entry counts twice.
double symmetricDot(const PlanarImage& e_hh, const PlanarImage& e_vv,
                    const PlanarImage& e_hv, const PlanarImage& r_hh,
                    const PlanarImage& r_vv, const PlanarImage& r_hv) {
  return dot(e_hh, r_hh) + dot(e_vv, r_vv) + 2.0 * dot(e_hv, r_hv);
}

TEST(Tgv, SymmetrizedDivergenceIsTheNegativeAdjointOfE) {
  for (const auto& size :
       {std::make_pair(17, 11), std::make_pair(1, 9), std::make_pair(8, 1),
        std::make_pair(2, 2), std::make_pair(3, 3), std::make_pair(64, 48)}) {
    const int W = size.first, H = size.second;
    PlanarImage v_h = test::randomImage(W, H, 3, 1);
    PlanarImage v_v = test::randomImage(W, H, 3, 2);
    zeroMissingLinks(v_h, v_v);
    const PlanarImage r_hh = test::randomImage(W, H, 3, 3);
    const PlanarImage r_vv = test::randomImage(W, H, 3, 4);
    const PlanarImage r_hv = test::randomImage(W, H, 3, 5);
    PlanarImage e_hh(W, H, 3), e_vv(W, H, 3), e_hv(W, H, 3);
    PlanarImage div_h(W, H, 3), div_v(W, H, 3);
    symmetrizedGradient(v_h, v_v, e_hh, e_vv, e_hv);
    symmetrizedDivergence(r_hh, r_vv, r_hv, div_h, div_v);
    // <E v, r> = -<v, div r>.
    const double lhs = symmetricDot(e_hh, e_vv, e_hv, r_hh, r_vv, r_hv);
    const double rhs = -(dot(v_h, div_h) + dot(v_v, div_v));
    EXPECT_NEAR(lhs, rhs, 1e-5 * (std::abs(lhs) + 1.0)) << W << "x" << H;
  }
}

TEST(Tgv, SymmetrizedGradientOfALinearFieldIsZero) {
  // v = grad n of a field linear in x and y: E v = 0 wherever it is taken.
  const int W = 9, H = 7;
  PlanarImage n(W, H, 3), v_h(W, H, 3), v_v(W, H, 3);
  for (int c = 0; c < 3; ++c) {
    for (int y = 0; y < H; ++y) {
      for (int x = 0; x < W; ++x) n.at(c, y, x) = 0.1f * (c + 1) * x - 0.2f * y;
    }
  }
  internal::reference::gradient(n, v_h, v_v);
  PlanarImage e_hh(W, H, 3), e_vv(W, H, 3), e_hv(W, H, 3);
  symmetrizedGradient(v_h, v_v, e_hh, e_vv, e_hv);
  for (std::size_t i = 0; i < n.pixelCount(); ++i) {
    EXPECT_NEAR(internal::tgv::symmetricNorm(e_hh, e_vv, e_hv, i), 0.0, 1e-5);
  }
  // A kink in n is seen.
  for (int c = 0; c < 3; ++c) {
    for (int y = 0; y < H; ++y) n.at(c, y, 4) += 0.5f;
  }
  internal::reference::gradient(n, v_h, v_v);
  symmetrizedGradient(v_h, v_v, e_hh, e_vv, e_hv);
  EXPECT_GT(internal::tgv::symmetricNorm(e_hh, e_vv, e_hv, 3 * W + 4), 0.5);
}

TEST(Tgv, OperatorNormIsBelowTheStepBound) {
  // Power iteration on K^T K, K (n, v) = (grad n - v, E v): ||K||^2 stays
  // below kTgvOperatorNorm2, the bound the scalar steps rely on.
  const int W = 24, H = 20;
  PlanarImage n = test::randomImage(W, H, 3, 7);
  PlanarImage v_h = test::randomImage(W, H, 3, 8);
  PlanarImage v_v = test::randomImage(W, H, 3, 9);
  PlanarImage g_h(W, H, 3), g_v(W, H, 3), div(W, H, 3);
  PlanarImage e_hh(W, H, 3), e_vv(W, H, 3), e_hv(W, H, 3);
  PlanarImage d_h(W, H, 3), d_v(W, H, 3);
  double norm2 = 0.0;
  for (int it = 0; it < 300; ++it) {
    zeroMissingLinks(v_h, v_v);
    const double length2 = dot(n, n) + dot(v_h, v_h) + dot(v_v, v_v);
    // y = K x.
    internal::reference::gradient(n, g_h, g_v);
    for (std::size_t i = 0; i < 3 * g_h.pixelCount(); ++i) {
      g_h.data()[i] -= v_h.data()[i];
      g_v.data()[i] -= v_v.data()[i];
    }
    symmetrizedGradient(v_h, v_v, e_hh, e_vv, e_hv);
    zeroMissingLinks(g_h, g_v);
    norm2 = (dot(g_h, g_h) + dot(g_v, g_v) +
             symmetricDot(e_hh, e_vv, e_hv, e_hh, e_vv, e_hv)) /
            length2;
    // x = K^T y / |K^T y|: (-div p, -p - div r).
    internal::reference::divergence(g_h, g_v, div);
    symmetrizedDivergence(e_hh, e_vv, e_hv, d_h, d_v);
    for (std::size_t i = 0; i < 3 * n.pixelCount(); ++i) {
      n.data()[i] = -div.data()[i];
      v_h.data()[i] = -g_h.data()[i] - d_h.data()[i];
      v_v.data()[i] = -g_v.data()[i] - d_v.data()[i];
    }
    zeroMissingLinks(v_h, v_v);
    const double scale =
        1.0 / std::sqrt(dot(n, n) + dot(v_h, v_h) + dot(v_v, v_v));
    for (PlanarImage* image : {&n, &v_h, &v_v}) {
      for (std::size_t i = 0; i < 3 * image->pixelCount(); ++i) {
        image->data()[i] = static_cast<float>(image->data()[i] * scale);
      }
    }
  }
  EXPECT_GT(norm2, 8.0);  // more than grad alone
  EXPECT_LT(norm2, internal::kTgvOperatorNorm2);
}

/// A solve of `problem` on the reference backend, with `alpha0`.
NormalMap solveWith(const FusionProblem& problem, double alpha0,
                    SolveReport* report,
                    SolverBackend backend = SolverBackend::kReference) {
  SolverSettings settings = test::convergedSettings();
  settings.backend = backend;
  settings.lambda = 0.1;
  settings.tgv_alpha0 = alpha0;
  // The second-order term against plain first-order TV: the image's weights
  // alone, no noise estimate.
  settings.dynamic_guidance = 0.0;
  settings.noise_radius = 0;
  settings.max_total_inner_iterations = 3000;
  settings.relative_tolerance = 1e-6;
  return Solver(settings).solve(problem, report);
}

TEST(Tgv, KeepsACurvedSurfaceThatTotalVariationFlattens) {
  // Noise-free normals of a cylinder: they turn linearly across the image.
  NormalMap gt;
  FusionProblem problem = test::cylinderScene(48, 32, &gt);
  NormalInput input;
  input.normals = gt;
  problem.inputs.push_back(input);
  SolveReport tv_report, tgv_report;
  const NormalMap tv = solveWith(problem, 0.0, &tv_report);
  const NormalMap tgv = solveWith(problem, 2.0, &tgv_report);
  const double tv_mse = test::meanSquaredError(tv, gt);
  const double tgv_mse = test::meanSquaredError(tgv, gt);
  // The bound that the second-order term meets and total variation, which
  // flattens the turn of the normals into facets, misses.
  const double bound = 2e-4;
  EXPECT_LT(tgv_mse, bound);
  EXPECT_GT(tv_mse, bound);
}

TEST(Tgv, OuterEnergyIsMonotone) {
  NormalMap gt;
  FusionProblem problem = test::cylinderScene(40, 30, &gt);
  NormalInput input;
  input.normals = test::noisy(gt, 0.3, 5);
  problem.inputs.push_back(input);
  SolveReport report;
  const NormalMap n = solveWith(problem, 2.0, &report);
  test::expectUnit(n);
  ASSERT_GE(report.energies.size(), 3u);
  for (std::size_t k = 1; k < report.energies.size(); ++k) {
    EXPECT_LE(report.energies[k], report.energies[k - 1]) << "step " << k;
  }
}

TEST(Tgv, FastBackendRequestRunsTheReferenceIterations) {
  NormalMap gt;
  FusionProblem problem = test::cylinderScene(24, 16, &gt);
  NormalInput input;
  input.normals = test::noisy(gt, 0.2, 3);
  problem.inputs.push_back(input);
  SolveReport fast_report, reference_report;
  const NormalMap fast =
      solveWith(problem, 1.0, &fast_report, SolverBackend::kFast);
  const NormalMap reference =
      solveWith(problem, 1.0, &reference_report, SolverBackend::kReference);
  EXPECT_TRUE(test::identical(fast, reference));
}

}  // namespace
}  // namespace normal_fusion
