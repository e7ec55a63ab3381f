// The cold start from an edge-aware filter of the inputs
// (cold_filter_radius): on a noisy two-plane scene the filtered start is
// nearer the ground truth than the data start, unit and facing the camera,
// fills pixels without data from their neighbours, and the solve from it
// ends at the energy of the solve from the data.
#include <gtest/gtest.h>

#include <cmath>
#include <cstddef>

#include "normal_fusion/detail/solver_internal.h"
#include "normal_fusion/detail/solver_levels.h"
#include "normal_fusion/solver.h"
#include "solver_test_util.h"
#include "test_util.h"

namespace normal_fusion {
namespace {

TEST(ColdFilter, NearerTheTruthUnitAndFacingTheCamera) {
  NormalMap gt;
  const FusionProblem problem = test::twoPlanesTwoInputs(0.5, 0.3, &gt, 96, 72);
  SolverSettings settings;
  const internal::PreparedLevel level =
      internal::prepareFinest(problem, settings);
  PlanarImage from_data, filtered, scratch;
  internal::initializeCold(level, settings.visibility, from_data, 1);
  internal::initializeFiltered(level, settings.visibility, 4, scratch, filtered,
                               2);
  const double mse_data = test::meanSquaredError(from_data, gt);
  const double mse_filtered = test::meanSquaredError(filtered, gt);
  // The filter averages the noise of both inputs inside each plane and keeps
  // the crease, where the image has its edge.
  EXPECT_LT(mse_filtered, 0.1 * mse_data)
      << "data " << mse_data << ", filtered " << mse_filtered;
  test::expectUnit(filtered);
  for (int y = 0; y < level.height; ++y) {
    for (int x = 0; x < level.width; ++x) {
      float r[3];
      level.ray(x, y, r);
      const float rn = r[0] * filtered.at(0, y, x) +
                       r[1] * filtered.at(1, y, x) +
                       r[2] * filtered.at(2, y, x);
      ASSERT_LE(rn, 1e-6f) << "pixel " << x << ", " << y;
    }
  }
}

TEST(ColdFilter, FillsPixelsWithoutDataFromTheirNeighbours) {
  NormalMap gt;
  FusionProblem problem = test::noisyTwoPlanes(64, 48, 0.3, &gt);
  // A 6x6 hole inside the left plane.
  for (int y = 20; y < 26; ++y) {
    for (int x = 10; x < 16; ++x) {
      for (int c = 0; c < 3; ++c)
        problem.inputs[0].normals.at(c, y, x) = test::kNaN;
    }
  }
  SolverSettings settings;
  const internal::PreparedLevel level =
      internal::prepareFinest(problem, settings);
  PlanarImage filtered, scratch;
  internal::initializeFiltered(level, settings.visibility, 4, scratch, filtered,
                               1);
  for (int y = 20; y < 26; ++y) {
    for (int x = 10; x < 16; ++x) {
      float dot = 0.0f;
      for (int c = 0; c < 3; ++c) dot += filtered.at(c, y, x) * gt.at(c, y, x);
      // Within 6 degrees of the plane's normal (the data start's -r/|r| is
      // 8 degrees or more off there).
      EXPECT_GT(dot, 0.995f) << "pixel " << x << ", " << y;
    }
  }
}

TEST(ColdFilter, SolveEndsAtTheEnergyOfTheDataStart) {
  NormalMap gt;
  const FusionProblem problem = test::twoPlanesTwoInputs(0.5, 0.3, &gt, 96, 72);
  SolverSettings settings = test::convergedSettings();
  settings.num_threads = 2;
  SolveReport from_data, filtered;
  Solver(settings).solve(problem, &from_data);
  settings.cold_filter_radius = 4;
  const NormalMap out = Solver(settings).solve(problem, &filtered);
  test::expectUnit(out);
  // It starts lower and ends within 1e-4 of the same energy.
  EXPECT_LT(filtered.initial_energy, from_data.initial_energy);
  EXPECT_NEAR(filtered.final_energy / from_data.final_energy, 1.0, 1e-4);
  for (std::size_t k = 1; k < filtered.energies.size(); ++k) {
    EXPECT_LE(filtered.energies[k], filtered.energies[k - 1]) << "step " << k;
  }
}

}  // namespace
}  // namespace normal_fusion
