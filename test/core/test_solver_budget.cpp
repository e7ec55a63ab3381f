// The solver's time budgets: the best iterate when time runs out, the frame
// budget counted from the frame's start, and a stream's cold start under its
// own budget.
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>

#include "normal_fusion/metrics.h"
#include "normal_fusion/solver.h"
#include "solver_test_util.h"

namespace normal_fusion {
namespace {

using test::expectUnit;
using test::noisyTwoPlanes;

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

/// The same with a cold-start budget of 2 s too.
SolverSettings twoHundredIterationsUnderTwoBudgets() {
  SolverSettings settings = twoHundredIterationsUnderABudget();
  settings.cold_start_budget_ms = 2000.0;
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
  // One-shot cold solve: the frame budget (its finest level still runs and
  // measures E).
  SolverState one_shot;
  spent_frame();
  solver.solve(problem, one_shot, false, report);
  EXPECT_TRUE(report.budget_exhausted);
  EXPECT_FALSE(report.cold_start_budget_used);
  EXPECT_LT(report.inner_iterations, 200);
  EXPECT_GT(report.inner_iterations, 0);
  EXPECT_FALSE(std::isnan(report.final_energy));
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

/// A stream's cold start under cold_start_budget_ms sets aside what the last
/// one's tail took (the levels left out, the finest level's start and the
/// output), at most half of the budget; one-shot solves and warm frames neither
/// use nor change that figure.
TEST(Solver, AStreamColdStartSetsAsideTheLastOnesTail) {
  NormalMap gt;
  FusionProblem problem = noisyTwoPlanes(64, 48, 0.5, &gt);
  SolverSettings settings = twoHundredIterationsUnderTwoBudgets();
  Solver solver(settings);
  SolveReport report;
  SolverState first;
  solver.solve(problem, first, true, report);
  ASSERT_TRUE(report.cold_start_budget_used);
  EXPECT_EQ(report.cold_start_tail_reserved_seconds, 0.0);  // none yet
  EXPECT_GT(report.cold_start_tail_seconds, 0.0);
  const double first_tail = report.cold_start_tail_seconds;
  SolverState second;
  solver.solve(problem, second, true, report);
  EXPECT_EQ(report.cold_start_tail_reserved_seconds, first_tail);
  const double second_tail = report.cold_start_tail_seconds;
  EXPECT_GT(second_tail, 0.0);
  // A warm frame and a one-shot solve: no cold-start budget, no tail.
  solver.solve(problem, second, true, report);
  EXPECT_TRUE(report.warm_started);
  EXPECT_EQ(report.cold_start_tail_reserved_seconds, 0.0);
  EXPECT_EQ(report.cold_start_tail_seconds, 0.0);
  SolverState one_shot;
  solver.solve(problem, one_shot, false, report);
  EXPECT_FALSE(report.cold_start_budget_used);
  EXPECT_EQ(report.cold_start_tail_seconds, 0.0);
  SolverState third;
  solver.solve(problem, third, true, report);
  EXPECT_EQ(report.cold_start_tail_reserved_seconds, second_tail);
  // At most half of the budget.
  settings.cold_start_budget_ms = 1e-9;
  solver.setSettings(settings);
  SolverState fourth;
  solver.solve(problem, fourth, true, report);
  EXPECT_DOUBLE_EQ(report.cold_start_tail_reserved_seconds, 0.5e-12);
  expectUnit(fourth.normals);
}

/// A stream's cold start that its budget cuts short hands on a converging
/// state; one whose budget ran out before its finer levels began hands on
/// the upsampled coarsest result (no finest iterations, no energies) rather
/// than overrunning the frame with the finest level's first chunk. The warm
/// frame after it iterates the whole image (no local refinement) and, with
/// the tolerance met, hands on a converged one.
TEST(Solver, ABudgetCutColdStartGoesOnConvergingInTheWarmFrames) {
  NormalMap gt;
  FusionProblem problem = noisyTwoPlanes(64, 48, 0.5, &gt);
  SolverSettings settings = twoHundredIterationsUnderTwoBudgets();
  Solver solver(settings);
  SolveReport report;
  SolverState stream;
  spendTheFrameBudget(solver);
  solver.solve(problem, stream, true, report);
  EXPECT_TRUE(report.budget_exhausted);
  EXPECT_TRUE(stream.converging);
  EXPECT_TRUE(report.still_converging);
  ASSERT_GE(report.pyramid_levels, 2);
  EXPECT_GT(report.coarse_inner_iterations, 0);
  EXPECT_EQ(report.inner_iterations, 0);
  EXPECT_TRUE(std::isnan(report.final_energy));
  expectUnit(stream.normals);
  // The coarsest level's smoothing, upsampled: closer to the truth than the
  // noisy input.
  EXPECT_GT(psnr(stream.normals, gt), psnr(problem.inputs[0].normals, gt));
  // A warm frame with time to spare: whole-image steps until the tolerance.
  settings.relative_tolerance = 1e-2;
  solver.setSettings(settings);
  solver.solve(problem, stream, true, report);
  EXPECT_TRUE(report.warm_started);
  EXPECT_GT(report.inner_iterations, 0);
  EXPECT_EQ(report.refine_iterations, 0);
  EXPECT_TRUE(report.converged);
  EXPECT_FALSE(stream.converging);
  // Converged: the next warm frame refines locally, as live frames do.
  spendTheFrameBudget(solver);
  solver.solve(problem, stream, true, report);
  EXPECT_EQ(report.inner_iterations, 0);
}

}  // namespace
}  // namespace normal_fusion
