// The duals carried through the pyramid (prolong_duals): with inputs that
// have holes (the pyramid is automatic then) the carried duals keep the outer
// energy monotone, start the finest level nearer the optimum than duals
// restarted at zero, and leave a result of the same accuracy.
#include <gtest/gtest.h>

#include <cstddef>
#include <cstdint>
#include <random>

#include "normal_fusion/metrics.h"
#include "normal_fusion/solver.h"
#include "solver_test_util.h"
#include "test_util.h"

namespace normal_fusion {
namespace {

/// Two noisy planes with a quarter of the pixels missing in blobs of 4x4.
FusionProblem problemWithHoles(NormalMap* gt) {
  FusionProblem problem = test::noisyTwoPlanes(96, 72, 0.4, gt);
  NormalMap& n = problem.inputs[0].normals;
  std::mt19937 rng(7);
  std::uniform_int_distribution<int> coin(0, 3);
  for (int by = 0; by < n.height(); by += 4) {
    for (int bx = 0; bx < n.width(); bx += 4) {
      if (coin(rng) != 0) continue;
      for (int y = by; y < by + 4 && y < n.height(); ++y) {
        for (int x = bx; x < bx + 4 && x < n.width(); ++x) {
          for (int c = 0; c < 3; ++c) n.at(c, y, x) = test::kNaN;
        }
      }
    }
  }
  return problem;
}

SolveReport solveWith(const FusionProblem& problem, bool prolong,
                      int max_iterations, NormalMap* out) {
  SolverSettings s;
  s.prolong_duals = prolong;
  s.max_total_inner_iterations = max_iterations;
  s.num_threads = 1;
  SolveReport report;
  *out = Solver(s).solve(problem, &report);
  return report;
}

TEST(SolverProlongDuals, MonotoneNearerTheOptimumAndAsAccurate) {
  NormalMap gt;
  const FusionProblem problem = problemWithHoles(&gt);
  NormalMap on, off;
  const SolveReport r_on = solveWith(problem, true, 1000, &on);
  const SolveReport r_off = solveWith(problem, false, 1000, &off);
  ASSERT_GT(r_on.pyramid_levels, 1) << "the pyramid did not run";
  EXPECT_EQ(r_on.pyramid_levels, r_off.pyramid_levels);
  for (std::size_t k = 1; k < r_on.energies.size(); ++k) {
    EXPECT_LE(r_on.energies[k], r_on.energies[k - 1]) << "outer step " << k;
  }
  // At the finest level, its start and its first outer step: the carried
  // duals (through every coarser level too) are further along.
  ASSERT_GE(r_on.energies.size(), 2u);
  ASSERT_GE(r_off.energies.size(), 2u);
  EXPECT_LT(r_on.energies[0], r_off.energies[0]);
  EXPECT_LT(r_on.energies[1], r_off.energies[1]);
  const double psnr_on = psnr(on, gt);
  const double psnr_off = psnr(off, gt);
  EXPECT_GT(psnr_on, psnr_off - 0.2);
  test::expectUnit(on);
}

}  // namespace
}  // namespace normal_fusion
