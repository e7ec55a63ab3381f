#include "normal_fusion/settings.h"

#include <omp.h>

#include <algorithm>
#include <climits>
#include <cmath>
#include <sstream>

#include "normal_fusion/errors.h"

namespace normal_fusion {
namespace {

/// Throws unless `value` is inside the range of the table's line.
void requireInRange(const char* field, double value, double lo, double hi,
                    bool lo_exclusive) {
  std::ostringstream msg;
  msg << "setting " << field << " = " << value << ": ";
  if (!std::isfinite(value)) {
    msg << "expected a finite number";
    throw ParameterError(msg.str());
  }
  const bool below = lo_exclusive ? !(value > lo) : value < lo;
  if (!below && value <= hi) return;
  if (hi == INT_MAX) {
    msg << "expected >= " << lo;
  } else {
    msg << "expected in " << (lo_exclusive ? "(" : "[") << lo << ", " << hi
        << "]";
  }
  throw ParameterError(msg.str());
}

}  // namespace

int resolveThreadCount(int num_threads) {
  return num_threads > 0 ? num_threads : std::max(1, omp_get_num_procs());
}

void SolverSettings::validate() const {
#define NF_DOUBLE(name, field, def, lo, hi, when, meaning, old) \
  requireInRange(#field, field, lo, hi, false);
#define NF_DOUBLE_ABOVE(name, field, def, lo, hi, when, meaning, old) \
  requireInRange(#field, field, lo, hi, true);
#define NF_INT(name, field, def, lo, hi, when, meaning, old) \
  requireInRange(#field, field, lo, hi, false);
#include "normal_fusion/detail/settings_table.def"
  if ((tau > 0.0) != (sigma > 0.0)) {
    throw ParameterError(
        "settings tau and sigma: set both (> 0) or neither (0 = automatic)");
  }
}

namespace {
template <typename Enum, std::size_t N>
Enum parseEnum(const char* what, const std::string& name,
               const std::pair<const char*, Enum> (&table)[N]) {
  for (const auto& entry : table) {
    if (name == entry.first) return entry.second;
  }
  std::ostringstream msg;
  msg << what << " '" << name << "': expected one of";
  for (const auto& entry : table) msg << " " << entry.first;
  throw ParameterError(msg.str());
}

template <typename Enum, std::size_t N>
std::string enumName(Enum value,
                     const std::pair<const char*, Enum> (&table)[N]) {
  for (const auto& entry : table) {
    if (value == entry.second) return entry.first;
  }
  return "unknown";
}

const std::pair<const char*, DataPenalty> kPenalties[] = {
    {"l2", DataPenalty::kL2}, {"squared_l2", DataPenalty::kSquaredL2}};
const std::pair<const char*, VisibilityMode> kVisibility[] = {
    {"off", VisibilityMode::kOff},
    {"hard", VisibilityMode::kHard},
    {"soft", VisibilityMode::kSoft}};
const std::pair<const char*, EdgeColorMode> kColorModes[] = {
    {"luminance", EdgeColorMode::kLuminance},
    {"color_max", EdgeColorMode::kColorMax}};
const std::pair<const char*, EdgeWeightFunction> kWeightFunctions[] = {
    {"exponential", EdgeWeightFunction::kExponential},
    {"rational", EdgeWeightFunction::kRational}};
const std::pair<const char*, EdgeGradient> kGradients[] = {
    {"sobel", EdgeGradient::kSobel},
    {"forward_difference", EdgeGradient::kForwardDifference}};
const std::pair<const char*, SolverBackend> kBackends[] = {
    {"fast", SolverBackend::kFast}, {"reference", SolverBackend::kReference}};
}  // namespace

DataPenalty parseDataPenalty(const std::string& name) {
  return parseEnum("data penalty", name, kPenalties);
}
VisibilityMode parseVisibilityMode(const std::string& name) {
  return parseEnum("visibility mode", name, kVisibility);
}
EdgeColorMode parseEdgeColorMode(const std::string& name) {
  return parseEnum("edge colour mode", name, kColorModes);
}
EdgeWeightFunction parseEdgeWeightFunction(const std::string& name) {
  return parseEnum("edge weight function", name, kWeightFunctions);
}
EdgeGradient parseEdgeGradient(const std::string& name) {
  return parseEnum("edge gradient", name, kGradients);
}
std::string toString(EdgeGradient value) { return enumName(value, kGradients); }
SolverBackend parseSolverBackend(const std::string& name) {
  return parseEnum("solver backend", name, kBackends);
}
std::string toString(DataPenalty value) { return enumName(value, kPenalties); }
std::string toString(VisibilityMode value) {
  return enumName(value, kVisibility);
}
std::string toString(EdgeColorMode value) {
  return enumName(value, kColorModes);
}
std::string toString(EdgeWeightFunction value) {
  return enumName(value, kWeightFunctions);
}
std::string toString(SolverBackend value) { return enumName(value, kBackends); }

}  // namespace normal_fusion
