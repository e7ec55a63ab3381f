#include "normal_fusion/ros/parameters.h"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <limits>
#include <set>
#include <sstream>

#include "normal_fusion/errors.h"

namespace normal_fusion {
namespace node {

// Enum names, found by the visitors through one overload set.
std::string toStringEnum(DataPenalty v) { return toString(v); }
std::string toStringEnum(VisibilityMode v) { return toString(v); }
std::string toStringEnum(EdgeColorMode v) { return toString(v); }
std::string toStringEnum(EdgeWeightFunction v) { return toString(v); }
std::string toStringEnum(EdgeGradient v) { return toString(v); }
std::string toStringEnum(SolverBackend v) { return toString(v); }
std::string toStringEnum(Resampling v) { return toString(v); }

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr int kIntMax = std::numeric_limits<int>::max();

std::string indexed(const char* stem, int i) {
  return std::string(stem) + "_" + std::to_string(i);
}

/// Visits every parameter of `s`: the settings tables' lines, walked by both
/// directions (map -> settings, settings -> map) and the range collector.
template <typename Visitor>
void visitParameters(NodeSettings& s, Visitor& v) {
  SolverSettings& solver = s.solver;
#define NF_DOUBLE(name, field, def, lo, hi, when, meaning, old) \
  v.real(#name, solver.field, lo, hi);
#define NF_DOUBLE_ABOVE(name, field, def, lo, hi, when, meaning, old) \
  v.above(#name, solver.field, lo, hi);
#define NF_INT(name, field, def, lo, hi, when, meaning, old) \
  v.integer(#name, solver.field, lo, hi);
#define NF_BOOL(name, field, def, when, meaning, old) \
  v.flag(#name, solver.field);
#define NF_ENUM(name, field, def, Type, values, when, meaning, old) \
  v.choice(#name, solver.field, parse##Type);
#include "normal_fusion/detail/settings_table.def"

#define NF_DOUBLE(name, field, def, lo, hi, when, meaning, old) \
  v.real(#name, s.field, lo, hi);
#define NF_INT(name, field, def, lo, hi, when, meaning, old) \
  v.integer(#name, s.field, lo, hi);
#define NF_BOOL(name, field, def, when, meaning, old) v.flag(#name, s.field);
#define NF_ENUM(name, field, def, Type, values, when, meaning, old) \
  v.choice(#name, s.field, parse##Type);
#define NF_STRING(name, field, def, when, meaning, old) v.text(#name, s.field);
#define NF_INPUT_DOUBLE(name, field, def, lo, hi, when, meaning, old) \
  for (int i = 0; i < kMaxInputs; ++i) {                              \
    v.real(indexed(#name, i).c_str(), s.inputs[i].field, lo, hi);     \
  }
#define NF_INPUT_BOOL(name, field, def, when, meaning, old) \
  for (int i = 0; i < kMaxInputs; ++i) {                    \
    v.flag(indexed(#name, i).c_str(), s.inputs[i].field);   \
  }
#define NF_INPUT_ORIENTATION(name, field, def, when, meaning, old) \
  for (int i = 0; i < kMaxInputs; ++i) {                           \
    v.orientation(indexed(#name, i).c_str(), s.inputs[i]);         \
  }
#include "normal_fusion/ros/detail/node_settings_table.def"
}

std::vector<SettingDescriptor> makeNodeDescriptors() {
  std::vector<SettingDescriptor> table;
  std::string group;
  const auto add = [&](SettingDescriptor d, bool per_input) {
    d.per_input = per_input;
    table.push_back(std::move(d));
  };
#define NF_GROUP(name) group = #name;
#define NF_DOUBLE(name, field, def, lo, hi, when, meaning, old)         \
  add(makeSettingDescriptor(#name, #field, group, SettingType::kDouble, \
                            double(def), lo, hi, false, "",             \
                            NF_SETTING_IS_DYNAMIC(when), meaning, old), \
      false);
#define NF_INPUT_DOUBLE(name, field, def, lo, hi, when, meaning, old)   \
  add(makeSettingDescriptor(#name, #field, group, SettingType::kDouble, \
                            double(def), lo, hi, false, "",             \
                            NF_SETTING_IS_DYNAMIC(when), meaning, old), \
      true);
#define NF_INT(name, field, def, lo, hi, when, meaning, old)                   \
  add(makeSettingDescriptor(#name, #field, group, SettingType::kInt, int(def), \
                            lo, hi, false, "", NF_SETTING_IS_DYNAMIC(when),    \
                            meaning, old),                                     \
      false);
#define NF_BOOL(name, field, def, when, meaning, old)                   \
  add(makeSettingDescriptor(#name, #field, group, SettingType::kBool,   \
                            bool(def), 0, 0, false, "",                 \
                            NF_SETTING_IS_DYNAMIC(when), meaning, old), \
      false);
#define NF_INPUT_BOOL(name, field, def, when, meaning, old)             \
  add(makeSettingDescriptor(#name, #field, group, SettingType::kBool,   \
                            bool(def), 0, 0, false, "",                 \
                            NF_SETTING_IS_DYNAMIC(when), meaning, old), \
      true);
#define NF_ENUM(name, field, def, Type, values, when, meaning, old)     \
  add(makeSettingDescriptor(#name, #field, group, SettingType::kEnum,   \
                            toString(Type::def), 0, 0, false, values,   \
                            NF_SETTING_IS_DYNAMIC(when), meaning, old), \
      false);
#define NF_STRING(name, field, def, when, meaning, old)                 \
  add(makeSettingDescriptor(#name, #field, group, SettingType::kString, \
                            std::string(def), 0, 0, false, "",          \
                            NF_SETTING_IS_DYNAMIC(when), meaning, old), \
      false);
#define NF_INPUT_ORIENTATION(name, field, def, when, meaning, old)      \
  add(makeSettingDescriptor(#name, #field, group, SettingType::kString, \
                            std::string(def), 0, 0, false, "",          \
                            NF_SETTING_IS_DYNAMIC(when), meaning, old), \
      true);
#include "normal_fusion/ros/detail/node_settings_table.def"
  return table;
}

const char* typeName(const ParameterValue& value) {
  switch (value.index()) {
    case 0:
      return "bool";
    case 1:
      return "int";
    case 2:
      return "double";
    default:
      return "string";
  }
}

std::string numberText(double value) {
  std::ostringstream out;
  out << value;
  return out.str();
}

/// Map -> settings: reads each field, correcting and reporting bad values.
class Reader {
 public:
  Reader(ParameterMap& params, std::vector<std::string>* warnings)
      : params_(params), warnings_(warnings) {}

  void real(const char* name, double& field, double lo, double hi) {
    seen_.insert(name);
    auto it = params_.find(name);
    if (it == params_.end()) {
      params_[name] = field;
      return;
    }
    double value;
    if (const double* d = std::get_if<double>(&it->second)) {
      value = *d;
    } else if (const int* n = std::get_if<int>(&it->second)) {
      value = *n;
    } else {
      return replace(
          it, field,
          "expected a number, got a " + std::string(typeName(it->second)));
    }
    // Refused values keep the value in use: a bound may mean "off" (a time
    // budget of 0), so clamping to it would change what the node does.
    if (!std::isfinite(value)) {
      return replace(it, field, "expected a finite number");
    }
    if (value < lo || value > hi) {
      return replace(
          it, field,
          "out of range [" + numberText(lo) + ", " + numberText(hi) + "]");
    }
    field = value;
    it->second = value;
  }

  /// A finite number in (lo, hi]: anything else keeps the value in use.
  void above(const char* name, double& field, double lo, double hi) {
    seen_.insert(name);
    auto it = params_.find(name);
    if (it == params_.end()) {
      params_[name] = field;
      return;
    }
    double value;
    if (const double* d = std::get_if<double>(&it->second)) {
      value = *d;
    } else if (const int* n = std::get_if<int>(&it->second)) {
      value = *n;
    } else {
      return replace(it, field,
                     "expected a number > " + numberText(lo) + ", got a " +
                         std::string(typeName(it->second)));
    }
    if (!(value > lo) || !(value <= hi)) {
      return replace(it, field,
                     "expected a number in (" + numberText(lo) + ", " +
                         numberText(hi) + "]");
    }
    field = value;
    it->second = value;
  }

  void integer(const char* name, int& field, int lo, int hi) {
    seen_.insert(name);
    auto it = params_.find(name);
    if (it == params_.end()) {
      params_[name] = field;
      return;
    }
    long long value;
    if (const int* n = std::get_if<int>(&it->second)) {
      value = *n;
    } else if (const double* d = std::get_if<double>(&it->second)) {
      if (!std::isfinite(*d) || std::abs(*d) > 1e9) {
        return replace(it, field, "expected an integer");
      }
      value = std::llround(*d);
      if (static_cast<double>(value) != *d) {
        if (value < lo || value > hi) {
          return replace(it, field, "expected an integer in range");
        }
        return replace(it, static_cast<int>(value), "expected an integer",
                       &field);
      }
    } else {
      return replace(
          it, field,
          "expected an integer, got a " + std::string(typeName(it->second)));
    }
    if (value < lo || value > hi) {
      return replace(it, field,
                     "out of range [" + std::to_string(lo) + ", " +
                         std::to_string(hi) + "]");
    }
    field = static_cast<int>(value);
    it->second = field;
  }

  void flag(const char* name, bool& field) {
    seen_.insert(name);
    auto it = params_.find(name);
    if (it == params_.end()) {
      params_[name] = field;
      return;
    }
    if (const bool* b = std::get_if<bool>(&it->second)) {
      field = *b;
      return;
    }
    if (const int* n = std::get_if<int>(&it->second)) {
      if (*n == 0 || *n == 1) {
        return replace(it, *n == 1, "expected true or false", &field);
      }
    }
    replace(it, field, "expected true or false");
  }

  void text(const char* name, std::string& field) {
    seen_.insert(name);
    auto it = params_.find(name);
    if (it == params_.end()) {
      params_[name] = field;
      return;
    }
    if (const std::string* t = std::get_if<std::string>(&it->second)) {
      field = *t;
      return;
    }
    replace(it, field,
            "expected a string, got a " + std::string(typeName(it->second)));
  }

  template <typename Enum, typename Parse>
  void choice(const char* name, Enum& field, Parse parse) {
    std::string text_value = toStringEnum(field);
    const std::string default_text = text_value;
    text(name, text_value);
    try {
      field = parse(text_value);
    } catch (const Error& e) {
      auto it = params_.find(name);
      replace(it, default_text, e.what());
    }
  }

  void orientation(const char* name, InputSettings& input) {
    const std::string default_text = input.orientation_name;
    text(name, input.orientation_name);
    try {
      input.orientation = Orientation::fromString(input.orientation_name);
    } catch (const Error& e) {
      input.orientation_name = default_text;
      input.orientation = Orientation::fromString(default_text);
      auto it = params_.find(name);
      replace(it, default_text, e.what());
    }
  }

  void reportUnknown() {
    for (const auto& entry : params_) {
      if (seen_.count(entry.first) == 0 && warnings_ != nullptr) {
        warnings_->push_back("unknown parameter '" + entry.first +
                             "' = " + toString(entry.second) + " (ignored)");
      }
    }
  }

  void warn(const std::string& text) {
    if (warnings_ != nullptr) warnings_->push_back(text);
  }

 private:
  /// Writes the corrected `value` into the map (and into `field`, when given)
  /// and reports it.
  template <typename T, typename F = T>
  void replace(ParameterMap::iterator it, const T& value,
               const std::string& why, F* field = nullptr) {
    const ParameterValue corrected = value;
    warn("parameter '" + it->first + "' = " + toString(it->second) + ": " +
         why + "; using " + toString(corrected));
    it->second = corrected;
    if (field != nullptr) *field = value;
  }

  ParameterMap& params_;
  std::vector<std::string>* warnings_;
  std::set<std::string> seen_;
};

/// Settings -> map.
class Writer {
 public:
  explicit Writer(ParameterMap& params) : params_(params) {}
  void real(const char* name, double& field, double, double) {
    params_[name] = field;
  }
  void integer(const char* name, int& field, int, int) {
    params_[name] = field;
  }
  void above(const char* name, double& field, double, double) {
    params_[name] = field;
  }
  void flag(const char* name, bool& field) { params_[name] = field; }
  void text(const char* name, std::string& field) { params_[name] = field; }
  template <typename Enum, typename Parse>
  void choice(const char* name, Enum& field, Parse) {
    params_[name] = toStringEnum(field);
  }
  void orientation(const char* name, InputSettings& input) {
    params_[name] = input.orientation_name;
  }

 private:
  ParameterMap& params_;
};

/// The numeric parameters' ranges.
class RangeCollector {
 public:
  explicit RangeCollector(std::vector<ParameterRange>* ranges)
      : ranges_(ranges) {}
  void real(const char* name, double&, double lo, double hi) {
    ranges_->push_back({name, lo, hi});
  }
  void integer(const char* name, int&, int lo, int hi) {
    ranges_->push_back(
        {name, static_cast<double>(lo), static_cast<double>(hi)});
  }
  void above(const char* name, double&, double lo, double hi) {
    // (lo, hi]: the next double above lo stands for the open bound.
    ranges_->push_back({name, std::nextafter(lo, kInf), hi});
  }
  void flag(const char*, bool&) {}
  void text(const char*, std::string&) {}
  template <typename Enum, typename Parse>
  void choice(const char*, Enum&, Parse) {}
  void orientation(const char*, InputSettings&) {}

 private:
  std::vector<ParameterRange>* ranges_;
};

}  // namespace

std::vector<ParameterRange> numericParameterRanges() {
  std::vector<ParameterRange> ranges;
  NodeSettings settings;
  RangeCollector collector(&ranges);
  visitParameters(settings, collector);
  return ranges;
}

const std::vector<SettingDescriptor>& nodeSettingDescriptors() {
  static const std::vector<SettingDescriptor> table = makeNodeDescriptors();
  return table;
}

bool isDynamicParameter(const std::string& name) {
  for (const auto* table :
       {&solverSettingDescriptors(), &nodeSettingDescriptors()}) {
    for (const SettingDescriptor& d : *table) {
      if (d.name == name) return d.dynamic;
      if (d.per_input && name.rfind(d.name + "_", 0) == 0 &&
          name.size() > d.name.size() + 1) {
        const std::string index = name.substr(d.name.size() + 1);
        if (index.find_first_not_of("0123456789") == std::string::npos &&
            std::stoi(index) < kMaxInputs) {
          return d.dynamic;
        }
      }
    }
  }
  return true;
}

ParameterMap parametersFromSettings(const NodeSettings& settings) {
  ParameterMap params;
  NodeSettings copy = settings;
  Writer writer(params);
  visitParameters(copy, writer);
  return params;
}

namespace {

/// The visitors' pass and the step-pair rule: every value checked on its own.
NodeSettings readSettings(ParameterMap& params,
                          std::vector<std::string>* warnings,
                          const NodeSettings& base) {
  NodeSettings settings = base;
  Reader reader(params, warnings);
  visitParameters(settings, reader);
  reader.reportUnknown();

  SolverSettings& solver = settings.solver;
  // Explicit step sizes come in pairs and must satisfy the step condition.
  const bool tau_set = solver.tau > 0.0, sigma_set = solver.sigma > 0.0;
  const double step_product =
      solver.tau * solver.sigma * (8.0 + settings.num_inputs);
  if (tau_set != sigma_set || (tau_set && step_product >= 1.0)) {
    std::ostringstream why;
    why << "parameters 'tau' = " << solver.tau
        << " and 'sigma' = " << solver.sigma << ": ";
    if (tau_set != sigma_set) {
      why << "set both (> 0) or neither (0 = automatic)";
    } else {
      why << "expected tau * sigma * (8 + num_inputs) < 1, got "
          << step_product;
    }
    why << "; using 0 and 0 (automatic steps)";
    reader.warn(why.str());
    solver.tau = solver.sigma = 0.0;
    params["tau"] = 0.0;
    params["sigma"] = 0.0;
  }
  return settings;
}

bool solverAccepts(const NodeSettings& settings, std::string* why) {
  try {
    settings.solver.validate();
    settings.temporal.validate();
  } catch (const Error& e) {
    *why = e.what();
    return false;
  }
  return true;
}

}  // namespace

NodeSettings settingsFromParameters(ParameterMap& params,
                                    std::vector<std::string>* warnings,
                                    const NodeSettings& base) {
  NodeSettings settings = readSettings(params, warnings, base);
  std::string why;
  if (solverAccepts(settings, &why)) return settings;
  // A combination the per-value ranges do not know: the one parameter whose
  // base value makes the settings valid again is refused; the rest stay.
  const ParameterMap base_params = parametersFromSettings(base);
  for (const auto& entry : base_params) {
    auto it = params.find(entry.first);
    if (it == params.end() || it->second == entry.second) continue;
    ParameterMap trial = params;
    trial[entry.first] = entry.second;
    const NodeSettings candidate = readSettings(trial, nullptr, base);
    std::string ignored;
    if (!solverAccepts(candidate, &ignored)) continue;
    if (warnings != nullptr) {
      warnings->push_back("parameter '" + entry.first +
                          "' = " + toString(it->second) + ": rejected (" + why +
                          "); using " + toString(entry.second));
    }
    params = trial;
    return candidate;
  }
  if (warnings != nullptr) {
    warnings->push_back(std::string("solver settings rejected (") + why +
                        "); using the previous values of all parameters");
  }
  params = base_params;
  return base;
}

ParameterMap parametersFromYamlFile(const std::string& path,
                                    std::vector<std::string>* warnings) {
  YAML::Node root;
  try {
    root = YAML::LoadFile(path);
  } catch (const std::exception& e) {
    throw InputError("parameters file " + path +
                     ": expected a readable YAML file (" + e.what() + ")");
  }
  ParameterMap params;
  if (root.IsNull()) return params;
  if (!root.IsMap()) {
    throw InputError("parameters file " + path +
                     ": expected a map of parameter names to values");
  }
  for (const auto& entry : root) {
    const std::string name = entry.first.as<std::string>();
    const YAML::Node& node = entry.second;
    if (!node.IsScalar()) {
      if (warnings != nullptr) {
        warnings->push_back("parameters file " + path + ": '" + name +
                            "' is not a scalar (ignored)");
      }
      continue;
    }
    params[name] = parameterFromText(node.Scalar(), node.Tag() == "!");
  }
  return params;
}

ParameterValue parameterFromText(const std::string& text, bool quoted) {
  if (quoted) return text;
  std::string lower = text;
  std::transform(lower.begin(), lower.end(), lower.begin(),
                 [](unsigned char c) { return std::tolower(c); });
  if (lower == "true" || lower == "yes" || lower == "on") return true;
  if (lower == "false" || lower == "no" || lower == "off") return false;
  char* end = nullptr;
  const long long as_int = std::strtoll(text.c_str(), &end, 10);
  if (!text.empty() && end != nullptr && *end == '\0' &&
      as_int >= std::numeric_limits<int>::min() && as_int <= kIntMax) {
    return static_cast<int>(as_int);
  }
  if (lower == ".inf" || lower == "+.inf") return kInf;
  if (lower == "-.inf") return -kInf;
  if (lower == ".nan") return std::numeric_limits<double>::quiet_NaN();
  const double as_double = std::strtod(text.c_str(), &end);
  if (!text.empty() && end != nullptr && *end == '\0') return as_double;
  return text;
}

std::string toString(Resampling value) {
  return value == Resampling::kNearest ? "nearest" : "bilinear";
}

Resampling parseResampling(const std::string& name) {
  if (name == "nearest") return Resampling::kNearest;
  if (name == "bilinear") return Resampling::kBilinear;
  throw ParameterError("resampling '" + name +
                       "': expected one of nearest bilinear");
}

std::string toString(const ParameterValue& value) {
  struct Printer {
    std::string operator()(bool b) const { return b ? "true" : "false"; }
    std::string operator()(int n) const { return std::to_string(n); }
    std::string operator()(double d) const { return numberText(d); }
    std::string operator()(const std::string& s) const { return "'" + s + "'"; }
  };
  return std::visit(Printer(), value);
}

}  // namespace node
}  // namespace normal_fusion
