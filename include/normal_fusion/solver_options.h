// Command-line options of every solver setting, shared by the tools
// (fuse_normals, evaluate): one table of names, one parser, one help text.
#pragma once

#include <ostream>
#include <string>

#include "normal_fusion/settings.h"

namespace normal_fusion {
namespace cli {

/// True when `option` (e.g. "--lambda") names a solver setting.
bool isSolverOption(const std::string& option);

/// Applies one solver option with its value to `settings`. Throws
/// ParameterError naming the option when the value is malformed (not a
/// number, an unknown name). Range checks are SolverSettings::validate()'s.
void applySolverOption(const std::string& option, const std::string& value,
                       SolverSettings& settings);

/// Help lines of all solver options, with the defaults of `defaults`.
void printSolverOptions(std::ostream& out, const SolverSettings& defaults);

/// Strict number parsing for the tools: the whole text must be a finite
/// number (an integer for parseInt). Throws ParameterError naming `option`.
double parseDouble(const std::string& option, const std::string& text);
int parseInt(const std::string& option, const std::string& text);

}  // namespace cli
}  // namespace normal_fusion
