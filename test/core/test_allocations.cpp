// Steady state: once running, solving frame after frame of one size performs
// no heap allocation inside the solver (counted by replacing operator new).
#include <gtest/gtest.h>

#include <array>
#include <atomic>
#include <cmath>
#include <cstdlib>
#include <functional>
#include <new>

#include "allocation_counter.h"
#include "normal_fusion/solver.h"
#include "normal_fusion/warp.h"
#include "test_util.h"

namespace normal_fusion {
namespace {

/// The cylinder scene, 96x64, with two noisy inputs.
FusionProblem cylinderTwoInputs() {
  NormalMap gt;
  FusionProblem problem = test::cylinderScene(96, 64, &gt);
  for (std::uint64_t l = 0; l < 2; ++l) {
    NormalInput input;
    input.normals = test::noisy(gt, 0.3, 5 + l);
    problem.inputs.push_back(input);
  }
  return problem;
}

using test::allocationsDuring;

TEST(Allocations, NonePerFrameOnceRunning) {
  for (SolverBackend backend :
       {SolverBackend::kFast, SolverBackend::kReference}) {
    for (bool with_holes : {false, true}) {
      FusionProblem problem = cylinderTwoInputs();
      if (with_holes) {  // cold starts then use the pyramid
        for (int y = 10; y < 40; ++y) {
          for (int x = 10; x < 40; ++x) {
            for (NormalInput& in : problem.inputs) in.normals.at(2, y, x) = NAN;
          }
        }
      }
      SolverSettings settings;
      settings.backend = backend;
      settings.max_total_inner_iterations = 60;
      settings.inner_iterations = 20;
      settings.num_threads = 2;
      Solver solver(settings);
      SolverState state;
      SolveReport report;
      for (int frame = 0; frame < 3; ++frame) {
        solver.solve(problem, state, !with_holes, report);
      }
      const long count = allocationsDuring([&] {
        for (int frame = 0; frame < 3; ++frame) {
          solver.solve(problem, state, !with_holes, report);
        }
      });
      EXPECT_EQ(count, 0) << "backend " << toString(backend) << ", holes "
                          << with_holes;
      EXPECT_EQ(report.pyramid_levels > 1, with_holes);
      // The counter works: a cold solve into a fresh state allocates.
      EXPECT_GT(allocationsDuring([&] { solver.solve(problem); }), 0);
    }
  }
}

/// Warm starts warped from frame to frame leave unknown pixels (a strip
/// entering the view, edges of the map): neither the warp (with its scratch
/// state) nor the local refinement allocates once running.
TEST(Allocations, NonePerWarpedFrameWithLocalRefinement) {
  for (SolverBackend backend :
       {SolverBackend::kFast, SolverBackend::kReference}) {
    FusionProblem problem = cylinderTwoInputs();
    SolverSettings settings;
    settings.backend = backend;
    settings.max_total_inner_iterations = 20;
    settings.num_threads = 2;
    Solver solver(settings);
    SolverState state, warp_scratch;
    SolveReport report;
    // 0.5 degrees about the y axis per frame, alternating in sign (so that
    // the strip moves from side to side).
    const double a = 0.5 * 3.14159265358979 / 180.0;
    auto warp = [&](int frame) {
      const double s = (frame % 2 == 0 ? 1.0 : -1.0) * std::sin(a);
      const std::array<double, 9> R = {std::cos(a), 0,  s, 0,          1,
                                       0,           -s, 0, std::cos(a)};
      warpStateByRotation(state, problem.K, R, warp_scratch, 2);
    };
    solver.solve(problem, state, false, report);
    for (int frame = 0; frame < 4; ++frame) {
      warp(frame);
      solver.solve(problem, state, true, report);
    }
    long count = 0;
    for (int frame = 0; frame < 4; ++frame) {
      count += allocationsDuring([&] {
        warp(frame);
        solver.solve(problem, state, true, report);
      });
      EXPECT_GT(report.refined_pixels, 0);
    }
    EXPECT_EQ(count, 0) << "backend " << toString(backend);
  }
}

/// With the warp's scratch sized with the state after the cold start
/// (SolverState::resize), even the first warp of a stream allocates nothing.
/// (The solver's refinement buffers are sized on the cold start for 1/16 of
/// the pixels and may grow in a first warm frame that needs more, as on this
/// small image.)
TEST(Allocations, NoneInTheFirstWarp) {
  FusionProblem problem = cylinderTwoInputs();
  SolverSettings settings;
  settings.max_total_inner_iterations = 20;
  settings.num_threads = 2;
  Solver solver(settings);
  SolverState state, warp_scratch;
  solver.solve(problem, state, false);
  warp_scratch.resize(problem.image.width(), problem.image.height(), 2);
  const double a = 0.5 * 3.14159265358979 / 180.0;
  const std::array<double, 9> R = {std::cos(a),  0, std::sin(a), 0, 1, 0,
                                   -std::sin(a), 0, std::cos(a)};
  for (DualWarp duals : {DualWarp::kReset, DualWarp::kRotate}) {
    const long count = allocationsDuring([&] {
      warpStateByRotation(state, problem.K, R, warp_scratch, 2, duals);
    });
    EXPECT_EQ(count, 0);
    EXPECT_TRUE(
        state.compatible(problem.image.width(), problem.image.height(), 2));
  }
}

}  // namespace
}  // namespace normal_fusion
