// The tools' command lines (fuse_normals, evaluate, depth_to_normals): the
// walk over "--name value" / "--name=value" arguments, and the options of
// every solver setting, made from the settings table: the option of a
// setting is "--" + its ROS name with '_' -> '-' (--huber-eps); the table's
// older spellings still work and print one deprecation line.
#pragma once

#include <iostream>
#include <ostream>
#include <stdexcept>
#include <string>

#include "normal_fusion/settings.h"

namespace normal_fusion {
namespace cli {

/// A malformed command line (the tools exit with status 2).
class UsageError : public std::runtime_error {
 public:
  explicit UsageError(const std::string& what) : std::runtime_error(what) {}
};

/// Walks a tool's arguments: every argument is an option, "--name" or
/// "--name=value"; a value is the part after '=' or the next argument.
class ArgumentCursor {
 public:
  ArgumentCursor(int argc, char** argv) : argc_(argc), argv_(argv) {}

  /// Moves to the next option; false when none is left. Throws UsageError
  /// for an argument that does not start with "--".
  bool next();
  /// The current option without its "=value" (e.g. "--lambda").
  const std::string& option() const { return option_; }
  /// Throws UsageError when the current option was given "=value".
  void expectNoValue() const;
  /// The current option's value (after '=', else the next argument, which
  /// is then consumed); throws UsageError when there is none.
  std::string value();

 private:
  int argc_;
  char** argv_;
  int index_ = 0;
  std::string option_;
  std::string inline_value_;
  bool has_inline_value_ = false;
};

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
