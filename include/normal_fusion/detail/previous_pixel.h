// Where a pixel of the current frame was in the previous one, for a camera
// that rotated by R (the homography K R^T K^-1): shared by the warm start's
// warp and the temporal averaging of the inputs.
#pragma once

#include <array>
#include <cmath>
#include <string>

#include "normal_fusion/errors.h"
#include "normal_fusion/geometry.h"
#include "normal_fusion/types.h"

namespace normal_fusion {
namespace internal {

/// Throws InputError ("<who>: R is not a rotation matrix ...") unless R is a
/// rotation (geometry.h's isRotation, the one check of the library).
inline void checkRotation(const std::array<double, 9>& R, const char* who) {
  if (!isRotation(R)) throw InputError(notRotationMessage(who));
}

/// Where a current pixel comes from in the previous image: u_prev ~ K R^T
/// K^-1 u_cur, the homography of a camera that rotated by R.
class PreviousPixel {
 public:
  PreviousPixel(const CameraIntrinsics& K, const std::array<double, 9>& R) {
    const std::array<double, 9> K_inv = K.inverse();
    // A = K R^T K^-1.
    double RtKinv[9];
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) {
        RtKinv[3 * i + j] =
            R[i] * K_inv[j] + R[3 + i] * K_inv[3 + j] + R[6 + i] * K_inv[6 + j];
      }
    }
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) {
        A_[3 * i + j] = K.K[3 * i] * RtKinv[j] +
                        K.K[3 * i + 1] * RtKinv[3 + j] +
                        K.K[3 * i + 2] * RtKinv[6 + j];
      }
    }
  }

  /// The previous pixel (u, v) of pixel (x, y); false when it lies outside
  /// the previous W x H image (or behind the camera). Positions within 1e-6
  /// of the border count as on it (rounding of an identity warp).
  bool at(int x, int y, int W, int H, double* u, double* v) const {
    const double w = A_[6] * x + A_[7] * y + A_[8];
    if (!(w > 1e-9)) return false;
    const double inv_w = 1.0 / w;
    *u = clampNear((A_[0] * x + A_[1] * y + A_[2]) * inv_w, W - 1.0);
    *v = clampNear((A_[3] * x + A_[4] * y + A_[5]) * inv_w, H - 1.0);
    return *u >= 0.0 && *v >= 0.0 && *u <= W - 1.0 && *v <= H - 1.0;
  }

  /// A = K R^T K^-1, row-major.
  const double* matrix() const { return A_; }

  static double clampNear(double t, double high) {
    constexpr double kSlack = 1e-6;
    const double low_clamped = ((t < 0.0) & (t > -kSlack)) ? 0.0 : t;
    return ((t > high) & (t < high + kSlack)) ? high : low_clamped;
  }

 private:
  double A_[9];
};

}  // namespace internal
}  // namespace normal_fusion
