// Helpers shared by the synthetic scenes' ray caster (synthetic.cpp) and
// their noise models (synthetic_noise.cpp).
#pragma once

#include <cmath>
#include <limits>
#include <sstream>

#include "eval/synthetic.h"
#include "normal_fusion/errors.h"
#include "normal_fusion/geometry.h"

namespace normal_fusion {
namespace synthetic {
namespace internal {

constexpr float kMissing = std::numeric_limits<float>::quiet_NaN();

inline Vec3 add(const Vec3& a, const Vec3& b) {
  return {a[0] + b[0], a[1] + b[1], a[2] + b[2]};
}
inline Vec3 sub(const Vec3& a, const Vec3& b) {
  return {a[0] - b[0], a[1] - b[1], a[2] - b[2]};
}
inline Vec3 scale(const Vec3& a, double s) {
  return {a[0] * s, a[1] * s, a[2] * s};
}
inline Vec3 normalized(const Vec3& a) {
  return scale(a, 1.0 / std::sqrt(dot(a, a)));
}

inline void requireSize(int width, int height) {
  if (width < 1 || height < 1) {
    std::ostringstream msg;
    msg << "synthetic render size " << width << "x" << height
        << ": expected at least 1x1";
    throw ParameterError(msg.str());
  }
}

inline void requireFinite(const char* name, double value) {
  if (!std::isfinite(value)) {
    std::ostringstream msg;
    msg << name << " = " << value << ": expected a finite number";
    throw ParameterError(msg.str());
  }
}

inline void requireRange(const char* name, double value, double lo, double hi) {
  requireFinite(name, value);
  if (value < lo || value > hi) {
    std::ostringstream msg;
    msg << name << " = " << value << ": expected in [" << lo << ", " << hi
        << "]";
    throw ParameterError(msg.str());
  }
}

inline void requireNormalMap(const char* name, const NormalMap& normals) {
  if (normals.channels() != 3) {
    std::ostringstream msg;
    msg << name << ": expected a normal map of 3 channels, got "
        << normals.channels() << " channels (" << normals.width() << "x"
        << normals.height() << ")";
    throw InputError(msg.str());
  }
}

}  // namespace internal
}  // namespace synthetic
}  // namespace normal_fusion
