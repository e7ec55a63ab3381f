#include "normal_fusion/solver_options.h"

#include <cmath>
#include <functional>
#include <map>
#include <stdexcept>

#include "normal_fusion/errors.h"

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

const std::map<std::string, Setter>& setters() {
  static const std::map<std::string, Setter> table = {
      {"--lambda",
       [](auto& o, auto& v, auto& s) { s.lambda = parseDouble(o, v); }},
      {"--eps",
       [](auto& o, auto& v, auto& s) { s.huber_eps = parseDouble(o, v); }},
      {"--penalty",
       [](auto& o, auto& v, auto& s) {
         s.penalty = parseName(o, v, parseDataPenalty);
       }},
      {"--visibility",
       [](auto& o, auto& v, auto& s) {
         s.visibility = parseName(o, v, parseVisibilityMode);
       }},
      {"--edges",
       [](auto& o, auto& v, auto& s) { s.edges.enabled = parseOnOff(o, v); }},
      {"--edge-alpha",
       [](auto& o, auto& v, auto& s) { s.edges.alpha = parseDouble(o, v); }},
      {"--edge-beta",
       [](auto& o, auto& v, auto& s) { s.edges.beta = parseDouble(o, v); }},
      {"--edge-wmin",
       [](auto& o, auto& v, auto& s) { s.edges.w_min = parseDouble(o, v); }},
      {"--edge-sigma",
       [](auto& o, auto& v, auto& s) {
         s.edges.smoothing_sigma = parseDouble(o, v);
       }},
      {"--edge-color",
       [](auto& o, auto& v, auto& s) {
         s.edges.color_mode = parseName(o, v, parseEdgeColorMode);
       }},
      {"--edge-function",
       [](auto& o, auto& v, auto& s) {
         s.edges.function = parseName(o, v, parseEdgeWeightFunction);
       }},
      {"--edge-gradient",
       [](auto& o, auto& v, auto& s) {
         s.edges.gradient = parseName(o, v, parseEdgeGradient);
       }},
      {"--data-eps",
       [](auto& o, auto& v, auto& s) { s.data_eps = parseDouble(o, v); }},
      {"--data-eps-local",
       [](auto& o, auto& v, auto& s) { s.data_eps_local = parseDouble(o, v); }},
      {"--density-power",
       [](auto& o, auto& v, auto& s) { s.density_power = parseDouble(o, v); }},
      {"--hole-link-weight",
       [](auto& o, auto& v, auto& s) {
         s.hole_link_weight = parseDouble(o, v);
       }},
      {"--local-radius",
       [](auto& o, auto& v, auto& s) { s.local_radius = parseInt(o, v); }},
      {"--inner-iterations",
       [](auto& o, auto& v, auto& s) { s.inner_iterations = parseInt(o, v); }},
      {"--warm-refine-iterations",
       [](auto& o, auto& v, auto& s) {
         s.warm_refine_iterations = parseInt(o, v);
       }},
      {"--warm-refine-radius",
       [](auto& o, auto& v, auto& s) {
         s.warm_refine_radius = parseInt(o, v);
       }},
      {"--max-outer", [](auto& o, auto& v,
                         auto& s) { s.max_outer_iterations = parseInt(o, v); }},
      {"--max-iterations",
       [](auto& o, auto& v, auto& s) {
         s.max_total_inner_iterations = parseInt(o, v);
       }},
      {"--tolerance",
       [](auto& o, auto& v, auto& s) {
         s.relative_tolerance = parseDouble(o, v);
       }},
      {"--time-budget-ms",
       [](auto& o, auto& v, auto& s) { s.time_budget_ms = parseDouble(o, v); }},
      {"--cold-start-budget-ms",
       [](auto& o, auto& v, auto& s) {
         s.cold_start_budget_ms = parseDouble(o, v);
       }},
      {"--pyramid-levels",
       [](auto& o, auto& v, auto& s) { s.pyramid_levels = parseInt(o, v); }},
      {"--threads",
       [](auto& o, auto& v, auto& s) { s.num_threads = parseInt(o, v); }},
      {"--adaptive-refine-threads",
       [](auto& o, auto& v, auto& s) {
         s.adaptive_refine_threads = parseOnOff(o, v);
       }},
      {"--backend",
       [](auto& o, auto& v, auto& s) {
         s.backend = parseName(o, v, parseSolverBackend);
       }},
      {"--preconditioning",
       [](auto& o, auto& v, auto& s) { s.preconditioning = parseOnOff(o, v); }},
      {"--tau", [](auto& o, auto& v, auto& s) { s.tau = parseDouble(o, v); }},
      {"--sigma",
       [](auto& o, auto& v, auto& s) { s.sigma = parseDouble(o, v); }},
      {"--step-balance",
       [](auto& o, auto& v, auto& s) { s.step_balance = parseDouble(o, v); }},
  };
  return table;
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
  return setters().count(option) > 0;
}

void applySolverOption(const std::string& option, const std::string& value,
                       SolverSettings& settings) {
  const auto it = setters().find(option);
  if (it == setters().end()) {
    throw ParameterError("unknown solver option '" + option + "'");
  }
  it->second(option, value, settings);
}

void printSolverOptions(std::ostream& out, const SolverSettings& d) {
  const auto onOff = [](bool b) { return b ? "on" : "off"; };
  out << "  --lambda X            data weight [" << d.lambda << "]\n"
      << "  --eps X               Huber threshold, 0 = plain TV ["
      << d.huber_eps << "]\n"
      << "  --penalty P           l2 | squared_l2 [" << toString(d.penalty)
      << "]\n"
      << "  --visibility V        off | hard | soft [" << toString(d.visibility)
      << "]\n"
      << "  --edges on|off        image-driven edge weights ["
      << onOff(d.edges.enabled) << "]\n"
      << "  --edge-gradient G     forward_difference | sobel ["
      << toString(d.edges.gradient) << "]\n"
      << "  --edge-color C        luminance | color_max ["
      << toString(d.edges.color_mode) << "]\n"
      << "  --edge-function F     exponential | rational ["
      << toString(d.edges.function) << "]\n"
      << "  --edge-alpha X        w = exp(-alpha g^beta) or 1 / (1 + alpha "
         "g^beta) ["
      << d.edges.alpha << "]\n"
      << "  --edge-beta X         exponent beta [" << d.edges.beta << "]\n"
      << "  --edge-wmin X         floor of the edge weights [" << d.edges.w_min
      << "]\n"
      << "  --edge-sigma X        Gaussian pre-smoothing of the guide, pixels ["
      << d.edges.smoothing_sigma << "]\n"
      << "  --data-eps X          Huber threshold of the data terms, "
         "global part ["
      << d.data_eps << "]\n"
      << "  --data-eps-local X    its part per unit of the input's local "
         "spread ["
      << d.data_eps_local << "]\n"
      << "  --density-power X     data weight times (window / valid)^X in "
         "the window ["
      << d.density_power << "]\n"
      << "  --local-radius N      window half-size of the spread and the "
         "density ["
      << d.local_radius << "]\n"
      << "  --hole-link-weight X  edge weight factor inside holes, (0, 1] ["
      << d.hole_link_weight << "]\n"
      << "  --inner-iterations N  Chambolle-Pock iterations per outer step ["
      << d.inner_iterations << "]\n"
      << "  --max-outer N         majorize-minimize steps ["
      << d.max_outer_iterations << "]\n"
      << "  --max-iterations N    inner iterations in all ["
      << d.max_total_inner_iterations << "]\n"
      << "  --tolerance X         relative energy decrease to stop ["
      << d.relative_tolerance << "]\n"
      << "  --time-budget-ms X    wall-clock budget, 0 = none ["
      << d.time_budget_ms << "]\n"
      << "  --cold-start-budget-ms X  budget of a cold start while a budget is "
         "set, 0 = none ["
      << d.cold_start_budget_ms << "]\n"
      << "  --warm-refine-iterations N  local refinement of a warm start's "
         "unknown pixels, 0 = off ["
      << d.warm_refine_iterations << "]\n"
      << "  --warm-refine-radius N      pixels around them refined too ["
      << d.warm_refine_radius << "]\n"
      << "  --pyramid-levels N    1 = off, 0 = automatic [" << d.pyramid_levels
      << "]\n"
      << "  --preconditioning on|off  diagonal preconditioning ["
      << onOff(d.preconditioning) << "]\n"
      << "  --tau X, --sigma X    explicit step sizes, 0 = automatic\n"
      << "  --step-balance X      automatic steps: tau * X, sigma / X ["
      << d.step_balance << "]\n"
      << "  --threads N           0 = all hardware threads [" << d.num_threads
      << "]\n"
      << "  --adaptive-refine-threads on|off  local refinement on one thread "
         "while measured faster (same result) ["
      << onOff(d.adaptive_refine_threads) << "]\n"
      << "  --backend B           fast | reference [" << toString(d.backend)
      << "]\n";
}

}  // namespace cli
}  // namespace normal_fusion
