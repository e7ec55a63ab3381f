// Typed errors of the solver: InputError for bad problems, ParameterError for
// bad settings (named), settings kept when new ones are refused.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <string>

#include "normal_fusion/errors.h"
#include "normal_fusion/solver.h"
#include "solver_test_util.h"

namespace normal_fusion {
namespace {

using test::kNaN;
using test::noisyTwoPlanes;

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
  s.warm_face_steps = -1;
  expect_bad(s, "warm_face_steps");
  s = SolverSettings();
  s.warm_face_degrees = 0.0;
  expect_bad(s, "warm_face_degrees");
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

}  // namespace
}  // namespace normal_fusion
