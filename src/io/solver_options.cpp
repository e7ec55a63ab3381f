#include "normal_fusion/solver_options.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <map>
#include <sstream>
#include <stdexcept>
#include <vector>

#include "normal_fusion/errors.h"
#include "normal_fusion/settings_table.h"

namespace normal_fusion {
namespace cli {
namespace {

bool parseOnOff(const std::string& option, const std::string& text) {
  if (text == "on" || text == "true" || text == "1") return true;
  if (text == "off" || text == "false" || text == "0") return false;
  throw ParameterError(option + ": expected on or off, got '" + text + "'");
}

/// Runs a name parser of settings.h, naming the option in its error.
template <typename Parse>
auto parseName(const std::string& option, const std::string& text, Parse parse)
    -> decltype(parse(text)) {
  try {
    return parse(text);
  } catch (const ParameterError& e) {
    throw ParameterError(option + ": " + e.what());
  }
}

using Setter = std::function<void(const std::string& option,
                                  const std::string& value, SolverSettings&)>;

/// One option of the table: how it sets its field and how help shows it.
struct Option {
  const SettingDescriptor* descriptor;
  Setter set;
  std::function<std::string(const SolverSettings&)> show;
};

std::string onOff(bool value) { return value ? "on" : "off"; }

std::string numberText(double value) {
  std::ostringstream out;
  out << value;
  return out.str();
}

/// The table's settings by option, in the table's order.
std::vector<Option> makeOptions() {
  std::vector<Option> options;
  const auto& descriptors = solverSettingDescriptors();
  std::size_t next = 0;
  const auto add = [&](Setter set,
                       std::function<std::string(const SolverSettings&)> show) {
    options.push_back({&descriptors.at(next++), std::move(set), show});
  };
#define NF_DOUBLE(name, field, def, lo, hi, when, meaning, old)       \
  add([](auto& o, auto& v, auto& s) { s.field = parseDouble(o, v); }, \
      [](const SolverSettings& s) { return numberText(s.field); });
#define NF_DOUBLE_ABOVE NF_DOUBLE
#define NF_INT(name, field, def, lo, hi, when, meaning, old)       \
  add([](auto& o, auto& v, auto& s) { s.field = parseInt(o, v); }, \
      [](const SolverSettings& s) { return std::to_string(s.field); });
#define NF_BOOL(name, field, def, when, meaning, old)                \
  add([](auto& o, auto& v, auto& s) { s.field = parseOnOff(o, v); }, \
      [](const SolverSettings& s) { return onOff(s.field); });
#define NF_ENUM(name, field, def, Type, values, when, meaning, old) \
  add([](auto& o, auto& v,                                          \
         auto& s) { s.field = parseName(o, v, parse##Type); },      \
      [](const SolverSettings& s) { return toString(s.field); });
#include "normal_fusion/detail/settings_table.def"
#undef NF_DOUBLE_ABOVE
  return options;
}

const std::vector<Option>& options() {
  static const std::vector<Option> table = makeOptions();
  return table;
}

/// Every spelling, the deprecated ones too, to its option.
const std::map<std::string, const Option*>& optionsBySpelling() {
  static const std::map<std::string, const Option*> table = [] {
    std::map<std::string, const Option*> spellings;
    for (const Option& option : options()) {
      spellings[option.descriptor->cliOption()] = &option;
      if (!option.descriptor->old_option.empty()) {
        spellings[option.descriptor->old_option] = &option;
      }
    }
    return spellings;
  }();
  return table;
}

/// "X", "N", "on|off" or the values, for the help text.
std::string valueHint(const SettingDescriptor& d) {
  switch (d.type) {
    case SettingType::kBool:
      return "on|off";
    case SettingType::kInt:
      return "N";
    case SettingType::kEnum: {
      std::string hint;
      for (const std::string& v : d.values)
        hint += (hint.empty() ? "" : "|") + v;
      return hint;
    }
    default:
      return "X";
  }
}

}  // namespace

double parseDouble(const std::string& option, const std::string& text) {
  std::size_t used = 0;
  double value = 0.0;
  try {
    value = std::stod(text, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used == 0 || used != text.size() || !std::isfinite(value)) {
    throw ParameterError(option + ": expected a finite number, got '" + text +
                         "'");
  }
  return value;
}

int parseInt(const std::string& option, const std::string& text) {
  std::size_t used = 0;
  long value = 0;
  try {
    value = std::stol(text, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used == 0 || used != text.size() || value < -2147483647L ||
      value > 2147483647L) {
    throw ParameterError(option + ": expected an integer, got '" + text + "'");
  }
  return static_cast<int>(value);
}

bool isSolverOption(const std::string& option) {
  return optionsBySpelling().count(option) > 0;
}

std::string replacementOption(const std::string& option) {
  const auto it = optionsBySpelling().find(option);
  if (it == optionsBySpelling().end()) return "";
  const std::string current = it->second->descriptor->cliOption();
  return current == option ? "" : current;
}

void applySolverOption(const std::string& option, const std::string& value,
                       SolverSettings& settings, std::ostream& warnings) {
  const auto it = optionsBySpelling().find(option);
  if (it == optionsBySpelling().end()) {
    throw ParameterError("unknown solver option '" + option + "'");
  }
  const std::string current = replacementOption(option);
  if (!current.empty()) {
    warnings << "warning: " << option << " is deprecated; use " << current
             << "\n";
  }
  it->second->set(option, value, settings);
}

void printSolverOptions(std::ostream& out, const SolverSettings& defaults) {
  for (const Option& option : options()) {
    const SettingDescriptor& d = *option.descriptor;
    out << "  " << d.cliOption() << " " << valueHint(d) << "  ["
        << option.show(defaults) << "]";
    if (!d.old_option.empty()) out << "  (was " << d.old_option << ")";
    out << "\n      " << d.meaning;
    if (d.numeric()) out << "; " << d.rangeText();
    out << "\n";
  }
}

bool ArgumentCursor::next() {
  if (index_ + 1 >= argc_) return false;
  option_ = argv_[++index_];
  if (option_.rfind("--", 0) != 0) {
    throw UsageError("unexpected argument '" + option_ +
                     "' (options start with --; see --help)");
  }
  const std::size_t equals = option_.find('=');
  has_inline_value_ = equals != std::string::npos;
  inline_value_.clear();
  if (has_inline_value_) {
    inline_value_ = option_.substr(equals + 1);
    option_.resize(equals);
  }
  return true;
}

void ArgumentCursor::expectNoValue() const {
  if (has_inline_value_) throw UsageError(option_ + " takes no value");
}

std::string ArgumentCursor::value() {
  if (has_inline_value_) return inline_value_;
  if (index_ + 1 >= argc_) throw UsageError(option_ + " needs a value");
  return argv_[++index_];
}

}  // namespace cli
}  // namespace normal_fusion
