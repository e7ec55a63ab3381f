// The tools' shared solver options: every option reaches its setting, bad
// values are refused with the option's name.
#include <gtest/gtest.h>

#include <algorithm>
#include <sstream>
#include <string>
#include <vector>

#include "normal_fusion/errors.h"
#include "normal_fusion/settings_table.h"
#include "normal_fusion/solver_options.h"

namespace normal_fusion {
namespace {

TEST(SolverOptions, EachOptionSetsItsField) {
  SolverSettings s;
  cli::applySolverOption("--lambda", "2.5", s);
  cli::applySolverOption("--huber-eps", "0.01", s);
  cli::applySolverOption("--penalty", "squared_l2", s);
  cli::applySolverOption("--visibility", "hard", s);
  cli::applySolverOption("--edge-enabled", "off", s);
  cli::applySolverOption("--edge-gradient", "sobel", s);
  cli::applySolverOption("--edge-color-mode", "luminance", s);
  cli::applySolverOption("--edge-function", "rational", s);
  cli::applySolverOption("--edge-alpha", "7", s);
  cli::applySolverOption("--edge-beta", "2", s);
  cli::applySolverOption("--edge-w-min", "0.2", s);
  cli::applySolverOption("--edge-smoothing-sigma", "0.8", s);
  cli::applySolverOption("--data-eps", "0.05", s);
  cli::applySolverOption("--data-eps-local", "1.5", s);
  cli::applySolverOption("--density-power", "0.5", s);
  cli::applySolverOption("--local-radius", "2", s);
  cli::applySolverOption("--hole-link-weight", "0.75", s);
  cli::applySolverOption("--inner-iterations", "30", s);
  cli::applySolverOption("--max-outer-iterations", "9", s);
  cli::applySolverOption("--max-total-inner-iterations", "333", s);
  cli::applySolverOption("--relative-tolerance", "1e-5", s);
  cli::applySolverOption("--time-budget-ms", "33", s);
  cli::applySolverOption("--pyramid-levels", "3", s);
  cli::applySolverOption("--preconditioning", "off", s);
  cli::applySolverOption("--num-threads", "1", s);
  cli::applySolverOption("--adaptive-refine-threads", "off", s);
  cli::applySolverOption("--cold-start-budget-ms", "250", s);
  cli::applySolverOption("--backend", "reference", s);
  cli::applySolverOption("--tau", "0.1", s);
  cli::applySolverOption("--sigma", "0.2", s);
  cli::applySolverOption("--step-balance", "0.5", s);
  EXPECT_EQ(s.lambda, 2.5);
  EXPECT_EQ(s.huber_eps, 0.01);
  EXPECT_EQ(s.penalty, DataPenalty::kSquaredL2);
  EXPECT_EQ(s.visibility, VisibilityMode::kHard);
  EXPECT_FALSE(s.edges.enabled);
  EXPECT_EQ(s.edges.gradient, EdgeGradient::kSobel);
  EXPECT_EQ(s.edges.color_mode, EdgeColorMode::kLuminance);
  EXPECT_EQ(s.edges.function, EdgeWeightFunction::kRational);
  EXPECT_EQ(s.edges.alpha, 7.0);
  EXPECT_EQ(s.edges.beta, 2.0);
  EXPECT_EQ(s.edges.w_min, 0.2);
  EXPECT_EQ(s.edges.smoothing_sigma, 0.8);
  EXPECT_EQ(s.data_eps, 0.05);
  EXPECT_EQ(s.data_eps_local, 1.5);
  EXPECT_EQ(s.density_power, 0.5);
  EXPECT_EQ(s.local_radius, 2);
  EXPECT_EQ(s.hole_link_weight, 0.75);
  EXPECT_EQ(s.inner_iterations, 30);
  EXPECT_EQ(s.max_outer_iterations, 9);
  EXPECT_EQ(s.max_total_inner_iterations, 333);
  EXPECT_EQ(s.relative_tolerance, 1e-5);
  EXPECT_EQ(s.time_budget_ms, 33.0);
  EXPECT_EQ(s.cold_start_budget_ms, 250.0);
  EXPECT_EQ(s.pyramid_levels, 3);
  EXPECT_FALSE(s.preconditioning);
  EXPECT_EQ(s.num_threads, 1);
  EXPECT_FALSE(s.adaptive_refine_threads);
  EXPECT_EQ(s.backend, SolverBackend::kReference);
  EXPECT_EQ(s.tau, 0.1);
  EXPECT_EQ(s.sigma, 0.2);
  EXPECT_EQ(s.step_balance, 0.5);
  // The help text names every option with its default.
  std::ostringstream help;
  cli::printSolverOptions(help, SolverSettings());
  for (const char* name :
       {"--lambda", "--huber-eps", "--edge-gradient", "--preconditioning",
        "--backend", "--max-total-inner-iterations", "--data-eps",
        "--data-eps-local", "--density-power", "--local-radius",
        "--hole-link-weight", "--adaptive-refine-threads",
        "--cold-start-budget-ms", "--step-balance"}) {
    EXPECT_TRUE(cli::isSolverOption(name)) << name;
    EXPECT_NE(help.str().find(name), std::string::npos) << name;
  }
}

TEST(SolverOptions, BadValuesNameTheOption) {
  SolverSettings s;
  auto expect_refused = [&](const char* option, const char* value) {
    try {
      cli::applySolverOption(option, value, s);
      ADD_FAILURE() << option << " " << value << " was accepted";
    } catch (const ParameterError& e) {
      EXPECT_NE(std::string(e.what()).find(option), std::string::npos)
          << e.what();
    }
  };
  expect_refused("--lambda", "abc");
  expect_refused("--lambda", "1.5x");
  expect_refused("--lambda", "nan");
  expect_refused("--inner-iterations", "2.5");
  expect_refused("--visibility", "sometimes");
  expect_refused("--preconditioning", "maybe");
  EXPECT_FALSE(cli::isSolverOption("--output"));
  EXPECT_THROW(cli::applySolverOption("--output", "x", s), ParameterError);
}

TEST(SolverOptions, EverySettingHasTheOptionOfItsName) {
  for (const SettingDescriptor& d : solverSettingDescriptors()) {
    std::string expected = "--" + d.name;
    std::replace(expected.begin(), expected.end(), '_', '-');
    EXPECT_EQ(d.cliOption(), expected);
    EXPECT_TRUE(cli::isSolverOption(expected)) << expected;
    EXPECT_EQ(cli::replacementOption(expected), "") << expected;
    if (!d.old_option.empty()) {
      EXPECT_TRUE(cli::isSolverOption(d.old_option)) << d.old_option;
      EXPECT_EQ(cli::replacementOption(d.old_option), expected);
    }
  }
}

TEST(SolverOptions, AnOldSpellingStillWorksAndNamesTheNewOne) {
  SolverSettings s;
  std::ostringstream warnings;
  cli::applySolverOption("--eps", "0.01", s, warnings);
  cli::applySolverOption("--edges", "off", s, warnings);
  EXPECT_EQ(s.huber_eps, 0.01);
  EXPECT_FALSE(s.edges.enabled);
  EXPECT_EQ(warnings.str(),
            "warning: --eps is deprecated; use --huber-eps\n"
            "warning: --edges is deprecated; use --edge-enabled\n");
  warnings.str("");
  cli::applySolverOption("--huber-eps", "0.02", s, warnings);
  EXPECT_EQ(s.huber_eps, 0.02);
  EXPECT_TRUE(warnings.str().empty());
}

TEST(ArgumentCursor, SplitsInlineValuesAndTakesTheNextArgument) {
  std::vector<std::string> words = {"tool",    "--lambda=0.3", "--output",
                                    "out.exr", "--help",       "--x=a=b"};
  std::vector<char*> argv;
  for (std::string& w : words) argv.push_back(&w[0]);
  cli::ArgumentCursor cursor(static_cast<int>(argv.size()), argv.data());
  ASSERT_TRUE(cursor.next());
  EXPECT_EQ(cursor.option(), "--lambda");
  EXPECT_THROW(cursor.expectNoValue(), cli::UsageError);
  EXPECT_EQ(cursor.value(), "0.3");
  ASSERT_TRUE(cursor.next());
  EXPECT_EQ(cursor.option(), "--output");
  EXPECT_NO_THROW(cursor.expectNoValue());
  EXPECT_EQ(cursor.value(), "out.exr");
  ASSERT_TRUE(cursor.next());
  EXPECT_EQ(cursor.option(), "--help");
  ASSERT_TRUE(cursor.next());
  EXPECT_EQ(cursor.option(), "--x");  // only the first '=' splits
  EXPECT_EQ(cursor.value(), "a=b");
  EXPECT_FALSE(cursor.next());
}

TEST(ArgumentCursor, RefusesPositionalArgumentsAndMissingValues) {
  std::vector<std::string> words = {"tool", "stray", "--output"};
  std::vector<char*> argv;
  for (std::string& w : words) argv.push_back(&w[0]);
  cli::ArgumentCursor cursor(static_cast<int>(argv.size()), argv.data());
  try {
    cursor.next();
    FAIL() << "a positional argument was accepted";
  } catch (const cli::UsageError& e) {
    EXPECT_NE(std::string(e.what()).find("'stray'"), std::string::npos);
  }
  ASSERT_TRUE(cursor.next());
  try {
    cursor.value();
    FAIL() << "a missing value was accepted";
  } catch (const cli::UsageError& e) {
    EXPECT_EQ(std::string(e.what()), "--output needs a value");
  }
}

}  // namespace
}  // namespace normal_fusion
