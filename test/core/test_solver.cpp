// Behaviour of the whole solver: monotone energy, balanced steps, unit output,
// visibility, fill-in, fusion of several inputs, the backends alike on a whole
// solve, the relaxed iteration, orientation conventions and the stopping
// rules.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <random>
#include <utility>
#include <vector>

#include "eval/synthetic.h"
#include "normal_fusion/errors.h"
#include "normal_fusion/solver.h"
#include "solver_test_util.h"
#include "test_util.h"

namespace normal_fusion {
namespace {

using test::expectUnit;
using test::kNaN;
using test::noisyTwoPlanes;
using test::twoPlanesTwoInputs;

float dot3(const NormalMap& n, std::size_t i, const float r[3]) {
  return n.plane(0)[i] * r[0] + n.plane(1)[i] * r[1] + n.plane(2)[i] * r[2];
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

/// The relaxed iteration (over_relaxation 1.9) on a whole solve: the
/// backends alike, the energy monotone, the same converged energy as the
/// plain iteration and closer to it after the same iterations, on each
/// synthetic scene; its output faces the camera (soft visibility).
TEST(Solver, RelaxedIterationConvergesSoonerToTheSameEnergy) {
  ASSERT_EQ(SolverSettings().over_relaxation, 1.0);
  {
    NormalMap gt;
    const FusionProblem problem = twoPlanesTwoInputs(0.4, 0.2, &gt, 40, 30, 99);
    SolverSettings settings;
    settings.over_relaxation = 1.9;
    settings.max_total_inner_iterations = 200;
    settings.relative_tolerance = 0.0;
    settings.backend = SolverBackend::kReference;
    SolveReport ref_report, fast_report;
    Solver(settings).solve(problem, &ref_report);
    settings.backend = SolverBackend::kFast;
    Solver(settings).solve(problem, &fast_report);
    EXPECT_EQ(ref_report.inner_iterations, fast_report.inner_iterations);
    EXPECT_NEAR(fast_report.final_energy, ref_report.final_energy,
                1e-4 * ref_report.final_energy);
  }
  for (int scene = 0; scene < synthetic::kNumScenes; ++scene) {
    SCOPED_TRACE(::testing::Message() << "scene " << scene);
    const synthetic::Frame frame = synthetic::renderScene(scene, 160, 120);
    FusionProblem problem;
    problem.image = frame.image;
    problem.K = frame.K;
    NormalInput input;
    input.normals = synthetic::addPaperNoise(frame.normals_gt, 0.4, 5);
    problem.inputs = {input};
    auto solve = [&](double rho, int iterations, NormalMap* out) {
      SolverSettings settings;
      settings.over_relaxation = rho;
      settings.relative_tolerance = 0.0;
      settings.max_total_inner_iterations = iterations;
      settings.max_outer_iterations = 1000;
      SolveReport report;
      NormalMap n = Solver(settings).solve(problem, &report);
      for (std::size_t k = 1; k < report.energies.size(); ++k) {
        EXPECT_LE(report.energies[k], report.energies[k - 1])
            << "rho " << rho << ", outer step " << k;
      }
      if (out != nullptr) *out = std::move(n);
      return report.final_energy;
    };
    NormalMap relaxed;
    const double e_relaxed = solve(1.9, 4000, &relaxed);
    const double e_plain = solve(1.0, 4000, nullptr);
    const double e_star = std::min(e_relaxed, e_plain);
    EXPECT_NEAR(e_relaxed, e_plain, 1e-4 * e_star);
    EXPECT_LT(solve(1.9, 300, nullptr) - e_star,
              solve(1.0, 300, nullptr) - e_star);
    // Soft visibility (the default) holds for the relaxed solve's output.
    const auto K_inv = problem.K.inverse();
    for (int y = 0; y < relaxed.height(); ++y) {
      for (int x = 0; x < relaxed.width(); ++x) {
        const float r[3] = {
            static_cast<float>(K_inv[0] * x + K_inv[1] * y + K_inv[2]),
            static_cast<float>(K_inv[3] * x + K_inv[4] * y + K_inv[5]),
            static_cast<float>(K_inv[6] * x + K_inv[7] * y + K_inv[8])};
        const std::size_t i = static_cast<std::size_t>(y) * relaxed.width() + x;
        ASSERT_LE(dot3(relaxed, i, r), 1e-5f) << x << ", " << y;
      }
    }
  }
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

}  // namespace
}  // namespace normal_fusion
