// The solver's settings table (detail/settings_table.def): SolverSettings'
// defaults, validate()'s ranges, the enums' names and the solver table of
// docs/parameters.md all agree with it, line by line.
#include <gtest/gtest.h>

#include <algorithm>
#include <climits>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <map>
#include <sstream>
#include <string>

#include "normal_fusion/errors.h"
#include "normal_fusion/settings.h"
#include "normal_fusion/settings_table.h"
#include "normal_fusion/solver_options.h"

namespace normal_fusion {
namespace {

/// Every setting of `s` as the table types it, by name.
std::map<std::string, SettingValue> valuesOf(const SolverSettings& s) {
  std::map<std::string, SettingValue> values;
#define NF_DOUBLE(name, field, def, lo, hi, when, meaning, old) \
  values[#name] = s.field;
#define NF_DOUBLE_ABOVE NF_DOUBLE
#define NF_INT(name, field, def, lo, hi, when, meaning, old) \
  values[#name] = s.field;
#define NF_BOOL(name, field, def, when, meaning, old) values[#name] = s.field;
#define NF_ENUM(name, field, def, Type, names, when, meaning, old) \
  values[#name] = toString(s.field);
#include "normal_fusion/detail/settings_table.def"
#undef NF_DOUBLE_ABOVE
  return values;
}

TEST(SettingsTable, SolverSettingsStartFromTheTableDefaults) {
  const auto values = valuesOf(SolverSettings());
  ASSERT_EQ(values.size(), solverSettingDescriptors().size());
  for (const SettingDescriptor& d : solverSettingDescriptors()) {
    ASSERT_EQ(values.count(d.name), 1u) << d.name;
    EXPECT_EQ(values.at(d.name), d.default_value) << d.name;
  }
  EXPECT_NO_THROW(SolverSettings().validate());
}

/// The value as an option's text, exactly.
std::string exactText(double value) {
  std::ostringstream out;
  out.precision(17);
  out << value;
  return out.str();
}

/// validate() on the defaults with one setting changed through its option;
/// tau and sigma are set together (the pair rule).
std::string validateWith(const SettingDescriptor& d, double value) {
  SolverSettings s;
  cli::applySolverOption(d.cliOption(), exactText(value), s);
  if (d.name == "tau") s.sigma = value > 0.0 ? 1e-3 : 0.0;
  if (d.name == "sigma") s.tau = value > 0.0 ? 1e-3 : 0.0;
  try {
    s.validate();
  } catch (const ParameterError& e) {
    return e.what();
  }
  return "";
}

TEST(SettingsTable, ValidateRefusesJustOutsideEveryRange) {
  for (const SettingDescriptor& d : solverSettingDescriptors()) {
    if (!d.numeric()) continue;
    SCOPED_TRACE(d.name);
    const bool integer = d.type == SettingType::kInt;
    // Doubles: a millionth of the bound outside (1e-9 at 0).
    const double below = d.min_exclusive ? d.min
                         : integer
                             ? d.min - 1
                             : d.min - std::max(1e-9, std::abs(d.min) * 1e-6);
    EXPECT_NE(validateWith(d, below).find(d.field), std::string::npos)
        << below << " accepted";
    if (!(integer && d.max == INT_MAX)) {
      const double above = integer ? d.max + 1 : d.max * (1.0 + 1e-6);
      EXPECT_NE(validateWith(d, above).find(d.field), std::string::npos)
          << above << " accepted";
    }
    if (!d.min_exclusive) {
      EXPECT_EQ(validateWith(d, d.min), "") << d.min;
    }
    EXPECT_EQ(validateWith(d, d.max), "") << d.max;
  }
}

TEST(SettingsTable, EnumValuesAreTheNamesTheirParsersTake) {
  std::map<std::string, std::string> refusals;
#define NF_ENUM(name, field, def, Type, names, when, meaning, old) \
  try {                                                            \
    parse##Type("?");                                              \
  } catch (const ParameterError& e) {                              \
    refusals[#name] = e.what();                                    \
  }                                                                \
  for (const std::string& value : descriptor(#name).values) {      \
    EXPECT_EQ(toString(parse##Type(value)), value) << #name;       \
  }
  const auto descriptor = [](const std::string& name) {
    for (const SettingDescriptor& d : solverSettingDescriptors()) {
      if (d.name == name) return d;
    }
    ADD_FAILURE() << "no setting " << name;
    return SettingDescriptor();
  };
#include "normal_fusion/detail/settings_table.def"
  for (const SettingDescriptor& d : solverSettingDescriptors()) {
    if (d.type != SettingType::kEnum) continue;
    std::string names;
    for (const std::string& v : d.values) names += " " + v;
    // "...: expected one of l2 squared_l2": the table lists every name.
    const std::string& refusal = refusals[d.name];
    EXPECT_EQ(refusal.substr(refusal.size() - names.size()), names)
        << d.name << ": " << refusal;
  }
}

/// The lines between the markers of one generated table.
std::string generatedSection(const std::string& doc, const std::string& begin,
                             const std::string& end) {
  const std::size_t from = doc.find(begin);
  const std::size_t to = doc.find(end);
  if (from == std::string::npos || to == std::string::npos || to < from) {
    return "(markers missing)";
  }
  const std::size_t start = doc.find('\n', from) + 1;
  return doc.substr(start, to - start);
}

TEST(SettingsTable, DocsListTheTable) {
  const std::string path = "docs/parameters.md";
  const std::string begin = "<!-- BEGIN GENERATED solver settings table";
  const std::string end = "<!-- END GENERATED solver settings table";
  std::ifstream in(path);
  ASSERT_TRUE(in) << path << " (run from the source directory)";
  std::stringstream text;
  text << in.rdbuf();
  std::string doc = text.str();
  std::ostringstream expected;
  printSettingsMarkdown(expected, solverSettingDescriptors(), true);
  const char* write = std::getenv("NF_WRITE_PARAMETERS_MD");
  if (write != nullptr && std::string(write) == "1") {
    const std::size_t start = doc.find('\n', doc.find(begin)) + 1;
    doc.replace(start, doc.find(end) - start, expected.str());
    std::ofstream(path) << doc;
  }
  EXPECT_EQ(generatedSection(doc, begin, end), expected.str())
      << path << " differs from the table: regenerate it (docs/development.md)";
}

}  // namespace
}  // namespace normal_fusion
