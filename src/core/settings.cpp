#include "normal_fusion/settings.h"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <sstream>

#include "normal_fusion/errors.h"

namespace normal_fusion {
namespace {

void requireFinite(const char* name, double value) {
  if (!std::isfinite(value)) {
    std::ostringstream msg;
    msg << "setting " << name << " = " << value << ": expected a finite number";
    throw ParameterError(msg.str());
  }
}

void requireAtLeast(const char* name, double value, double lo) {
  requireFinite(name, value);
  if (value < lo) {
    std::ostringstream msg;
    msg << "setting " << name << " = " << value << ": expected >= " << lo;
    throw ParameterError(msg.str());
  }
}

void requireRange(const char* name, double value, double lo, double hi) {
  requireFinite(name, value);
  if (value < lo || value > hi) {
    std::ostringstream msg;
    msg << "setting " << name << " = " << value << ": expected in [" << lo
        << ", " << hi << "]";
    throw ParameterError(msg.str());
  }
}

}  // namespace

int resolveThreadCount(int num_threads) {
  return num_threads > 0 ? num_threads : std::max(1, omp_get_num_procs());
}

void SolverSettings::validate() const {
  requireAtLeast("lambda", lambda, 0.0);
  requireAtLeast("huber_eps", huber_eps, 0.0);
  // The guide's pre-smoothing costs 6 sigma + 1 taps per pixel: beyond 10 px
  // it would take seconds per frame and blur every edge away.
  requireRange("edges.smoothing_sigma", edges.smoothing_sigma, 0.0, 10.0);
  requireAtLeast("edges.alpha", edges.alpha, 0.0);
  requireAtLeast("edges.beta", edges.beta, 0.0);
  requireRange("edges.w_min", edges.w_min, 0.0, 1.0);
  requireRange("data_eps", data_eps, 0.0, 2.0);
  requireRange("data_eps_local", data_eps_local, 0.0, 100.0);
  requireRange("density_power", density_power, 0.0, 4.0);
  requireRange("local_radius", local_radius, 1, 8);
  requireRange("hole_link_weight", hole_link_weight, 0.0, 1.0);
  if (hole_link_weight <= 0.0) {
    throw ParameterError(
        "setting hole_link_weight = 0: expected in (0, 1] (0 would cut holes "
        "off from their surroundings)");
  }
  requireRange("warm_refine_iterations", warm_refine_iterations, 0, 100000);
  requireRange("warm_refine_radius", warm_refine_radius, 0, 16);
  requireAtLeast("inner_iterations", inner_iterations, 1);
  requireAtLeast("max_outer_iterations", max_outer_iterations, 1);
  requireAtLeast("max_total_inner_iterations", max_total_inner_iterations, 1);
  requireAtLeast("relative_tolerance", relative_tolerance, 0.0);
  requireAtLeast("time_budget_ms", time_budget_ms, 0.0);
  requireAtLeast("cold_start_budget_ms", cold_start_budget_ms, 0.0);
  requireRange("pyramid_levels", pyramid_levels, 0, 12);
  requireRange("num_threads", num_threads, 0, 1024);
  requireAtLeast("tau", tau, 0.0);
  requireAtLeast("sigma", sigma, 0.0);
  requireRange("step_balance", step_balance, 1e-3, 1e3);
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
