// Small 3x3 geometry of the library: row-major matrices, vectors, the rigid
// pose of a camera and the one test of a rotation matrix.
#pragma once

#include <array>
#include <cmath>
#include <string>

#include "normal_fusion/errors.h"

namespace normal_fusion {

/// Row-major 3x3 matrix: entry (r, c) at [3 r + c].
using Mat3 = std::array<double, 9>;
using Vec3 = std::array<double, 3>;

constexpr Mat3 kIdentity3{{1, 0, 0, 0, 1, 0, 0, 0, 1}};

/// The library's one pose type, a rigid transform: a point X of frame B maps
/// to R X + t in frame A (t in metres); a variable's name says the frames,
/// e.g. T_cam_world (world point to camera point) or T_rgb_depth.
struct Pose {
  Mat3 R = kIdentity3;
  Vec3 t{{0, 0, 0}};
};

inline double dot(const Vec3& a, const Vec3& b) {
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

inline Vec3 cross(const Vec3& a, const Vec3& b) {
  return {{a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
           a[0] * b[1] - a[1] * b[0]}};
}

/// A B.
inline Mat3 multiply(const Mat3& A, const Mat3& B) {
  Mat3 AB{};
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) {
      for (int k = 0; k < 3; ++k) AB[3 * r + c] += A[3 * r + k] * B[3 * k + c];
    }
  }
  return AB;
}

inline Mat3 transpose(const Mat3& M) {
  return {{M[0], M[3], M[6], M[1], M[4], M[7], M[2], M[5], M[8]}};
}

/// M v.
inline Vec3 multiply(const Mat3& M, const Vec3& v) {
  return {{M[0] * v[0] + M[1] * v[1] + M[2] * v[2],
           M[3] * v[0] + M[4] * v[1] + M[5] * v[2],
           M[6] * v[0] + M[7] * v[1] + M[8] * v[2]}};
}

/// M^T v.
inline Vec3 multiplyTransposed(const Mat3& M, const Vec3& v) {
  return {{M[0] * v[0] + M[3] * v[1] + M[6] * v[2],
           M[1] * v[0] + M[4] * v[1] + M[7] * v[2],
           M[2] * v[0] + M[5] * v[1] + M[8] * v[2]}};
}

/// The pose applied to a point: R X + t.
inline Vec3 transformPoint(const Pose& T, const Vec3& X) {
  const Vec3 RX = multiply(T.R, X);
  return {{RX[0] + T.t[0], RX[1] + T.t[1], RX[2] + T.t[2]}};
}

/// The inverse pose: R^T and -R^T t.
inline Pose inverse(const Pose& T) {
  Pose inv;
  inv.R = transpose(T.R);
  for (int r = 0; r < 3; ++r) {
    inv.t[r] = 0.0;
    for (int k = 0; k < 3; ++k) {
      inv.t[r] -= inv.R[3 * r + k] * T.t[k];
    }
  }
  return inv;
}

inline double determinant(const Mat3& M) {
  return M[0] * (M[4] * M[8] - M[5] * M[7]) -
         M[1] * (M[3] * M[8] - M[5] * M[6]) +
         M[2] * (M[3] * M[7] - M[4] * M[6]);
}

/// The adjugate divided by `det` (determinant(M), non-zero).
inline Mat3 inverse(const Mat3& M, double det) {
  const double inv_det = 1.0 / det;
  return {{(M[4] * M[8] - M[5] * M[7]) * inv_det,
           (M[2] * M[7] - M[1] * M[8]) * inv_det,
           (M[1] * M[5] - M[2] * M[4]) * inv_det,
           (M[5] * M[6] - M[3] * M[8]) * inv_det,
           (M[0] * M[8] - M[2] * M[6]) * inv_det,
           (M[2] * M[3] - M[0] * M[5]) * inv_det,
           (M[3] * M[7] - M[4] * M[6]) * inv_det,
           (M[1] * M[6] - M[0] * M[7]) * inv_det,
           (M[0] * M[4] - M[1] * M[3]) * inv_det}};
}

/// How far an entry of R R^T may be from I's for R to count as a rotation:
/// rotations written as text with six or seven digits pass.
constexpr double kRotationTolerance = 1e-4;

/// True when R has finite entries, R R^T = I within kRotationTolerance and
/// det R > 0 (no reflection).
inline bool isRotation(const Mat3& R) {
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) {
      double d = 0.0;
      for (int k = 0; k < 3; ++k) d += R[3 * i + k] * R[3 * j + k];
      if (!std::isfinite(d) ||
          std::abs(d - (i == j ? 1.0 : 0.0)) > kRotationTolerance) {
        return false;
      }
    }
  }
  return determinant(R) > 0.0;
}

/// The message for a matrix isRotation rejects, `who` naming its owner.
inline std::string notRotationMessage(const std::string& who) {
  return who +
         ": R is not a rotation matrix (expected R R^T = I within 1e-4 and "
         "det R = +1)";
}

/// Throws ParameterError naming `who` unless T's entries are finite and T.R
/// is a rotation (isRotation).
inline void validatePose(const Pose& T, const std::string& who) {
  for (double v : T.t) {
    if (!std::isfinite(v)) {
      throw ParameterError(who + ": t has a non-finite entry");
    }
  }
  if (!isRotation(T.R)) throw ParameterError(notRotationMessage(who));
}

}  // namespace normal_fusion
