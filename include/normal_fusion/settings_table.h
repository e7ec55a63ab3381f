// The settings table as data: one descriptor per setting of the solver
// (detail/settings_table.def), from which the tools' options, the ROS
// parameters, dynamic_reconfigure's .cfg and docs/parameters.md are made.
#pragma once

#include <ostream>
#include <string>
#include <variant>
#include <vector>

// "when" of a table line: true for DYNAMIC (dynamic_reconfigure may change it).
#define NF_SETTING_IS_DYNAMIC_DYNAMIC true
#define NF_SETTING_IS_DYNAMIC_START false
#define NF_SETTING_IS_DYNAMIC(when) NF_SETTING_IS_DYNAMIC_##when

namespace normal_fusion {

/// One value as the parameter server types it (enums as their names).
using SettingValue = std::variant<bool, int, double, std::string>;

enum class SettingType { kBool, kInt, kDouble, kEnum, kString };

/// What the table declares about one setting.
struct SettingDescriptor {
  std::string name;   ///< ROS parameter name (per input: the stem, see below)
  std::string field;  ///< member path in its struct, e.g. "edges.w_min"
  std::string group;  ///< NF_GROUP above it
  SettingType type = SettingType::kDouble;
  SettingValue default_value;
  /// Numeric range, inclusive, except the lower bound when min_exclusive.
  double min = 0.0, max = 0.0;
  bool min_exclusive = false;
  std::vector<std::string> values;  ///< an enum's value names
  bool dynamic = true;              ///< dynamic_reconfigure may change it
  std::string meaning;              ///< one line
  std::string old_option;           ///< deprecated CLI spelling, empty if none
  /// Parameters name_0 .. name_{kMaxInputs-1}, one per input of the node.
  bool per_input = false;

  bool numeric() const {
    return type == SettingType::kInt || type == SettingType::kDouble;
  }
  /// The setting's CLI option: "--" + name with '_' -> '-'.
  std::string cliOption() const;
  /// True when `value` is inside the range (numbers only).
  bool inRange(double value) const;
  /// The range as text: "[0, 10]", "(0, 1e6]", ">= 1", or the values.
  std::string rangeText() const;
};

/// A descriptor from the arguments of a table line (values: the enum's
/// value names separated by spaces, else empty).
SettingDescriptor makeSettingDescriptor(
    const char* name, const char* field, const std::string& group,
    SettingType type, SettingValue default_value, double lo, double hi,
    bool lo_exclusive, const char* values, bool dynamic, const char* meaning,
    const char* old_option);

/// The solver's settings in the order of the table.
const std::vector<SettingDescriptor>& solverSettingDescriptors();

/// Numbers as the table and the docs write them: 0.5, 1e-4, 1e6, 12000000.
std::string settingNumberText(double value);
/// A value as the docs write it: 0.5, true, `l2`, "".
std::string settingValueText(const SettingValue& value);

/// The Markdown table of `settings` (docs/parameters.md); with_cli adds the
/// tools' option column.
void printSettingsMarkdown(std::ostream& out,
                           const std::vector<SettingDescriptor>& settings,
                           bool with_cli);

}  // namespace normal_fusion
