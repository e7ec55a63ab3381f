#include "normal_fusion/types.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "normal_fusion/errors.h"

namespace normal_fusion {

PlanarImage::PlanarImage(int width, int height, int channels, float fill) {
  resize(width, height, channels);
  this->fill(fill);
}

namespace {

/// Throws InputError for a negative size.
void checkSize(int width, int height, int channels) {
  if (width < 0 || height < 0 || channels < 0) {
    std::ostringstream msg;
    msg << "PlanarImage: negative size " << width << "x" << height << "x"
        << channels;
    throw InputError(msg.str());
  }
}

}  // namespace

void PlanarImage::resize(int width, int height, int channels) {
  checkSize(width, height, channels);
  const std::size_t values =
      static_cast<std::size_t>(width) * height * channels;
  if (values < data_.capacity() / 4) {
    // Sized for a much larger image: a buffer of the new size replaces it
    // (a vector keeps its capacity when it shrinks).
    std::vector<float, AlignedAllocator<float>> smaller(values);
    data_.swap(smaller);
  }
  resizeKeepingCapacity(width, height, channels);
}

void PlanarImage::resizeKeepingCapacity(int width, int height, int channels) {
  checkSize(width, height, channels);
  width_ = width;
  height_ = height;
  channels_ = channels;
  data_.resize(static_cast<std::size_t>(width) * height * channels);
}

void PlanarImage::fill(float value) {
  std::fill(data_.begin(), data_.end(), value);
}

void CameraIntrinsics::validate() const {
  for (double k : K) {
    if (!std::isfinite(k)) {
      throw InputError("camera intrinsics: K has a non-finite entry");
    }
  }
  const double det = determinant(K);
  const double scale = std::max({std::abs(K[0]), std::abs(K[4]), 1e-300});
  if (!(std::abs(det) > 1e-12 * scale * scale)) {
    std::ostringstream msg;
    msg << "camera intrinsics: K is singular (fx = " << K[0]
        << ", fy = " << K[4] << ", det = " << det
        << "); expected fx, fy != 0 and K[2][2] = 1";
    throw InputError(msg.str());
  }
}

void CameraIntrinsics::validateForImage(int width, int height) const {
  validate();
  const Mat3 Kinv = inverse();
  // Beyond this the rays of the edge pixels overflow what the solver's float
  // arithmetic can normalize.
  constexpr double kMaxSlope = 1e4;
  const double us[2] = {-0.5, width - 0.5}, vs[2] = {-0.5, height - 0.5};
  for (double u : us) {
    for (double v : vs) {
      const Vec3 ray = multiply(Kinv, Vec3{{u, v, 1.0}});
      const double x = ray[0], y = ray[1], z = ray[2];
      const double sx = x / z, sy = y / z;
      if (!(z > 0.0) || !std::isfinite(sx) || !std::isfinite(sy) ||
          std::abs(sx) > kMaxSlope || std::abs(sy) > kMaxSlope) {
        std::ostringstream msg;
        msg << "camera intrinsics: the ray of pixel (" << u << ", " << v
            << ") of a " << width << "x" << height << " image is (" << x << ", "
            << y << ", " << z << ") (fx = " << K[0] << ", fy = " << K[4]
            << ", cx = " << K[2] << ", cy = " << K[5]
            << "); expected z > 0 and |x / z|, |y / z| <= " << kMaxSlope
            << " (a focal length and principal point that fit the image)";
        throw InputError(msg.str());
      }
    }
  }
}

Mat3 CameraIntrinsics::inverse() const {
  validate();
  return normal_fusion::inverse(K, determinant(K));
}

CameraIntrinsics CameraIntrinsics::scaled(double sx, double sy) const {
  CameraIntrinsics out = *this;
  // u' = sx (u + 0.5) - 0.5 applied to the first row, likewise v' to the
  // second.
  for (int c = 0; c < 3; ++c) {
    out.K[c] = sx * K[c] + (sx - 1.0) * 0.5 * K[6 + c];
    out.K[3 + c] = sy * K[3 + c] + (sy - 1.0) * 0.5 * K[6 + c];
  }
  return out;
}

Orientation Orientation::optical() { return Orientation(); }

Orientation Orientation::opticalFlipped() {
  Orientation o;
  o.M = {{-1, 0, 0, 0, -1, 0, 0, 0, -1}};
  return o;
}

Orientation Orientation::opengl() {
  Orientation o;
  o.M = {{1, 0, 0, 0, -1, 0, 0, 0, -1}};
  return o;
}

Orientation Orientation::fromString(const std::string& text) {
  if (text == "optical" || text.empty()) return optical();
  if (text == "optical_flipped") return opticalFlipped();
  if (text == "opengl") return opengl();
  std::string cleaned = text;
  std::replace(cleaned.begin(), cleaned.end(), ',', ' ');
  std::replace(cleaned.begin(), cleaned.end(), '[', ' ');
  std::replace(cleaned.begin(), cleaned.end(), ']', ' ');
  std::istringstream in(cleaned);
  Orientation o;
  for (float& m : o.M) {
    if (!(in >> m)) {
      throw ParameterError("orientation '" + text +
                           "': expected optical, optical_flipped, opengl or "
                           "nine numbers of a signed permutation matrix");
    }
  }
  std::string rest;
  if (in >> rest) {
    throw ParameterError("orientation '" + text + "': more than nine numbers");
  }
  o.validate();
  return o;
}

void Orientation::validate() const {
  for (int r = 0; r < 3; ++r) {
    int nonzero_row = 0;
    int nonzero_col = 0;
    for (int c = 0; c < 3; ++c) {
      const float a = M[r * 3 + c];
      const float b = M[c * 3 + r];
      if (!(a == 0.0f || a == 1.0f || a == -1.0f)) {
        throw ParameterError(
            "orientation: entries of a signed permutation matrix must be 0, 1 "
            "or -1");
      }
      nonzero_row += a != 0.0f;
      nonzero_col += b != 0.0f;
    }
    if (nonzero_row != 1 || nonzero_col != 1) {
      throw ParameterError(
          "orientation: expected one non-zero entry per row and column (a "
          "signed permutation matrix)");
    }
  }
}

}  // namespace normal_fusion
