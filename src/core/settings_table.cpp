#include "normal_fusion/settings_table.h"

#include <climits>
#include <cmath>
#include <cstdio>
#include <sstream>

#include "normal_fusion/settings.h"

namespace normal_fusion {
namespace {

std::vector<std::string> splitWords(const std::string& text) {
  std::vector<std::string> words;
  std::istringstream in(text);
  for (std::string word; in >> word;) words.push_back(word);
  return words;
}

std::vector<SettingDescriptor> makeSolverDescriptors() {
  std::vector<SettingDescriptor> table;
  std::string group;
#define NF_GROUP(name) group = #name;
#define NF_DOUBLE(name, field, def, lo, hi, when, meaning, old)               \
  table.push_back(makeSettingDescriptor(                                      \
      #name, #field, group, SettingType::kDouble, double(def), lo, hi, false, \
      "", NF_SETTING_IS_DYNAMIC(when), meaning, old));
#define NF_DOUBLE_ABOVE(name, field, def, lo, hi, when, meaning, old)        \
  table.push_back(makeSettingDescriptor(                                     \
      #name, #field, group, SettingType::kDouble, double(def), lo, hi, true, \
      "", NF_SETTING_IS_DYNAMIC(when), meaning, old));
#define NF_INT(name, field, def, lo, hi, when, meaning, old)                \
  table.push_back(makeSettingDescriptor(                                    \
      #name, #field, group, SettingType::kInt, int(def), lo, hi, false, "", \
      NF_SETTING_IS_DYNAMIC(when), meaning, old));
#define NF_BOOL(name, field, def, when, meaning, old)                       \
  table.push_back(makeSettingDescriptor(                                    \
      #name, #field, group, SettingType::kBool, bool(def), 0, 0, false, "", \
      NF_SETTING_IS_DYNAMIC(when), meaning, old));
#define NF_ENUM(name, field, def, Type, values, when, meaning, old)        \
  table.push_back(makeSettingDescriptor(                                   \
      #name, #field, group, SettingType::kEnum, toString(Type::def), 0, 0, \
      false, values, NF_SETTING_IS_DYNAMIC(when), meaning, old));
#include "normal_fusion/detail/settings_table.def"
  return table;
}

}  // namespace

SettingDescriptor makeSettingDescriptor(
    const char* name, const char* field, const std::string& group,
    SettingType type, SettingValue default_value, double lo, double hi,
    bool lo_exclusive, const char* values, bool dynamic, const char* meaning,
    const char* old_option) {
  SettingDescriptor d;
  d.name = name;
  d.field = field;
  d.group = group;
  d.type = type;
  d.default_value = std::move(default_value);
  d.min = lo;
  d.max = hi;
  d.min_exclusive = lo_exclusive;
  d.values = splitWords(values);
  d.dynamic = dynamic;
  d.meaning = meaning;
  d.old_option = old_option;
  return d;
}

const std::vector<SettingDescriptor>& solverSettingDescriptors() {
  static const std::vector<SettingDescriptor> table = makeSolverDescriptors();
  return table;
}

std::string SettingDescriptor::cliOption() const {
  std::string option = "--" + name;
  for (char& c : option) {
    if (c == '_') c = '-';
  }
  return option;
}

bool SettingDescriptor::inRange(double value) const {
  if (!std::isfinite(value) || value > max) return false;
  return min_exclusive ? value > min : value >= min;
}

std::string SettingDescriptor::rangeText() const {
  if (type == SettingType::kEnum) {
    std::string text;
    for (const std::string& v : values) {
      text += (text.empty() ? "`" : ", `") + v + "`";
    }
    return text;
  }
  if (!numeric()) return "";
  if (type == SettingType::kInt && max == INT_MAX) {
    return ">= " + settingNumberText(min);
  }
  return (min_exclusive ? "(" : "[") + settingNumberText(min) + ", " +
         settingNumberText(max) + "]";
}

std::string settingNumberText(double value) {
  char text[32];
  std::snprintf(text, sizeof text, "%g", value);
  std::string out = text;
  const std::size_t e = out.find('e');
  if (e == std::string::npos) return out;
  std::string mantissa = out.substr(0, e), exponent = out.substr(e + 1);
  // 1.2e+07 of an integer is written out: 12000000.
  if (mantissa.find('.') != std::string::npos && std::abs(value) < 1e9 &&
      value == std::round(value)) {
    return std::to_string(static_cast<long long>(value));
  }
  // 1e+06 -> 1e6, 1e-04 -> 1e-4.
  const bool negative = exponent[0] == '-';
  exponent = exponent.substr(1);
  while (exponent.size() > 1 && exponent[0] == '0') exponent.erase(0, 1);
  return mantissa + "e" + (negative ? "-" : "") + exponent;
}

std::string settingValueText(const SettingValue& value) {
  struct Printer {
    std::string operator()(bool b) const { return b ? "true" : "false"; }
    std::string operator()(int n) const { return std::to_string(n); }
    std::string operator()(double d) const { return settingNumberText(d); }
    std::string operator()(const std::string& s) const {
      return s.empty() ? "\"\"" : "`" + s + "`";
    }
  };
  return std::visit(Printer(), value);
}

void printSettingsMarkdown(std::ostream& out,
                           const std::vector<SettingDescriptor>& settings,
                           bool with_cli) {
  out << "| parameter |" << (with_cli ? " option |" : "")
      << " default | range | when | meaning |\n"
      << "|---|" << (with_cli ? "---|" : "") << "---|---|---|---|\n";
  for (const SettingDescriptor& d : settings) {
    const std::string name = d.per_input ? d.name + "_i" : d.name;
    out << "| `" << name << "` |";
    if (with_cli) out << " `" << d.cliOption() << "` |";
    std::string meaning = d.meaning;
    // A table cell ends at '|': write the absolute value bars escaped.
    for (std::size_t at = meaning.find('|'); at != std::string::npos;
         at = meaning.find('|', at + 2)) {
      meaning.replace(at, 1, "\\|");
    }
    out << " " << settingValueText(d.default_value) << " | " << d.rangeText()
        << " | " << (d.dynamic ? "dyn" : "start") << " | " << meaning << " |\n";
  }
}

}  // namespace normal_fusion
