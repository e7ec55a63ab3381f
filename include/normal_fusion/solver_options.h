// Command-line options of every solver setting, shared by the tools
// (fuse_normals, evaluate), made from the settings table: the option of a
// setting is "--" + its ROS name with '_' -> '-' (--huber-eps); the table's
// older spellings still work and print one deprecation line.
#pragma once

#include <iostream>
#include <ostream>
#include <string>

#include "normal_fusion/settings.h"

namespace normal_fusion {
namespace cli {

/// True when `option` (e.g. "--lambda") names a solver setting, in its
/// spelling or a deprecated one.
bool isSolverOption(const std::string& option);

/// The spelling of the setting that a deprecated `option` names (e.g.
/// "--huber-eps" for "--eps"); empty when `option` is not deprecated.
std::string replacementOption(const std::string& option);

/// Applies one solver option with its value to `settings`. Throws
/// ParameterError naming the option when the value is malformed (not a
/// number, an unknown name). Range checks are SolverSettings::validate()'s.
/// A deprecated spelling writes one line naming the new one to `warnings`.
void applySolverOption(const std::string& option, const std::string& value,
                       SolverSettings& settings,
                       std::ostream& warnings = std::cerr);

/// Help lines of all solver options, with the defaults of `defaults`.
void printSolverOptions(std::ostream& out, const SolverSettings& defaults);

/// Strict number parsing for the tools: the whole text must be a finite
/// number (an integer for parseInt). Throws ParameterError naming `option`.
double parseDouble(const std::string& option, const std::string& text);
int parseInt(const std::string& option, const std::string& text);

}  // namespace cli
}  // namespace normal_fusion
