// The warm start: far fewer iterations from a converged state, the local
// refinement of unknown pixels, of content the warp cannot know and of moved
// map edges, its thread count, and a live frame that ends with it.
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "normal_fusion/metrics.h"
#include "normal_fusion/solver.h"
#include "solver_test_util.h"
#include "test_util.h"

namespace normal_fusion {
namespace {

using test::convergedSettings;
using test::expectUnit;
using test::kNaN;
using test::noisyTwoPlanes;
using test::refineOnce;
using test::twoPlanesTwoInputs;

TEST(Solver, WarmStartFromConvergedStateNeedsFarFewerIterations) {
  NormalMap gt;
  FusionProblem problem = noisyTwoPlanes(64, 48, 0.5, &gt);
  SolverSettings settings;
  settings.inner_iterations = 20;
  settings.relative_tolerance = 1e-4;
  settings.max_total_inner_iterations = 5000;
  settings.max_outer_iterations = 250;
  // The cold solve runs to a tighter tolerance, so that it has converged
  // and not merely paused (the stopping rule can stop on a short plateau).
  SolverSettings cold_settings = settings;
  cold_settings.relative_tolerance = 1e-6;
  Solver solver(cold_settings);
  SolverState state;
  const SolveReport cold = solver.solve(problem, state, false);
  ASSERT_TRUE(cold.converged);
  solver.setSettings(settings);
  EXPECT_FALSE(cold.warm_started);
  const SolveReport warm = solver.solve(problem, state, true);
  EXPECT_TRUE(warm.warm_started);
  EXPECT_TRUE(warm.converged);
  EXPECT_LE(warm.final_energy, cold.final_energy * (1.0 + 1e-4));
  EXPECT_LE(warm.inner_iterations * 4, cold.inner_iterations);
  // An incompatible state (other size) falls back to a cold start.
  NormalMap gt_small;
  FusionProblem small = noisyTwoPlanes(32, 24, 0.5, &gt_small);
  const SolveReport fallback = solver.solve(small, state, true);
  EXPECT_FALSE(fallback.warm_started);
}

/// A warm start with unknown pixels (a band and a border strip, as a warp
/// leaves them): the local refinement solves them, both backends alike, and
/// ends far closer to the converged solution than the same solve without it.
TEST(Solver, WarmStartRefinementSolvesTheUnknownPixels) {
  NormalMap gt;
  const FusionProblem problem = twoPlanesTwoInputs(0.5, 0.3, &gt);
  SolverState converged;
  Solver(convergedSettings()).solve(problem, converged, false);
  // Unknown: columns 28 - 35 (across the planes' edge at x = 32) and the
  // first 3 columns.
  SolverState holed = converged;
  ScalarMap band(64, 48, 1);
  for (int y = 0; y < 48; ++y) {
    for (int x = 0; x < 64; ++x) {
      if ((x >= 28 && x < 36) || x < 3) {
        for (int c = 0; c < 3; ++c) holed.normals.at(c, y, x) = kNaN;
        band.at(0, y, x) = 1.0f;
      }
    }
  }
  SolveReport with, without, reference;
  const NormalMap refined = refineOnce(problem, holed, 100, &with);
  const NormalMap plain = refineOnce(problem, holed, 0, &without);
  const NormalMap oracle =
      refineOnce(problem, holed, 100, &reference, SolverBackend::kReference);
  EXPECT_TRUE(with.warm_started);
  // Columns 27 - 36 and 0 - 3 (the band, the strip and 1 pixel around
  // each), 48 rows.
  EXPECT_EQ(with.refined_pixels, 14 * 48);
  // All 100, or a converged stop once at least half of them ran; the
  // reference backend stops at the same count.
  EXPECT_GE(with.refine_iterations, 50);
  EXPECT_LE(with.refine_iterations, 100);
  EXPECT_EQ(reference.refine_iterations, with.refine_iterations);
  EXPECT_EQ(without.refined_pixels, 0);
  EXPECT_LE(with.final_energy, without.final_energy);
  const double err_with = test::meanSquaredError(refined, converged.normals);
  const double err_without = test::meanSquaredError(plain, converged.normals);
  EXPECT_LT(err_with, 0.2 * err_without)
      << "with " << err_with << " without " << err_without;
  // Measured: 144 dB with the refinement, 9.8 dB without.
  EXPECT_GT(psnr(refined, converged.normals, band), 40.0);
  EXPECT_LT(psnr(plain, converged.normals, band), 20.0);
  // The reference backend refines to the same normals.
  EXPECT_LT(test::meanSquaredError(refined, oracle), 1e-8);
  EXPECT_EQ(reference.refined_pixels, with.refined_pixels);
  expectUnit(refined);
}

/// The local refinement on one thread or two per step
/// (adaptive_refine_threads) gives the same bits as always two: the choice
/// changes only the time. The set is large enough for two threads, and the
/// chooser's second step always runs on one (each count measured once).
TEST(Solver, AdaptiveRefineThreadsGiveTheSameBits) {
  NormalMap gt;
  const FusionProblem problem = twoPlanesTwoInputs(0.5, 0.3, &gt, 160, 120, 12);
  SolverState converged;
  Solver(convergedSettings()).solve(problem, converged, false);
  SolverState holed = converged;
  for (int y = 0; y < 120; ++y) {
    for (int x = 40; x < 80; ++x) {
      for (int c = 0; c < 3; ++c) holed.normals.at(c, y, x) = kNaN;
    }
  }
  std::vector<NormalMap> results[2];
  int single_thread_iterations[2] = {0, 0};
  for (int adaptive = 0; adaptive < 2; ++adaptive) {
    SolverSettings live;
    live.num_threads = 2;
    live.max_total_inner_iterations = 1;
    live.warm_refine_iterations = 100;
    live.adaptive_refine_threads = adaptive == 1;
    Solver solver(live);
    // Two frames with the same solver: the second starts with both counts
    // measured.
    for (int frame = 0; frame < 2; ++frame) {
      SolverState state = holed;
      const SolveReport report = solver.solve(problem, state, true);
      ASSERT_GT(report.refined_pixels, 4096);
      EXPECT_EQ(report.refine_iterations, 100);
      single_thread_iterations[adaptive] +=
          report.refine_single_thread_iterations;
      results[adaptive].push_back(state.normals);
    }
  }
  EXPECT_EQ(single_thread_iterations[0], 0);
  EXPECT_GT(single_thread_iterations[1], 0);
  for (int frame = 0; frame < 2; ++frame) {
    for (int c = 0; c < 3; ++c) {
      const float* a = results[0][frame].plane(c);
      const float* b = results[1][frame].plane(c);
      for (std::size_t i = 0; i < results[0][frame].pixelCount(); ++i) {
        ASSERT_EQ(a[i], b[i]) << "frame " << frame << " pixel " << i;
      }
    }
  }
}

/// New content that the warp cannot know of (a patch whose normals turned
/// by 40 degrees, with no unknown pixel in the warm start): the inputs
/// contradict the warm start there, so the local refinement takes the patch
/// and follows the new data; without it the patch stays stale.
TEST(Solver, WarmStartFollowsContentTheWarpCannotKnow) {
  NormalMap gt;
  const FusionProblem before = twoPlanesTwoInputs(0.3, 0.2, &gt);
  SolverSettings settings = convergedSettings();
  SolverState converged;
  Solver(settings).solve(before, converged, false);
  // The patch x 8 - 23, y 16 - 31 (inside the left plane) turns to face
  // 40 degrees up.
  NormalMap gt_after = gt;
  ScalarMap patch(64, 48, 1);
  const float turned[3] = {0.0f, static_cast<float>(std::sin(0.698)),
                           -static_cast<float>(std::cos(0.698))};
  for (int y = 16; y < 32; ++y) {
    for (int x = 8; x < 24; ++x) {
      for (int c = 0; c < 3; ++c) gt_after.at(c, y, x) = turned[c];
      patch.at(0, y, x) = 1.0f;
    }
  }
  FusionProblem after = before;
  after.inputs[0].normals = test::noisy(gt_after, 0.3, 21);
  after.inputs[1].normals = test::noisy(gt_after, 0.2, 22);
  SolveReport with, without;
  const NormalMap followed = refineOnce(after, converged, 100, &with);
  const NormalMap stale = refineOnce(after, converged, 0, &without);
  // Most of the patch is contradicted (measured: 197 of 256; the rest is
  // refined as their neighbours or left to noise), little else.
  EXPECT_GT(with.inconsistent_pixels, 150);
  EXPECT_LT(with.inconsistent_pixels, 256 + 20);
  EXPECT_EQ(without.inconsistent_pixels, 0);
  const double angle_with = angularError(followed, gt_after, patch).mean_deg;
  const double angle_without = angularError(stale, gt_after, patch).mean_deg;
  SolveReport cold_report;
  const NormalMap cold = Solver(settings).solve(after, &cold_report);
  const double angle_cold = angularError(cold, gt_after, patch).mean_deg;
  // Measured: 6.86 degrees live, 6.87 for a converged cold solve, 46.8 stale.
  EXPECT_LT(angle_with, angle_cold + 1.0) << "cold " << angle_cold;
  EXPECT_GT(angle_without, 30.0);
}

/// An edge that moved by 2 pixels (the parallax of a camera's translation,
/// which a rotation-only warp does not follow), where no input observes it:
/// the warm start has no unknown pixel and nothing contradicts it, but its
/// map edge seeds the local refinement, which moves the edge to where the
/// image puts it.
TEST(Solver, WarmStartMovesAnEdgeOfTheMap) {
  NormalMap gt;
  const FusionProblem before = twoPlanesTwoInputs(0.3, 0.2, &gt);
  SolverSettings settings = convergedSettings();
  SolverState converged;
  Solver(settings).solve(before, converged, false);
  // Columns 30 and 31 now belong to the right plane, in the image too.
  NormalMap gt_after = gt;
  FusionProblem after = before;
  ScalarMap strip(64, 48, 1);
  for (int y = 0; y < 48; ++y) {
    for (int x = 28; x < 36; ++x) strip.at(0, y, x) = 1.0f;
    for (int x = 30; x < 32; ++x) {
      for (int c = 0; c < 3; ++c) gt_after.at(c, y, x) = gt.at(c, y, 40);
      after.image.at(0, y, x) = before.image.at(0, y, 40);
    }
  }
  after.inputs[0].normals = test::noisy(gt_after, 0.3, 21);
  after.inputs[1].normals = test::noisy(gt_after, 0.2, 22);
  // No input sees columns 29 - 32, so no input can contradict the warm start
  // there: the image's edge alone moves the map's edge.
  for (NormalInput& input : after.inputs) {
    for (int y = 0; y < 48; ++y) {
      for (int x = 29; x < 33; ++x) input.normals.at(2, y, x) = kNaN;
    }
  }
  SolveReport with, without;
  const NormalMap moved = refineOnce(after, converged, 100, &with);
  const NormalMap stale = refineOnce(after, converged, 0, &without);
  // Seeds: both sides of the old edge (columns 31, 32), nothing else.
  EXPECT_EQ(with.inconsistent_pixels, 0);
  EXPECT_EQ(with.edge_pixels, 2 * 48);
  EXPECT_EQ(with.refined_pixels, 4 * 48);
  EXPECT_EQ(without.edge_pixels, 0);
  settings.pyramid_levels = 1;
  const NormalMap cold = Solver(settings).solve(after);
  const double angle_cold = angularError(cold, gt_after, strip).mean_deg;
  const double angle_with = angularError(moved, gt_after, strip).mean_deg;
  const double angle_without = angularError(stale, gt_after, strip).mean_deg;
  EXPECT_LT(angle_with, angle_cold + 1.0) << "cold " << angle_cold;
  EXPECT_GT(angle_without, angle_cold + 5.0) << "cold " << angle_cold;
}

/// Live (a time budget and the local refinement): a warm frame's time goes
/// to the refinement and the frame ends with it; no whole-image iterations
/// even when time is left. Without a budget they follow.
TEST(Solver, LiveWarmFrameEndsWithItsRefinement) {
  NormalMap gt;
  FusionProblem problem = noisyTwoPlanes(64, 48, 0.5, &gt);
  SolverSettings settings;
  settings.max_total_inner_iterations = 100;
  Solver solver(settings);
  SolverState state;
  solver.solve(problem, state, false);
  // Unknown pixels for the refinement: a band of NaN normals.
  auto with_band = [&] {
    SolverState warm = state;
    for (int y = 10; y < 20; ++y) {
      for (int c = 0; c < 3; ++c) warm.normals.at(c, y, 30) = NAN;
    }
    return warm;
  };
  settings.time_budget_ms = 10000.0;
  solver.setSettings(settings);
  SolverState live = with_band();
  SolveReport report;
  solver.solve(problem, live, true, report);
  EXPECT_GT(report.refine_iterations, 0);
  EXPECT_EQ(report.inner_iterations, 0);
  EXPECT_TRUE(report.energies.empty());
  expectUnit(live.normals);
  // The refinement keeps balance 1 whatever step_balance says (its filled
  // normals start far off; balanced steps left live maps 0.65 dB short).
  for (double balance : {1.0, 4.0}) {  // the default is 0.25
    SolverSettings balanced = settings;
    balanced.step_balance = balance;
    Solver other(balanced);
    SolverState live_balanced = with_band();
    other.solve(problem, live_balanced, true);
    for (std::size_t i = 0; i < 3 * live.normals.pixelCount(); ++i) {
      ASSERT_EQ(live_balanced.normals.data()[i], live.normals.data()[i])
          << "balance " << balance << ", value " << i;
    }
  }
  settings.time_budget_ms = 0.0;
  solver.setSettings(settings);
  SolverState offline = with_band();
  solver.solve(problem, offline, true, report);
  EXPECT_GT(report.refine_iterations, 0);
  EXPECT_GT(report.inner_iterations, 0);
  EXPECT_FALSE(report.energies.empty());
}

}  // namespace
}  // namespace normal_fusion
