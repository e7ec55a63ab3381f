// Scenes, settings and checks shared by the whole-solver tests
// (test/core/test_solver*.cpp).
#pragma once

#include <gtest/gtest.h>

#include <cstdint>
#include <limits>

#include "normal_fusion/solver.h"
#include "test_util.h"

namespace normal_fusion {
namespace test {

inline constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

/// The W x H two-plane scene with one noisy input (sigma, seed).
inline FusionProblem noisyTwoPlanes(int W, int H, double sigma, NormalMap* gt,
                                    std::uint64_t seed = 7) {
  FusionProblem problem = test::twoPlaneScene(W, H, gt);
  NormalInput input;
  input.normals = test::noisy(*gt, sigma, seed);
  problem.inputs.push_back(input);
  return problem;
}

/// The W x H two-plane scene with two noisy inputs (sigma_0 with seed 7,
/// sigma_1 with seed_1).
inline FusionProblem twoPlanesTwoInputs(double sigma_0, double sigma_1,
                                        NormalMap* gt, int W = 64, int H = 48,
                                        std::uint64_t seed_1 = 11) {
  FusionProblem problem = noisyTwoPlanes(W, H, sigma_0, gt);
  NormalInput second;
  second.normals = test::noisy(*gt, sigma_1, seed_1);
  problem.inputs.push_back(second);
  return problem;
}

/// Settings that run a solve to convergence.
inline SolverSettings convergedSettings() {
  SolverSettings settings;
  settings.relative_tolerance = 1e-7;
  settings.max_total_inner_iterations = 6000;
  settings.max_outer_iterations = 300;
  return settings;
}

/// A warm solve from `start`: the local refinement (`refine` iterations),
/// then 1 whole-image iteration. Returns the normals.
inline NormalMap refineOnce(const FusionProblem& problem,
                            const SolverState& start, int refine,
                            SolveReport* report,
                            SolverBackend backend = SolverBackend::kFast) {
  SolverSettings live;
  live.max_total_inner_iterations = 1;
  live.warm_refine_iterations = refine;
  live.backend = backend;
  SolverState state = start;
  *report = Solver(live).solve(problem, state, true);
  return state.normals;
}

/// Every pixel of `n` is a unit vector.
inline void expectUnit(const NormalMap& n) {
  for (std::size_t i = 0; i < n.pixelCount(); ++i) {
    const float len2 = n.plane(0)[i] * n.plane(0)[i] +
                       n.plane(1)[i] * n.plane(1)[i] +
                       n.plane(2)[i] * n.plane(2)[i];
    ASSERT_NEAR(len2, 1.0f, 1e-4) << "pixel " << i;
  }
}

}  // namespace test
}  // namespace normal_fusion
