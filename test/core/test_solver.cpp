// Behaviour of the whole solver: monotone energy, unit output, visibility,
// fill-in, fusion, warm start, backends, and typed errors on bad input.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <vector>

#include "eval/synthetic.h"
#include "normal_fusion/errors.h"
#include "normal_fusion/metrics.h"
#include "normal_fusion/solver.h"
#include "test_util.h"

namespace normal_fusion {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

FusionProblem noisyTwoPlanes(int W, int H, double sigma, NormalMap* gt,
                             std::uint64_t seed = 7) {
  FusionProblem problem = test::twoPlaneScene(W, H, gt);
  NormalInput input;
  input.normals = test::noisy(*gt, sigma, seed);
  problem.inputs.push_back(input);
  return problem;
}

/// The W x H two-plane scene with two noisy inputs (sigma_0 with seed 7,
/// sigma_1 with seed_1).
FusionProblem twoPlanesTwoInputs(double sigma_0, double sigma_1, NormalMap* gt,
                                 int W = 64, int H = 48,
                                 std::uint64_t seed_1 = 11) {
  FusionProblem problem = noisyTwoPlanes(W, H, sigma_0, gt);
  NormalInput second;
  second.normals = test::noisy(*gt, sigma_1, seed_1);
  problem.inputs.push_back(second);
  return problem;
}

/// Settings that run a solve to convergence.
SolverSettings convergedSettings() {
  SolverSettings settings;
  settings.relative_tolerance = 1e-7;
  settings.max_total_inner_iterations = 6000;
  settings.max_outer_iterations = 300;
  return settings;
}

/// A warm solve from `start`: the local refinement (`refine` iterations),
/// then 1 whole-image iteration. Returns the normals.
NormalMap refineOnce(const FusionProblem& problem, const SolverState& start,
                     int refine, SolveReport* report,
                     SolverBackend backend = SolverBackend::kFast) {
  SolverSettings live;
  live.max_total_inner_iterations = 1;
  live.warm_refine_iterations = refine;
  live.backend = backend;
  SolverState state = start;
  *report = Solver(live).solve(problem, state, true);
  return state.normals;
}

float dot3(const NormalMap& n, std::size_t i, const float r[3]) {
  return n.plane(0)[i] * r[0] + n.plane(1)[i] * r[1] + n.plane(2)[i] * r[2];
}

void expectUnit(const NormalMap& n) {
  for (std::size_t i = 0; i < n.pixelCount(); ++i) {
    const float len2 = n.plane(0)[i] * n.plane(0)[i] +
                       n.plane(1)[i] * n.plane(1)[i] +
                       n.plane(2)[i] * n.plane(2)[i];
    ASSERT_NEAR(len2, 1.0f, 1e-4) << "pixel " << i;
  }
}

TEST(Solver, EnergyNeverIncreasesAcrossOuterSteps) {
  for (DataPenalty penalty : {DataPenalty::kL2, DataPenalty::kSquaredL2}) {
    for (VisibilityMode mode : {VisibilityMode::kOff, VisibilityMode::kSoft}) {
      for (bool preconditioning : {false, true}) {
        for (double step_balance : {1.0, 0.25}) {
          SCOPED_TRACE(::testing::Message()
                       << "penalty " << static_cast<int>(penalty)
                       << ", visibility " << static_cast<int>(mode)
                       << ", preconditioning " << preconditioning
                       << ", step balance " << step_balance);
          NormalMap gt;
          FusionProblem problem = noisyTwoPlanes(48, 32, 0.6, &gt);
          SolverSettings settings;
          settings.penalty = penalty;
          settings.visibility = mode;
          settings.preconditioning = preconditioning;
          settings.step_balance = step_balance;
          settings.inner_iterations =
              300;  // enough to approach each tangent minimizer
          settings.max_outer_iterations = 8;
          settings.max_total_inner_iterations = 100000;
          // Balance 1: all 8 steps run (tolerance 0). Balance 0.25 settles
          // within them, after which E differs between steps only by
          // rounding and a step may be rejected for it: it stops on a
          // tolerance of 1e-6 instead.
          const bool plain = step_balance == 1.0;
          settings.relative_tolerance = plain ? 0.0 : 1e-6;
          settings.pyramid_levels = 1;
          Solver solver(settings);
          SolveReport report;
          solver.solve(problem, &report);
          ASSERT_GE(report.energies.size(), 2u);
          // Every tangent-plane solve, normalized, lowered E: none was
          // rejected.
          EXPECT_EQ(report.rejected_outer_steps, 0);
          if (plain) {
            EXPECT_EQ(report.outer_iterations, 8);
          } else {
            EXPECT_GE(report.outer_iterations, 5);
          }
          for (std::size_t k = 1; k < report.energies.size(); ++k) {
            EXPECT_LE(report.energies[k], report.energies[k - 1] * (1.0 + 1e-6))
                << "outer step " << k;
          }
          EXPECT_LT(report.final_energy, 0.5 * report.initial_energy);
          EXPECT_EQ(report.energy_seconds.size(), report.energies.size());
        }
      }
    }
  }
}

/// Steps balanced towards the duals (the default 0.25) bring the energy
/// closer to the converged one after the same iterations than balance 1, on
/// each synthetic scene; explicit steps are not balanced.
TEST(Solver, BalancedStepsConvergeSooner) {
  double gap_balanced = 0.0, gap_plain = 0.0;
  for (int scene = 0; scene < synthetic::kNumScenes; ++scene) {
    SCOPED_TRACE(::testing::Message() << "scene " << scene);
    const synthetic::Frame frame = synthetic::renderScene(scene, 160, 120);
    FusionProblem problem;
    problem.image = frame.image;
    problem.K = frame.K;
    NormalInput input;
    input.normals = synthetic::addPaperNoise(frame.normals_gt, 0.4, 5);
    problem.inputs = {input};
    auto energyAfter = [&](double balance, int iterations) {
      SolverSettings settings;
      settings.step_balance = balance;
      settings.relative_tolerance = 0.0;
      settings.max_total_inner_iterations = iterations;
      settings.max_outer_iterations = 1000;
      SolveReport report;
      Solver(settings).solve(problem, &report);
      return report.final_energy;
    };
    ASSERT_EQ(SolverSettings().step_balance, 0.25);
    // E*: the lower of two long runs.
    const double e_star =
        std::min(energyAfter(0.25, 4000), energyAfter(1.0, 4000));
    const double balanced = energyAfter(0.25, 600) / e_star - 1.0;
    const double plain = energyAfter(1.0, 600) / e_star - 1.0;
    EXPECT_GT(balanced, 0.0);
    EXPECT_LT(balanced, plain);
    gap_balanced += balanced;
    gap_plain += plain;
  }
  // Measured: 0.39 of the gap left by balance 1, summed over the scenes.
  EXPECT_LT(gap_balanced, 0.5 * gap_plain);

  // Explicit steps: the balance does not touch them.
  NormalMap gt;
  const FusionProblem problem = noisyTwoPlanes(32, 24, 0.5, &gt);
  SolverSettings explicit_steps;
  explicit_steps.tau = 0.1;
  explicit_steps.sigma = 0.3;
  explicit_steps.max_total_inner_iterations = 200;
  SolverSettings balanced = explicit_steps;
  balanced.step_balance = 0.1;
  const NormalMap a = Solver(explicit_steps).solve(problem);
  const NormalMap b = Solver(balanced).solve(problem);
  for (std::size_t i = 0; i < 3 * a.pixelCount(); ++i) {
    ASSERT_EQ(a.data()[i], b.data()[i]) << i;
  }
}

TEST(Solver, OutputIsUnitLengthAndDenoises) {
  NormalMap gt;
  FusionProblem problem = noisyTwoPlanes(64, 48, 0.5, &gt);
  Solver solver;
  SolveReport report;
  const NormalMap fused = solver.solve(problem, &report);
  expectUnit(fused);
  const double mse_in = test::meanSquaredError(problem.inputs[0].normals, gt);
  const double mse_out = test::meanSquaredError(fused, gt);
  EXPECT_LT(mse_out, 0.1 * mse_in);
  EXPECT_GT(report.inner_iterations, 0);
  EXPECT_EQ(report.num_inputs, 1);
}

TEST(Solver, SoftVisibilityMakesEveryNormalFaceTheCamera) {
  NormalMap gt;
  FusionProblem problem = noisyTwoPlanes(48, 32, 0.9, &gt);
  // Some observations face away: flip a block of them.
  for (int y = 5; y < 15; ++y) {
    for (int x = 5; x < 20; ++x) {
      for (int c = 0; c < 3; ++c)
        problem.inputs[0].normals.at(c, y, x) *= -1.0f;
    }
  }
  SolverSettings settings;
  settings.visibility = VisibilityMode::kSoft;
  Solver solver(settings);
  const NormalMap fused = solver.solve(problem);
  const auto K_inv = problem.K.inverse();
  for (int y = 0; y < fused.height(); ++y) {
    for (int x = 0; x < fused.width(); ++x) {
      const float r[3] = {
          static_cast<float>(K_inv[0] * x + K_inv[1] * y + K_inv[2]),
          static_cast<float>(K_inv[3] * x + K_inv[4] * y + K_inv[5]),
          static_cast<float>(K_inv[6] * x + K_inv[7] * y + K_inv[8])};
      ASSERT_LE(dot3(fused, static_cast<std::size_t>(y) * fused.width() + x, r),
                1e-5f)
          << "(" << x << ", " << y << ")";
    }
  }
  // Off mode lets flipped observations through (checks that the test can fail).
  settings.visibility = VisibilityMode::kOff;
  settings.lambda = 5.0;
  Solver off(settings);
  const NormalMap fused_off = off.solve(problem);
  int facing_away = 0;
  for (std::size_t i = 0; i < fused_off.pixelCount(); ++i) {
    facing_away += fused_off.plane(2)[i] > 0.0f;
  }
  EXPECT_GT(facing_away, 0);
}

TEST(Solver, HardVisibilityIgnoresInfeasibleObservations) {
  NormalMap gt;
  FusionProblem problem = test::twoPlaneScene(40, 30, &gt);
  NormalInput input;
  input.normals = gt;
  // A block of observations that face away from the camera (flipped).
  for (int y = 10; y < 20; ++y) {
    for (int x = 2; x < 12; ++x) {
      for (int c = 0; c < 3; ++c) input.normals.at(c, y, x) = -gt.at(c, y, x);
    }
  }
  problem.inputs.push_back(input);
  SolverSettings settings;
  settings.visibility = VisibilityMode::kHard;
  settings.lambda = 10.0;  // data would dominate if it were used
  Solver solver(settings);
  SolveReport report;
  const NormalMap fused = solver.solve(problem, &report);
  EXPECT_EQ(report.filled_pixels, 100);
  // The block is filled from its neighbours: close to the ground truth.
  for (int y = 10; y < 20; ++y) {
    for (int x = 2; x < 12; ++x) {
      float d = 0.0f;
      for (int c = 0; c < 3; ++c) d += fused.at(c, y, x) * gt.at(c, y, x);
      EXPECT_GT(d, std::cos(5.0f * 3.14159f / 180.0f)) << x << "," << y;
    }
  }
  // Energy counts no data term where the observation was ignored.
  const double e_gt = computeEnergy(problem, settings, gt);
  SolverSettings off_settings = settings;
  off_settings.visibility = VisibilityMode::kOff;
  EXPECT_LT(e_gt, computeEnergy(problem, off_settings, gt));
}

TEST(Solver, ZeroWeightPixelsAreFilledFromNeighbours) {
  NormalMap gt;
  FusionProblem problem = test::twoPlaneScene(64, 48, &gt);
  NormalInput input;
  input.normals = test::noisy(gt, 0.1, 3);
  input.confidence = ScalarMap(64, 48, 1, 1.0f);
  // A NaN hole and a zero-vector hole on the left plane, a zero-confidence hole
  // on the right one.
  for (int y = 10; y < 30; ++y) {
    for (int x = 4; x < 24; ++x) {
      for (int c = 0; c < 3; ++c)
        input.normals.at(c, y, x) = y < 20 ? kNaN : 0.0f;
    }
    for (int x = 40; x < 60; ++x) input.confidence.at(0, y, x) = 0.0f;
  }
  problem.inputs.push_back(input);
  Solver solver;
  SolveReport report;
  const NormalMap fused = solver.solve(problem, &report);
  expectUnit(fused);
  EXPECT_EQ(report.filled_pixels, 800);
  EXPECT_GT(report.pyramid_levels, 1);
  for (int y = 10; y < 30; ++y) {
    for (int x : {4, 14, 23, 40, 50, 59}) {
      float d = 0.0f;
      for (int c = 0; c < 3; ++c) d += fused.at(c, y, x) * gt.at(c, y, x);
      EXPECT_GT(d, std::cos(5.0f * 3.14159f / 180.0f)) << x << "," << y;
    }
  }
}

/// `gt` with paper noise of `sigma` at a random 5 % of the pixels, NaN at the
/// others.
NormalInput sparseInput(const NormalMap& gt, double sigma, std::uint64_t seed) {
  NormalInput sparse;
  sparse.normals = test::noisy(gt, sigma, seed);
  std::mt19937 rng(static_cast<std::mt19937::result_type>(seed + 1));
  std::uniform_real_distribution<float> u(0, 1);
  for (std::size_t i = 0; i < gt.pixelCount(); ++i) {
    if (u(rng) > 0.05f) {
      for (int c = 0; c < 3; ++c) sparse.normals.plane(c)[i] = kNaN;
    }
  }
  return sparse;
}

TEST(Solver, FusingDenseNoisyWithSparseAccurateBeatsEither) {
  NormalMap gt;
  FusionProblem problem = test::cylinderScene(64, 48, &gt);
  NormalInput dense;
  dense.normals = test::noisy(gt, 0.5, 11);
  NormalInput sparse = sparseInput(gt, 0.03, 12);
  sparse.weight = 4.0;
  dense.weight = 0.25;  // weights reflect each input's accuracy
  SolverSettings settings;
  auto solve_with = [&](std::vector<NormalInput> inputs) {
    FusionProblem p = problem;
    p.inputs = std::move(inputs);
    Solver solver(settings);
    return test::meanSquaredError(solver.solve(p), gt);
  };
  const double mse_dense = solve_with({dense});
  const double mse_sparse = solve_with({sparse});
  const double mse_both = solve_with({dense, sparse});
  EXPECT_LT(mse_both, mse_dense);
  EXPECT_LT(mse_both, mse_sparse);
}

/// With equal input weights, the density correction keeps a sparse, accurate
/// input from being outvoted by a dense, noisy one.
TEST(Solver, DensityCorrectionLetsASparseAccurateInputCount) {
  NormalMap gt;
  FusionProblem problem = test::cylinderScene(64, 48, &gt);
  NormalInput dense;
  dense.normals = test::noisy(gt, 0.6, 21);
  problem.inputs = {dense, sparseInput(gt, 0.03, 22)};
  auto mse_with = [&](double density_power) {
    SolverSettings settings;
    settings.density_power = density_power;
    Solver solver(settings);
    return test::meanSquaredError(solver.solve(problem), gt);
  };
  const double mse_off = mse_with(0.0);
  const double mse_on = mse_with(1.0);
  EXPECT_LT(mse_on, 0.8 * mse_off) << "off " << mse_off << " on " << mse_on;
}

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
  EXPECT_EQ(with.refine_iterations, 100);
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

TEST(Solver, FastBackendMatchesReferenceOnAWholeSolve) {
  NormalMap gt;
  const FusionProblem problem = twoPlanesTwoInputs(0.4, 0.2, &gt, 40, 30, 99);
  SolverSettings settings;
  settings.max_total_inner_iterations = 200;
  settings.relative_tolerance = 0.0;
  settings.backend = SolverBackend::kReference;
  SolveReport ref_report, fast_report;
  Solver reference(settings);
  reference.solve(problem, &ref_report);
  settings.backend = SolverBackend::kFast;
  Solver fast(settings);
  fast.solve(problem, &fast_report);
  EXPECT_EQ(ref_report.inner_iterations, fast_report.inner_iterations);
  EXPECT_NEAR(fast_report.final_energy, ref_report.final_energy,
              1e-4 * ref_report.final_energy);
}

TEST(Solver, OrientationConventionIsAppliedOnInput) {
  NormalMap gt;
  FusionProblem problem = test::twoPlaneScene(32, 24, &gt);
  NormalInput flipped;
  flipped.normals = gt;
  for (std::size_t i = 0; i < gt.pixelCount() * 3; ++i)
    flipped.normals.data()[i] *= -1;
  flipped.orientation = Orientation::opticalFlipped();
  NormalInput gl;
  gl.normals = gt;
  for (std::size_t i = 0; i < gt.pixelCount(); ++i) {
    gl.normals.plane(1)[i] *= -1;
    gl.normals.plane(2)[i] *= -1;
  }
  gl.orientation = Orientation::fromString("opengl");
  for (const NormalInput& input : {flipped, gl}) {
    FusionProblem p = problem;
    p.inputs = {input};
    Solver solver;
    EXPECT_LT(test::meanSquaredError(solver.solve(p), gt), 1e-3);
  }
  EXPECT_THROW(Orientation::fromString("1 0 0 0 2 0 0 0 1"), ParameterError);
  EXPECT_THROW(Orientation::fromString("upside_down"), ParameterError);
}

TEST(Solver, TimeBudgetReturnsTheBestIterateSoFar) {
  NormalMap gt;
  FusionProblem problem = noisyTwoPlanes(320, 240, 0.5, &gt);
  SolverSettings settings;
  settings.time_budget_ms = 1.0;
  settings.max_total_inner_iterations = 100000;
  Solver solver(settings);
  SolveReport report;
  const NormalMap fused = solver.solve(problem, &report);
  EXPECT_TRUE(report.budget_exhausted);
  EXPECT_LT(report.inner_iterations, 100000);
  expectUnit(fused);
  EXPECT_LE(report.final_energy, report.initial_energy);
}

/// 200 inner iterations (steps of 10, no tolerance stop) under a frame
/// budget of 2 s: a budget that only a frame begun long ago runs out of.
SolverSettings twoHundredIterationsUnderABudget() {
  SolverSettings settings;
  settings.time_budget_ms = 2000.0;
  settings.inner_iterations = 10;
  settings.max_total_inner_iterations = 200;
  settings.relative_tolerance = 0.0;
  return settings;
}

/// The next solve's frame began 10 s ago: its budget is spent before the
/// solve starts.
void spendTheFrameBudget(Solver& solver) {
  solver.setBudgetStart(std::chrono::steady_clock::now() -
                        std::chrono::seconds(10));
}

/// setBudgetStart(): the budget counts from the given time (work before the
/// solve is inside it), for one solve only.
TEST(Solver, TimeBudgetCountsFromTheFrameStart) {
  NormalMap gt;
  FusionProblem problem = noisyTwoPlanes(64, 48, 0.5, &gt);
  Solver solver(twoHundredIterationsUnderABudget());
  SolverState state;
  SolveReport report;
  spendTheFrameBudget(solver);
  solver.solve(problem, state, false, report);
  EXPECT_TRUE(report.budget_exhausted);
  EXPECT_LT(report.inner_iterations, 200);
  expectUnit(state.normals);
  // The next solve counts from its own start again: all 200 iterations.
  solver.solve(problem, state, false, report);
  EXPECT_FALSE(report.budget_exhausted);
  EXPECT_EQ(report.inner_iterations, 200);
}

/// A stream's cold start (a warm start asked for, no usable state) runs
/// under cold_start_budget_ms (0 = none), not under the frame budget; a
/// one-shot cold solve and a warm frame keep the frame budget. Each frame's
/// budget is spent before the solve starts (setBudgetStart 10 s back), so
/// only the rule decides whether it stops early.
TEST(Solver, StreamColdStartRunsUnderItsOwnBudget) {
  NormalMap gt;
  FusionProblem problem = noisyTwoPlanes(64, 48, 0.5, &gt);
  SolverSettings settings = twoHundredIterationsUnderABudget();
  Solver solver(settings);
  SolveReport report;
  auto spent_frame = [&] { spendTheFrameBudget(solver); };
  // One-shot cold solve: the frame budget.
  SolverState one_shot;
  spent_frame();
  solver.solve(problem, one_shot, false, report);
  EXPECT_TRUE(report.budget_exhausted);
  EXPECT_FALSE(report.cold_start_budget_used);
  EXPECT_LT(report.inner_iterations, 200);
  // A stream's cold start: no budget by default, all 200 iterations.
  SolverState stream;
  spent_frame();
  solver.solve(problem, stream, true, report);
  EXPECT_FALSE(report.warm_started);
  EXPECT_TRUE(report.cold_start_budget_used);
  EXPECT_FALSE(report.budget_exhausted);
  EXPECT_EQ(report.inner_iterations, 200);
  // The next (warm) frame: the frame budget again.
  spent_frame();
  solver.solve(problem, stream, true, report);
  EXPECT_TRUE(report.warm_started);
  EXPECT_FALSE(report.cold_start_budget_used);
  EXPECT_TRUE(report.budget_exhausted);
  // A cold-start budget of its own (spent too): it stops early.
  settings.cold_start_budget_ms = 2000.0;
  solver.setSettings(settings);
  SolverState restart;
  spent_frame();
  solver.solve(problem, restart, true, report);
  EXPECT_TRUE(report.cold_start_budget_used);
  EXPECT_TRUE(report.budget_exhausted);
  EXPECT_LT(report.inner_iterations, 200);
  expectUnit(restart.normals);
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

TEST(Solver, StopsOnIterationCapAndTolerance) {
  NormalMap gt;
  FusionProblem problem = noisyTwoPlanes(32, 24, 0.5, &gt);
  SolverSettings settings;
  settings.inner_iterations = 30;
  settings.max_total_inner_iterations = 100;
  settings.relative_tolerance = 0.0;
  Solver capped(settings);
  SolveReport report;
  capped.solve(problem, &report);
  EXPECT_EQ(report.inner_iterations, 100);
  EXPECT_EQ(report.outer_iterations, 4);
  EXPECT_FALSE(report.converged);
  settings.relative_tolerance = 1e-2;
  settings.max_total_inner_iterations = 100000;
  Solver tolerant(settings);
  tolerant.solve(problem, &report);
  EXPECT_TRUE(report.converged);
  EXPECT_LT(report.inner_iterations, 100000);
}

TEST(SolverErrors, BadInputRaisesTypedExceptions) {
  NormalMap gt;
  const FusionProblem good = noisyTwoPlanes(16, 12, 0.3, &gt);
  Solver solver;
  auto expect_input_error = [&](const FusionProblem& p, const char* what) {
    try {
      solver.solve(p);
      ADD_FAILURE() << "expected InputError for " << what;
    } catch (const InputError& e) {
      EXPECT_GT(std::string(e.what()).size(), 10u) << what;
    }
  };
  FusionProblem p = good;
  p.inputs.clear();
  expect_input_error(p, "no data terms");
  p = good;
  p.inputs[0].normals = NormalMap(15, 12, 3);
  expect_input_error(p, "mismatched size");
  p = good;
  p.inputs[0].normals = NormalMap(16, 12, 2);
  expect_input_error(p, "wrong channel count");
  p = good;
  p.image = ColorImage(16, 12, 2);
  expect_input_error(p, "image channels");
  p = good;
  p.inputs[0].confidence = ScalarMap(16, 11, 1);
  expect_input_error(p, "confidence size");
  p = good;
  p.K.K[0] = std::numeric_limits<double>::infinity();
  expect_input_error(p, "non-finite K");
  p = good;
  p.K = CameraIntrinsics(0.0, 0.0, 8, 6);
  expect_input_error(p, "singular K");
  p = good;
  p.image.at(0, 3, 3) = kNaN;
  expect_input_error(p, "NaN image");
  p = good;
  p.inputs[0].normals.fill(kNaN);
  expect_input_error(p, "all-missing input");
  p = good;
  p.inputs[0].weight = -1.0;
  EXPECT_THROW(solver.solve(p), ParameterError);
  p.inputs[0].weight = std::nan("");
  EXPECT_THROW(solver.solve(p), ParameterError);
}

TEST(SolverErrors, BadSettingsRaiseParameterError) {
  auto expect_bad = [](SolverSettings s, const char* name) {
    try {
      s.validate();
      ADD_FAILURE() << "expected ParameterError for " << name;
    } catch (const ParameterError& e) {
      EXPECT_NE(std::string(e.what()).find(name), std::string::npos)
          << e.what();
    }
    EXPECT_THROW(Solver{s}, ParameterError);
  };
  SolverSettings s;
  s.lambda = -1;
  expect_bad(s, "lambda");
  s = SolverSettings();
  s.huber_eps = std::nan("");
  expect_bad(s, "huber_eps");
  s = SolverSettings();
  s.inner_iterations = 0;
  expect_bad(s, "inner_iterations");
  s = SolverSettings();
  s.data_eps = std::nan("");
  expect_bad(s, "data_eps");
  s = SolverSettings();
  s.data_eps_local = -0.5;
  expect_bad(s, "data_eps_local");
  s = SolverSettings();
  s.density_power = 9.0;
  expect_bad(s, "density_power");
  s = SolverSettings();
  s.local_radius = 0;
  expect_bad(s, "local_radius");
  s = SolverSettings();
  s.hole_link_weight = 0.0;
  expect_bad(s, "hole_link_weight");
  s = SolverSettings();
  s.warm_refine_iterations = -1;
  expect_bad(s, "warm_refine_iterations");
  s = SolverSettings();
  s.warm_refine_radius = 17;
  expect_bad(s, "warm_refine_radius");
  s = SolverSettings();
  s.edges.w_min = 2.0;
  expect_bad(s, "w_min");
  s = SolverSettings();
  s.time_budget_ms = -5;
  expect_bad(s, "time_budget_ms");
  s = SolverSettings();
  s.cold_start_budget_ms = -1;
  expect_bad(s, "cold_start_budget_ms");
  s = SolverSettings();
  s.tau = 0.5;
  expect_bad(s, "tau");
  for (double balance : {0.0, -0.25, 1e-4, 2e3, std::nan("")}) {
    s = SolverSettings();
    s.step_balance = balance;
    expect_bad(s, "step_balance");
  }
  // Steps that violate tau sigma (8 + L) < 1 are refused at solve time.
  s = SolverSettings();
  s.tau = 0.5;
  s.sigma = 0.5;
  NormalMap gt;
  const FusionProblem problem = noisyTwoPlanes(16, 12, 0.3, &gt);
  Solver solver(s);
  EXPECT_THROW(solver.solve(problem), ParameterError);
  // setSettings keeps the old settings on error.
  Solver keeper;
  SolverSettings bad;
  bad.lambda = -2;
  EXPECT_THROW(keeper.setSettings(bad), ParameterError);
  EXPECT_EQ(keeper.settings().lambda, SolverSettings().lambda);
  EXPECT_THROW(parseVisibilityMode("sometimes"), ParameterError);
  EXPECT_EQ(parseDataPenalty("squared_l2"), DataPenalty::kSquaredL2);
}

/// The paper-style weights: Gaussian pre-smoothing, Sobel, luminance.
EdgeWeightSettings sobelSettings() {
  EdgeWeightSettings settings;
  settings.gradient = EdgeGradient::kSobel;
  settings.smoothing_sigma = 1.2;
  settings.alpha = 10.0;
  settings.w_min = 0.01;
  settings.color_mode = EdgeColorMode::kLuminance;
  return settings;
}

TEST(EdgeWeights, FlatImageGivesOneAndEdgesGiveLess) {
  ColorImage flat(20, 10, 1, 0.5f);
  EdgeWeightSettings settings = sobelSettings();
  const PlanarImage w_flat = computeEdgeWeights(flat, settings);
  for (std::size_t i = 0; i < w_flat.pixelCount() * 2; ++i) {
    EXPECT_FLOAT_EQ(w_flat.data()[i], 1.0f);
  }
  ColorImage step(20, 10, 3, 0.0f);
  for (int y = 0; y < 10; ++y) {
    for (int x = 10; x < 20; ++x) {
      for (int c = 0; c < 3; ++c) step.at(c, y, x) = 1.0f;  // black to white
    }
  }
  const PlanarImage w = computeEdgeWeights(step, settings);
  EXPECT_LT(w.at(0, 5, 9), 0.1f);   // across the step
  EXPECT_GT(w.at(1, 5, 9), 0.99f);  // along it
  EXPECT_GT(w.at(0, 5, 1), 0.99f);  // far from it
  EXPECT_GE(w.at(0, 5, 9), settings.w_min);
  // A step in green alone: the colour gradient sees full contrast, the
  // luminance only 0.587 of it.
  ColorImage green(20, 10, 3, 0.0f);
  for (int y = 0; y < 10; ++y) {
    for (int x = 10; x < 20; ++x) green.at(1, y, x) = 1.0f;
  }
  const PlanarImage w_lum = computeEdgeWeights(green, settings);
  settings.color_mode = EdgeColorMode::kColorMax;
  const PlanarImage w_max = computeEdgeWeights(green, settings);
  EXPECT_NEAR(w_max.at(0, 5, 9), w.at(0, 5, 9), 1e-6);
  EXPECT_LT(w_max.at(0, 5, 9), 0.5f * w_lum.at(0, 5, 9));
  settings.enabled = false;
  EXPECT_FLOAT_EQ(computeEdgeWeights(step, settings).at(0, 5, 9), 1.0f);
}

/// The exponential weights (computed with a float exp) against the double
/// exp of the same differences: within 2e-7 relative wherever the weight is
/// above 0.05, the floor everywhere else.
TEST(EdgeWeights, ExponentialMatchesTheDoubleExp) {
  const int W = 800, H = 2;
  ColorImage ramp(W, H, 1, 0.0f);
  // Differences 0, 0.0005, 0.001, ...: weights from 1 down to the floor.
  for (int y = 0; y < H; ++y) {
    float value = 0.0f;
    for (int x = 0; x < W; ++x) {
      ramp.at(0, y, x) = value;
      value += 0.0005f * x;
    }
  }
  EdgeWeightSettings settings;  // exponential, beta 1, forward differences
  settings.w_min = 0.01;
  const PlanarImage w = computeEdgeWeights(ramp, settings);
  int checked = 0, floored = 0;
  for (int x = 0; x + 1 < W; ++x) {
    const float g = std::abs(ramp.at(0, 0, x + 1) - ramp.at(0, 0, x));
    const double expected = std::exp(-settings.alpha * static_cast<double>(g));
    if (expected >= 0.05) {
      EXPECT_NEAR(w.at(0, 0, x), expected, 2e-7 * expected) << "g " << g;
      ++checked;
    } else if (expected < settings.w_min) {
      EXPECT_EQ(w.at(0, 0, x), static_cast<float>(settings.w_min));
      ++floored;
    }
  }
  EXPECT_GT(checked, 100);
  EXPECT_GT(floored, 100);
}

TEST(EdgeWeights, ForwardDifferencesMarkExactlyTheLinkAcrossAnEdge) {
  ColorImage step(20, 10, 3, 0.2f);
  for (int y = 0; y < 10; ++y) {
    for (int x = 10; x < 20; ++x) step.at(1, y, x) = 0.8f;  // green step
  }
  EdgeWeightSettings settings;  // defaults: forward differences, colour max
  ASSERT_EQ(settings.gradient, EdgeGradient::kForwardDifference);
  const PlanarImage w = computeEdgeWeights(step, settings);
  // Only the link between columns 9 and 10 is cut (down to the floor).
  EXPECT_FLOAT_EQ(w.at(0, 5, 9), static_cast<float>(settings.w_min));
  EXPECT_FLOAT_EQ(w.at(0, 5, 8), 1.0f);
  EXPECT_FLOAT_EQ(w.at(0, 5, 10), 1.0f);
  EXPECT_FLOAT_EQ(w.at(1, 5, 9), 1.0f);  // along the edge
  // A faint step (0.02) keeps most of the weight: exp(-alpha * 0.02).
  ColorImage faint(20, 10, 1, 0.5f);
  for (int y = 0; y < 10; ++y) {
    for (int x = 10; x < 20; ++x) faint.at(0, y, x) = 0.52f;
  }
  EXPECT_NEAR(computeEdgeWeights(faint, settings).at(0, 5, 9),
              std::exp(-settings.alpha * 0.02), 1e-4);
  EXPECT_GT(std::exp(-settings.alpha * 0.02), settings.w_min);
  // The luminance sees 0.587 of the green step: a higher weight.
  settings.color_mode = EdgeColorMode::kLuminance;
  settings.w_min = 0.0;
  settings.alpha = 5.0;
  const float w_lum = computeEdgeWeights(step, settings).at(0, 5, 9);
  settings.color_mode = EdgeColorMode::kColorMax;
  const float w_max = computeEdgeWeights(step, settings).at(0, 5, 9);
  EXPECT_NEAR(w_max, std::exp(-5.0 * 0.6), 1e-4);
  EXPECT_NEAR(w_lum, std::exp(-5.0 * 0.6 * 0.587), 1e-3);
}

}  // namespace
}  // namespace normal_fusion
