#include "normal_fusion/lens_distortion.h"

#include <cmath>
#include <sstream>

#include "normal_fusion/errors.h"

namespace normal_fusion {

LensDistortion LensDistortion::fromCameraInfo(
    const std::string& distortion_model, const std::vector<double>& D,
    const std::string& name) {
  LensDistortion lens;
  for (std::size_t i = 0; i < D.size(); ++i) {
    if (!std::isfinite(D[i])) {
      std::ostringstream msg;
      msg << name << ": distortion coefficient D[" << i << "] = " << D[i]
          << "; expected finite coefficients";
      throw InputError(msg.str());
    }
  }
  bool all_zero = true;
  for (double d : D) all_zero = all_zero && d == 0.0;
  if (distortion_model.empty() || all_zero) return lens;
  std::size_t expected = 0;
  if (distortion_model == "plumb_bob") {
    lens.model = Model::kPlumbBob;
    expected = 5;
  } else if (distortion_model == "rational_polynomial") {
    lens.model = Model::kRationalPolynomial;
    expected = 8;
  } else {
    throw InputError(name + ": distortion model '" + distortion_model +
                     "' is not supported; expected plumb_bob, "
                     "rational_polynomial or a rectified image (D all zero)");
  }
  if (D.size() != expected) {
    std::ostringstream msg;
    msg << name << ": distortion model '" << distortion_model << "' with "
        << D.size() << " coefficients; expected " << expected;
    throw InputError(msg.str());
  }
  for (std::size_t i = 0; i < expected; ++i) lens.coefficients[i] = D[i];
  return lens;
}

bool LensDistortion::isIdentity() const {
  if (model == Model::kNone) return true;
  for (double c : coefficients) {
    if (c != 0.0) return false;
  }
  return true;
}

void LensDistortion::distort(double x, double y, double* x_d,
                             double* y_d) const {
  if (model == Model::kNone) {
    *x_d = x;
    *y_d = y;
    return;
  }
  const auto& k = coefficients;
  const double r2 = x * x + y * y, r4 = r2 * r2, r6 = r4 * r2;
  const double radial = (1.0 + k[0] * r2 + k[1] * r4 + k[4] * r6) /
                        (1.0 + k[5] * r2 + k[6] * r4 + k[7] * r6);
  *x_d = x * radial + 2.0 * k[2] * x * y + k[3] * (r2 + 2.0 * x * x);
  *y_d = y * radial + k[2] * (r2 + 2.0 * y * y) + 2.0 * k[3] * x * y;
}

bool LensDistortion::undistort(double x_d, double y_d, double* x,
                               double* y) const {
  *x = x_d;
  *y = y_d;
  if (model == Model::kNone) return true;
  // Newton on F(x, y) = distort(x, y) - (x_d, y_d), central-difference
  // Jacobian (the model is smooth and the steps are tiny).
  constexpr double h = 1e-7;
  for (int iteration = 0; iteration < 50; ++iteration) {
    double fx, fy;
    distort(*x, *y, &fx, &fy);
    fx -= x_d;
    fy -= y_d;
    if (std::abs(fx) < 1e-10 && std::abs(fy) < 1e-10) return true;
    double ax, ay, bx, by, cx, cy, dx, dy;
    distort(*x + h, *y, &ax, &ay);
    distort(*x - h, *y, &bx, &by);
    distort(*x, *y + h, &cx, &cy);
    distort(*x, *y - h, &dx, &dy);
    const double j11 = (ax - bx) / (2 * h), j21 = (ay - by) / (2 * h);
    const double j12 = (cx - dx) / (2 * h), j22 = (cy - dy) / (2 * h);
    const double det = j11 * j22 - j12 * j21;
    if (!(std::abs(det) > 1e-12) || !std::isfinite(det)) return false;
    *x -= (j22 * fx - j12 * fy) / det;
    *y -= (-j21 * fx + j11 * fy) / det;
    if (!std::isfinite(*x) || !std::isfinite(*y)) return false;
  }
  return false;
}

bool LensDistortion::monotonicUpTo(double r_max) const {
  if (isIdentity()) return true;
  constexpr int kSteps = 512;
  const double directions[4][2] = {
      {1, 0}, {0, 1}, {M_SQRT1_2, M_SQRT1_2}, {M_SQRT1_2, -M_SQRT1_2}};
  for (const auto& d : directions) {
    double previous = 0.0;
    for (int i = 1; i <= kSteps; ++i) {
      const double r = r_max * i / kSteps;
      double xd, yd;
      distort(r * d[0], r * d[1], &xd, &yd);
      const double r_d = std::hypot(xd, yd);
      if (!(r_d > previous)) return false;
      previous = r_d;
    }
  }
  return true;
}

std::string toString(LensDistortion::Model model) {
  switch (model) {
    case LensDistortion::Model::kPlumbBob:
      return "plumb_bob";
    case LensDistortion::Model::kRationalPolynomial:
      return "rational_polynomial";
    case LensDistortion::Model::kNone:
      break;
  }
  return "none";
}

}  // namespace normal_fusion
