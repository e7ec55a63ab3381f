// Typed exceptions of the normal_fusion library.
#pragma once

#include <stdexcept>
#include <string>

namespace normal_fusion {

/// Base of every exception the library throws on purpose.
class Error : public std::runtime_error {
 public:
  explicit Error(const std::string& what) : std::runtime_error(what) {}
};

/// Input data is unusable: mismatched sizes, wrong channel count, a singular or
/// non-finite K, no data terms, an unreadable file. The message says what was
/// expected and what came.
class InputError : public Error {
 public:
  explicit InputError(const std::string& what) : Error(what) {}
};

/// A caller asked the solve to stop (Solver::requestCancel).
class Cancelled : public Error {
 public:
  explicit Cancelled(const std::string& what) : Error(what) {}
};

/// A setting is out of its range (negative, NaN, inconsistent).
class ParameterError : public Error {
 public:
  explicit ParameterError(const std::string& what) : Error(what) {}
};

}  // namespace normal_fusion
