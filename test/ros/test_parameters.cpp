// The ROS parameters of the node (no master needed): the settings tables'
// names, defaults and ranges as settingsFromParameters reads them, the
// refusal of invalid values, dynamic_reconfigure's .cfg, config/*.yaml and
// the node's table of docs/parameters.md.
#include <gtest/gtest.h>
#include <normal_fusion/NormalFusionConfig.h>

#include <algorithm>
#include <boost/any.hpp>
#include <climits>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <limits>
#include <map>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "normal_fusion/errors.h"
#include "normal_fusion/ros/parameters.h"
#include "normal_fusion/settings_table.h"

namespace normal_fusion {
namespace node {
namespace {

bool mentions(const std::vector<std::string>& warnings,
              const std::string& word) {
  return std::any_of(
      warnings.begin(), warnings.end(),
      [&](const std::string& w) { return w.find(word) != std::string::npos; });
}

/// Every descriptor of both tables.
std::vector<SettingDescriptor> allDescriptors() {
  std::vector<SettingDescriptor> all = solverSettingDescriptors();
  const auto& node = nodeSettingDescriptors();
  all.insert(all.end(), node.begin(), node.end());
  return all;
}

/// The parameter names of a descriptor (name_0 .. name_7 per input).
std::vector<std::string> parameterNames(const SettingDescriptor& d) {
  if (!d.per_input) return {d.name};
  std::vector<std::string> names;
  for (int i = 0; i < kMaxInputs; ++i) {
    names.push_back(d.name + "_" + std::to_string(i));
  }
  return names;
}

TEST(Parameters, EveryTableLineIsAParameterWithTheTableDefault) {
  const ParameterMap defaults = parametersFromSettings(NodeSettings());
  std::set<std::string> named;
  for (const SettingDescriptor& d : allDescriptors()) {
    for (const std::string& name : parameterNames(d)) {
      named.insert(name);
      ASSERT_EQ(defaults.count(name), 1u) << name;
      EXPECT_EQ(defaults.at(name), d.default_value) << name;
    }
  }
  for (const auto& entry : defaults) {
    EXPECT_EQ(named.count(entry.first), 1u)
        << entry.first << " is in no settings table";
  }
  // Orientation: the default's name parses to the default matrix.
  EXPECT_EQ(Orientation::fromString(node_default::orientation).M,
            InputSettings().orientation.M);
  EXPECT_EQ(NodeSettings().temporal.frames, TemporalSettings().frames);
  EXPECT_EQ(NodeSettings().temporal.gate_degrees,
            TemporalSettings().gate_degrees);
}

TEST(Parameters, ValuesJustOutsideEveryRangeAreRefusedAndInsideKept) {
  const NodeSettings defaults;
  const ParameterMap in_use = parametersFromSettings(defaults);
  const auto read = [&](const std::string& name, double value, bool integer) {
    ParameterMap params = in_use;
    params[name] = integer ? ParameterValue(static_cast<int>(value))
                           : ParameterValue(value);
    std::vector<std::string> warnings;
    const NodeSettings s = settingsFromParameters(params, &warnings, defaults);
    return std::make_pair(parametersFromSettings(s), warnings);
  };
  for (const SettingDescriptor& d : allDescriptors()) {
    if (!d.numeric()) continue;
    const bool integer = d.type == SettingType::kInt;
    // Doubles: a millionth of the bound outside (1e-9 at 0).
    std::vector<double> outside = {
        d.min_exclusive ? d.min
        : integer       ? d.min - 1
                        : d.min - std::max(1e-9, std::abs(d.min) * 1e-6)};
    if (!(integer && d.max == INT_MAX)) {
      outside.push_back(integer ? d.max + 1 : d.max * (1.0 + 1e-6));
    }
    for (const std::string& name : parameterNames(d)) {
      for (double value : outside) {
        SCOPED_TRACE(name + " = " + std::to_string(value));
        const auto [used, warnings] = read(name, value, integer);
        EXPECT_EQ(used, in_use);
        ASSERT_EQ(warnings.size(), 1u);
        EXPECT_TRUE(mentions(warnings, "'" + name + "'")) << warnings[0];
      }
      // The bounds themselves are accepted (tau and sigma only in pairs).
      if (name == "tau" || name == "sigma") continue;
      for (double value : {d.min_exclusive ? d.max : d.min, d.max}) {
        SCOPED_TRACE(name + " = " + std::to_string(value));
        const auto [used, warnings] = read(name, value, integer);
        EXPECT_TRUE(warnings.empty()) << warnings[0];
      }
    }
  }
}

TEST(Parameters, RangesAndRunTimeChangesAreTheTables) {
  std::map<std::string, ParameterRange> ranges;
  for (const ParameterRange& r : numericParameterRanges()) ranges[r.name] = r;
  std::size_t numeric = 0;
  for (const SettingDescriptor& d : allDescriptors()) {
    for (const std::string& name : parameterNames(d)) {
      EXPECT_EQ(isDynamicParameter(name), d.dynamic) << name;
      if (!d.numeric()) continue;
      ++numeric;
      ASSERT_EQ(ranges.count(name), 1u) << name;
      EXPECT_EQ(ranges[name].max, d.max) << name;
      const double lo =
          d.min_exclusive ? std::nextafter(d.min, HUGE_VAL) : d.min;
      EXPECT_EQ(ranges[name].min, lo) << name;
    }
  }
  EXPECT_EQ(ranges.size(), numeric);
}

TEST(Parameters, DynamicReconfigureDefaultsAreTheTables) {
  using Config = normal_fusion::NormalFusionConfig;
  const Config defaults = Config::__getDefault__();
  const ParameterMap table = parametersFromSettings(NodeSettings());
  int checked = 0;
  for (const auto& d : Config::__getParamDescriptions__()) {
    boost::any value;
    d->getValue(defaults, value);
    ASSERT_EQ(table.count(d->name), 1u) << d->name;
    const ParameterValue& expected = table.at(d->name);
    if (d->type == "double") {
      EXPECT_EQ(ParameterValue(boost::any_cast<double>(value)), expected);
    } else if (d->type == "int") {
      EXPECT_EQ(ParameterValue(boost::any_cast<int>(value)), expected);
    } else if (d->type == "bool") {
      EXPECT_EQ(ParameterValue(boost::any_cast<bool>(value)), expected);
    } else {
      EXPECT_EQ(ParameterValue(boost::any_cast<std::string>(value)), expected);
    }
    ++checked;
  }
  EXPECT_GT(checked, 0);
}

TEST(Parameters, ConfigFilesHoldOnlyKnownValuesThatDifferFromTheDefaults) {
  const ParameterMap defaults = parametersFromSettings(NodeSettings());
  for (const char* file : {"normal_fusion.yaml", "live.yaml", "demo.yaml"}) {
    SCOPED_TRACE(file);
    std::vector<std::string> warnings;
    ParameterMap params = parametersFromYamlFile(
        std::string(NF_SOURCE_DIR "/config/") + file, &warnings);
    EXPECT_TRUE(warnings.empty());
    for (const auto& entry : params) {
      ASSERT_EQ(defaults.count(entry.first), 1u)
          << "unknown parameter " << entry.first;
      ParameterValue value = entry.second;
      // YAML writes 1 as an int: compare as the code types.
      if (std::holds_alternative<double>(defaults.at(entry.first)) &&
          std::holds_alternative<int>(value)) {
        value = static_cast<double>(std::get<int>(value));
      }
      EXPECT_NE(value, defaults.at(entry.first))
          << entry.first << " repeats the default (docs/parameters.md)";
    }
    // And read through the one function: no correction needed.
    settingsFromParameters(params, &warnings);
    EXPECT_TRUE(warnings.empty()) << warnings.front();
  }
}

TEST(Parameters, DocsListTheNodeTable) {
  const std::string path = NF_SOURCE_DIR "/docs/parameters.md";
  const std::string begin = "<!-- BEGIN GENERATED node settings table";
  const std::string end = "<!-- END GENERATED node settings table";
  std::ifstream in(path);
  ASSERT_TRUE(in) << path;
  std::stringstream text;
  text << in.rdbuf();
  std::string doc = text.str();
  std::ostringstream expected;
  printSettingsMarkdown(expected, nodeSettingDescriptors(), false);
  const std::size_t from = doc.find(begin), to = doc.find(end);
  ASSERT_TRUE(from != std::string::npos && to != std::string::npos && from < to)
      << path << " lacks the markers of the node table";
  const std::size_t start = doc.find('\n', from) + 1;
  const char* write = std::getenv("NF_WRITE_PARAMETERS_MD");
  if (write != nullptr && std::string(write) == "1") {
    doc.replace(start, to - start, expected.str());
    std::ofstream(path) << doc;
  }
  EXPECT_EQ(doc.substr(start, doc.find(end) - start), expected.str())
      << path << " differs from the table: regenerate it (docs/development.md)";
}

TEST(Parameters, RoundTripKeepsEveryValue) {
  NodeSettings settings;
  settings.solver.lambda = 2.5;
  settings.solver.edges.color_mode = EdgeColorMode::kLuminance;
  settings.solver.backend = SolverBackend::kReference;
  settings.num_inputs = 3;
  settings.inputs[2].weight = 4.0;
  settings.inputs[2].orientation_name = "opengl";
  settings.inputs[1].use_confidence = true;
  settings.fixed_frame = "odom";
  settings.resampling = Resampling::kNearest;
  ParameterMap params = parametersFromSettings(settings);
  std::vector<std::string> warnings;
  const NodeSettings back = settingsFromParameters(params, &warnings);
  EXPECT_TRUE(warnings.empty());
  EXPECT_EQ(parametersFromSettings(back), parametersFromSettings(settings));
  EXPECT_EQ(back.inputs[2].orientation.M, Orientation::opengl().M);
}

TEST(Parameters, InvalidValuesAreRefusedWithAWarningNamingThem) {
  ParameterMap params;
  params["lambda"] = -1.0;
  params["edge_w_min"] = 2.0;
  params["inner_iterations"] = 2.5;
  params["max_outer_iterations"] = std::string("many");
  params["penalty"] = std::string("cubic");
  params["orientation_1"] = std::string("sideways");
  params["num_inputs"] = 20;
  params["weight_0"] = std::numeric_limits<double>::quiet_NaN();
  params["warm_start"] = 1;
  params["no_such_parameter"] = 3;
  std::vector<std::string> warnings;
  const NodeSettings s = settingsFromParameters(params, &warnings);
  const NodeSettings defaults;
  EXPECT_EQ(s.solver.lambda, defaults.solver.lambda);  // > 0 required
  EXPECT_EQ(std::get<double>(params["lambda"]), defaults.solver.lambda);
  // Out of range: refused, not clamped (a bound may mean "off").
  EXPECT_EQ(s.solver.edges.w_min, defaults.solver.edges.w_min);
  EXPECT_EQ(s.solver.inner_iterations, 3);  // rounded
  EXPECT_EQ(s.solver.max_outer_iterations,
            defaults.solver.max_outer_iterations);
  EXPECT_EQ(s.solver.penalty, defaults.solver.penalty);
  EXPECT_EQ(s.inputs[1].orientation.M, Orientation::optical().M);
  EXPECT_EQ(s.num_inputs, defaults.num_inputs);
  EXPECT_EQ(s.inputs[0].weight, defaults.inputs[0].weight);
  EXPECT_TRUE(s.warm_start);
  for (const char* name :
       {"'lambda'", "'edge_w_min'", "'inner_iterations'",
        "'max_outer_iterations'", "'penalty'", "'orientation_1'",
        "'num_inputs'", "'weight_0'", "'warm_start'", "'no_such_parameter'"}) {
    EXPECT_TRUE(mentions(warnings, name)) << "no warning names " << name;
  }
  EXPECT_EQ(warnings.size(), 10u);
  // The corrected map reads back without any warning.
  warnings.clear();
  params.erase("no_such_parameter");
  settingsFromParameters(params, &warnings);
  EXPECT_TRUE(warnings.empty()) << warnings.front();
}

TEST(Parameters, AnInvalidValueKeepsTheValueInUseAndEveryOtherSetting) {
  // The settings in use, as a live stream has them.
  NodeSettings current;
  current.solver.time_budget_ms = 33.0;
  current.solver.huber_eps = 0.01;
  current.solver.edges.smoothing_sigma = 1.0;
  current.inputs[0].weight = 2.0;
  current.fixed_frame = "odom";
  const ParameterMap in_use = parametersFromSettings(current);
  const double inf = std::numeric_limits<double>::infinity();
  const double nan = std::numeric_limits<double>::quiet_NaN();
  // Each of these, sent alone (as rqt_reconfigure does), is refused.
  const std::vector<std::pair<std::string, ParameterValue>> bad = {
      {"huber_eps", inf},
      {"edge_smoothing_sigma", inf},
      {"edge_smoothing_sigma", 1e4},
      {"weight_0", inf},
      {"time_budget_ms", -1.0},
      {"time_budget_ms", nan},
      {"lambda", inf},
      {"edge_alpha", -inf},
      {"relative_tolerance", nan},
      {"max_interval", 1e9},
      {"inner_iterations", -5},
      {"temporal_gate_deg", 0.0},
  };
  for (const auto& [name, value] : bad) {
    ParameterMap params = in_use;
    params[name] = value;
    std::vector<std::string> warnings;
    const NodeSettings s = settingsFromParameters(params, &warnings, current);
    EXPECT_EQ(parametersFromSettings(s), in_use)
        << name << " = " << toString(value) << " changed the settings";
    EXPECT_EQ(params, in_use) << name << ": the map was not corrected";
    ASSERT_EQ(warnings.size(), 1u) << name;
    EXPECT_TRUE(mentions(warnings, "'" + name + "'")) << warnings.front();
  }
}

TEST(Parameters, StepSizesComeInPairsAndMeetTheStepCondition) {
  ParameterMap params{{"tau", 0.1}};
  std::vector<std::string> warnings;
  NodeSettings s = settingsFromParameters(params, &warnings);
  EXPECT_EQ(s.solver.tau, 0.0);
  EXPECT_EQ(s.solver.sigma, 0.0);
  EXPECT_TRUE(mentions(warnings, "'tau'"));
  params = {{"tau", 0.5}, {"sigma", 0.5}, {"num_inputs", 2}};
  warnings.clear();
  s = settingsFromParameters(params, &warnings);
  EXPECT_EQ(s.solver.tau, 0.0);  // 0.25 * 10 >= 1
  EXPECT_TRUE(mentions(warnings, "tau * sigma"));
  params = {{"tau", 0.2}, {"sigma", 0.2}, {"num_inputs", 2}};
  warnings.clear();
  s = settingsFromParameters(params, &warnings);
  EXPECT_EQ(s.solver.tau, 0.2);
  EXPECT_TRUE(warnings.empty());
}

TEST(Parameters, DynamicReconfigureListsExactlyTheDynamicParameters) {
  const auto& descriptions =
      normal_fusion::NormalFusionConfig::__getParamDescriptions__();
  std::map<std::string, std::string> cfg;
  for (const auto& d : descriptions) cfg[d->name] = d->type;
  const ParameterMap all = parametersFromSettings(NodeSettings());
  for (const auto& entry : all) {
    if (!isDynamicParameter(entry.first)) {
      EXPECT_EQ(cfg.count(entry.first), 0u) << entry.first;
      continue;
    }
    ASSERT_EQ(cfg.count(entry.first), 1u)
        << entry.first << " is missing from cfg/NormalFusion.cfg";
    const char* expected[] = {"bool", "int", "double", "str"};
    EXPECT_EQ(cfg[entry.first], expected[entry.second.index()]) << entry.first;
  }
  for (const auto& entry : cfg) {
    EXPECT_EQ(all.count(entry.first), 1u) << "cfg has unknown " << entry.first;
  }
}

}  // namespace
}  // namespace node
}  // namespace normal_fusion
