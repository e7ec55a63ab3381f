// Lens distortion of a camera in the models of sensor_msgs/CameraInfo (no
// ROS): plumb_bob (k1 k2 p1 p2 k3) and rational_polynomial (k1 k2 p1 p2 k3
// k4 k5 k6), both the model of OpenCV's calibration. On normalized image
// coordinates (x, y) = (X / Z, Y / Z), with r^2 = x^2 + y^2:
//   radial = (1 + k1 r^2 + k2 r^4 + k3 r^6) / (1 + k4 r^2 + k5 r^4 + k6 r^6)
//   x_d = x radial + 2 p1 x y + p2 (r^2 + 2 x^2)
//   y_d = y radial + p1 (r^2 + 2 y^2) + 2 p2 x y
// and the pixel is (fx x_d + cx, fy y_d + cy). The inverse has no closed
// form: undistort() solves it by Newton's method.
#pragma once

#include <array>
#include <string>
#include <vector>

namespace normal_fusion {

struct LensDistortion {
  enum class Model {
    kNone,                ///< a rectified image: x_d = x
    kPlumbBob,            ///< "plumb_bob": k4 = k5 = k6 = 0
    kRationalPolynomial,  ///< "rational_polynomial"
  };
  Model model = Model::kNone;
  /// k1 k2 p1 p2 k3 k4 k5 k6 (the order of CameraInfo.D).
  std::array<double, 8> coefficients{};

  /// From CameraInfo's distortion_model and D. An empty model or an all-zero
  /// D is kNone (whatever the model's name: nothing to undo); plumb_bob takes
  /// 5 coefficients, rational_polynomial 8. Throws InputError (starting with
  /// `name`) for another model with a non-zero D, a wrong count or a
  /// non-finite coefficient.
  static LensDistortion fromCameraInfo(const std::string& distortion_model,
                                       const std::vector<double>& D,
                                       const std::string& name);

  /// No distortion at all (every coefficient zero, or kNone).
  bool isIdentity() const;

  /// (x_d, y_d) of (x, y), the header's equations.
  void distort(double x, double y, double* x_d, double* y_d) const;

  /// (x, y) with distort(x, y) = (x_d, y_d), by Newton's method from (x_d,
  /// y_d); false when it does not converge to 1e-10 (a point outside the
  /// region where the model is invertible).
  bool undistort(double x_d, double y_d, double* x, double* y) const;

  /// Whether the model maps radius r monotonically on [0, r_max] (along the
  /// axes and the diagonals): beyond the first turning point a polynomial
  /// model folds back, and points there would land inside the image.
  bool monotonicUpTo(double r_max) const;
};

/// "none", "plumb_bob" or "rational_polynomial".
std::string toString(LensDistortion::Model model);

}  // namespace normal_fusion
