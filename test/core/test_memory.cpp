// Memory given back: buffers sized for a much larger frame than the current
// one are released (PlanarImage, the solver's own buffers, its state, the
// warp's scratch, the temporal averages), while a size seen before keeps its
// buffers (test_allocations.cpp counts that a steady stream allocates
// nothing).
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdio>

#include "normal_fusion/solver.h"
#include "normal_fusion/temporal.h"
#include "normal_fusion/warp.h"
#include "test_util.h"

namespace normal_fusion {
namespace {

constexpr std::size_t kFloat = sizeof(float);

TEST(Memory, PlanarImageGivesBackWhatAMuchLargerSizeLeft) {
  PlanarImage image(400, 300, 3);
  const float* data = image.data();
  const std::size_t large = image.bytesHeld();
  EXPECT_EQ(large, 400 * 300 * 3 * kFloat);
  // The same size, a smaller one down to a quarter of the capacity, and back:
  // the same buffer.
  image.resize(400, 300, 3);
  EXPECT_EQ(image.data(), data);
  image.resize(200, 150, 4);  // a third
  EXPECT_EQ(image.data(), data);
  EXPECT_EQ(image.bytesHeld(), large);
  image.resize(400, 300, 3);
  EXPECT_EQ(image.data(), data);
  // Kept on purpose (the levels of a pyramid).
  image.resizeKeepingCapacity(40, 30, 3);
  EXPECT_EQ(image.data(), data);
  EXPECT_EQ(image.bytesHeld(), large);
  // Below a quarter: a buffer of the new size replaces it, and stays.
  image.resize(40, 30, 3);
  EXPECT_EQ(image.bytesHeld(), 40 * 30 * 3 * kFloat);
  const float* small = image.data();
  image.resize(40, 30, 3);
  EXPECT_EQ(image.data(), small);
  EXPECT_EQ(image.width(), 40);
  EXPECT_EQ(image.channels(), 3);
  image.resize(0, 0, 0);
  EXPECT_EQ(image.bytesHeld(), 0u);
  EXPECT_TRUE(image.empty());
}

/// The cylinder scene, W x H, with two noisy inputs and a hole in both (a
/// cold start then runs on the pyramid).
FusionProblem cylinderWithHole(int W, int H) {
  NormalMap gt;
  FusionProblem problem = test::cylinderScene(W, H, &gt);
  for (std::uint64_t l = 0; l < 2; ++l) {
    NormalInput input;
    input.normals = test::noisy(gt, 0.3, 5 + l);
    problem.inputs.push_back(input);
  }
  for (int y = H / 4; y < H / 2; ++y) {
    for (int x = W / 4; x < W / 2; ++x) {
      for (NormalInput& input : problem.inputs) {
        input.normals.at(2, y, x) = NAN;
      }
    }
  }
  return problem;
}

/// What a solver, its state and the warp's scratch hold.
struct Held {
  std::size_t solver = 0, state = 0, scratch = 0;
};

/// A cold start (on the pyramid) and two warped warm frames (with the local
/// refinement) of `problem`.
void stream(Solver& solver, SolverState& state, SolverState& scratch,
            const FusionProblem& problem) {
  solver.solve(problem, state, false);
  const double a = 1.0 * 3.14159265358979 / 180.0;
  const std::array<double, 9> R = {std::cos(a),  0, std::sin(a), 0, 1, 0,
                                   -std::sin(a), 0, std::cos(a)};
  for (int frame = 0; frame < 2; ++frame) {
    warpStateByRotation(state, problem.K, R, scratch, 2);
    const SolveReport report = solver.solve(problem, state, true);
    EXPECT_TRUE(report.warm_started);
    EXPECT_GT(report.refined_pixels, 0);
  }
}

Held held(const Solver& solver, const SolverState& state,
          const SolverState& scratch) {
  return {solver.bytesHeld(), state.bytesHeld(), scratch.bytesHeld()};
}

/// clear() gives a state's memory back; clearKeepingCapacity() keeps it
/// (a stream's restart then allocates nothing), and either leaves a state
/// that warm-starts nothing; sized again, the kept buffers are reused.
TEST(Memory, AStateClearedKeepingCapacityHoldsItsBuffers) {
  SolverState state;
  state.resize(40, 30, 2);
  state.converging = true;
  const std::size_t bytes = state.bytesHeld();
  EXPECT_EQ(bytes, 5 * 40 * 30 * 3 * kFloat);  // n, p_h, p_v, q_0, q_1
  state.clearKeepingCapacity();
  EXPECT_EQ(state.bytesHeld(), bytes);
  EXPECT_FALSE(state.compatible(40, 30, 2));
  EXPECT_FALSE(state.converging);
  const float* normals = state.normals.data();
  state.resize(40, 30, 2);
  EXPECT_EQ(state.normals.data(), normals);
  EXPECT_TRUE(state.compatible(40, 30, 2));
  state.clear();
  EXPECT_EQ(state.bytesHeld(), 0u);
  EXPECT_FALSE(state.compatible(40, 30, 2));
}

/// A stream at 1600x1200, then one at 64x48 with the same solver, state and
/// scratch: they then hold about what a fresh solver, state and scratch
/// hold after the small stream alone (here at most twice), not the large
/// frame's buffers (about 600 times more). Both backends.
TEST(Memory, SolverAndStateGiveBackWhatALargeFrameLeft) {
  const FusionProblem large = cylinderWithHole(1600, 1200);
  const FusionProblem small = cylinderWithHole(64, 48);
  for (SolverBackend backend :
       {SolverBackend::kFast, SolverBackend::kReference}) {
    SolverSettings settings;
    settings.backend = backend;
    settings.num_threads = 2;
    settings.inner_iterations = 2;
    settings.max_total_inner_iterations = 4;
    settings.warm_refine_iterations = 5;
    Solver solver(settings);
    SolverState state, scratch;
    stream(solver, state, scratch, large);
    const Held after_large = held(solver, state, scratch);
    stream(solver, state, scratch, small);
    const Held after_small = held(solver, state, scratch);
    Solver fresh_solver(settings);
    SolverState fresh_state, fresh_scratch;
    stream(fresh_solver, fresh_state, fresh_scratch, small);
    const Held fresh = held(fresh_solver, fresh_state, fresh_scratch);
    std::printf(
        "%s: bytes held by the solver / state / warp scratch: %zu / %zu / %zu "
        "after 1600x1200, %zu / %zu / %zu after 64x48, fresh %zu / %zu / %zu\n",
        toString(backend).c_str(), after_large.solver, after_large.state,
        after_large.scratch, after_small.solver, after_small.state,
        after_small.scratch, fresh.solver, fresh.state, fresh.scratch);
    // The large frame's buffers were there to give back.
    EXPECT_GT(after_large.solver, 100 * fresh.solver);
    EXPECT_GT(after_large.state, 100 * fresh.state);
    EXPECT_LE(after_small.solver, 2 * fresh.solver) << toString(backend);
    EXPECT_LE(after_small.state, 2 * fresh.state) << toString(backend);
    EXPECT_LE(after_small.scratch, 2 * fresh.scratch) << toString(backend);
  }
}

/// The temporal averages of large inputs, then small ones: the averages and
/// their scratch follow the small size.
TEST(Memory, TemporalAveragesGiveBackWhatALargeFrameLeft) {
  const FusionProblem large = cylinderWithHole(1600, 1200);
  const FusionProblem small = cylinderWithHole(64, 48);
  TemporalSettings settings;
  settings.frames = 4;
  const std::array<double, 9> R = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  auto run = [&](TemporalAverage& average, const FusionProblem& problem) {
    for (const std::array<double, 9>* rotation : {&R, &R}) {
      std::vector<NormalInput> inputs = problem.inputs;
      average.apply(inputs, problem.K, rotation, settings, 2);
    }
  };
  TemporalAverage average, fresh;
  run(average, large);
  const std::size_t after_large = average.bytesHeld();
  run(average, small);
  run(fresh, small);
  std::printf(
      "temporal averages: %zu bytes after 1600x1200, %zu after 64x48, "
      "fresh %zu\n",
      after_large, average.bytesHeld(), fresh.bytesHeld());
  EXPECT_GT(after_large, 100 * fresh.bytesHeld());
  EXPECT_LE(average.bytesHeld(), 2 * fresh.bytesHeld());
}

}  // namespace
}  // namespace normal_fusion
