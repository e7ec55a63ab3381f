#include "normal_fusion/registration.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

#include "normal_fusion/errors.h"

namespace normal_fusion {
namespace depth {
namespace {

const float kNaN = std::numeric_limits<float>::quiet_NaN();
// The z-buffer's "nothing yet": any surface in front of the camera is nearer.
const float kFar = std::numeric_limits<float>::max();

/// K as the four numbers the projection uses; throws InputError for a K
/// with skew or a last row other than (0, 0, 1), which they cannot express.
void checkPinhole(const CameraIntrinsics& K, const char* which) {
  K.validate();
  if (K.K[1] != 0.0 || K.K[3] != 0.0 || K.K[6] != 0.0 || K.K[7] != 0.0 ||
      K.K[8] != 1.0 || !(K.fx() > 0.0) || !(K.fy() > 0.0)) {
    throw InputError(std::string("registration: ") + which +
                     " must be a pinhole K (fx, fy > 0, no skew, last row "
                     "0 0 1)");
  }
}

/// One depth pixel moved into the colour camera.
struct Point {
  double X_rgb[3];  ///< P_rgb, metres
  double n_rgb[3];  ///< R n_depth, facing the colour camera when asked
};

/// P_rgb = R z K_depth^-1 (u, v, 1) + t and n_rgb = R n_depth; (ray_x,
/// ray_y) = the first two entries of K_depth^-1 (u, v, 1).
Point transformPixel(double ray_x, double ray_y, float z,
                     const float n_depth[3], const RigidTransform& T) {
  const double X_depth[3] = {ray_x * z, ray_y * z, z};
  Point p;
  for (int r = 0; r < 3; ++r) {
    p.X_rgb[r] = T.t[r];
    p.n_rgb[r] = 0.0;
    for (int k = 0; k < 3; ++k) {
      p.X_rgb[r] += T.R[3 * r + k] * X_depth[k];
      p.n_rgb[r] += T.R[3 * r + k] * n_depth[k];
    }
  }
  return p;
}

bool sameCamera(const TargetCamera& a, const TargetCamera& b) {
  return a.K.K == b.K.K && a.width == b.width && a.height == b.height &&
         a.distortion.model == b.distortion.model &&
         a.distortion.coefficients == b.distortion.coefficients;
}

/// The squared radius (normalized coordinates, undistorted) that covers the
/// colour image with a two-pixel margin: the largest radius of its undistorted
/// border points. Throws InputError when the border cannot be undistorted or
/// the model folds back inside that radius.
double distortedFieldRadius2(const TargetCamera& rgb) {
  if (rgb.distortion.isIdentity()) return std::numeric_limits<double>::max();
  const CameraIntrinsics& K = rgb.K;
  const double u_max = rgb.width + 1.0, v_max = rgb.height + 1.0;
  double r2_max = 0.0;
  constexpr int kSteps = 16;
  for (int i = 0; i <= kSteps; ++i) {
    const double s = static_cast<double>(i) / kSteps;
    const double border[4][2] = {{-2.0 + s * (u_max + 2.0), -2.0},
                                 {-2.0 + s * (u_max + 2.0), v_max},
                                 {-2.0, -2.0 + s * (v_max + 2.0)},
                                 {u_max, -2.0 + s * (v_max + 2.0)}};
    for (const auto& px : border) {
      double x, y;
      if (!rgb.distortion.undistort((px[0] - K.cx()) / K.fx(),
                                    (px[1] - K.cy()) / K.fy(), &x, &y)) {
        throw InputError(
            "registration: the colour camera's distortion cannot be inverted "
            "at its image border");
      }
      r2_max = std::max(r2_max, x * x + y * y);
    }
  }
  if (!rgb.distortion.monotonicUpTo(std::sqrt(r2_max))) {
    throw InputError(
        "registration: the colour camera's distortion folds back inside its "
        "image; expected a model that is monotonic over the field of view");
  }
  return r2_max;
}

}  // namespace

Splat splatFromString(const std::string& name) {
  if (name == "nearest") return Splat::kNearest;
  if (name == "2x2") return Splat::k2x2;
  throw ParameterError("registration splat '" + name +
                       "': expected nearest or 2x2");
}

std::string toString(Splat splat) {
  return splat == Splat::kNearest ? "nearest" : "2x2";
}

void DepthRegistration::check(const ScalarMap& depth_m,
                              const NormalMap& normals_depth,
                              const ScalarMap* confidence_depth,
                              const CameraIntrinsics& K_depth,
                              const TargetCamera& rgb,
                              const RigidTransform& T_rgb_depth,
                              const ScalarMap* confidence_rgb) const {
  if (depth_m.channels() != 1 || depth_m.empty()) {
    throw InputError("registration: expected a depth map with one plane");
  }
  if (normals_depth.channels() != 3 || !normals_depth.sameSize(depth_m)) {
    throw InputError(
        "registration: expected three normal planes at the depth's size");
  }
  if (confidence_depth != nullptr && (confidence_depth->channels() != 1 ||
                                      !confidence_depth->sameSize(depth_m))) {
    throw InputError(
        "registration: expected one confidence plane at the depth's size");
  }
  if (confidence_rgb != nullptr && confidence_depth == nullptr) {
    throw InputError(
        "registration: a registered confidence needs the depth's confidence");
  }
  if (rgb.width < 1 || rgb.height < 1) {
    std::ostringstream msg;
    msg << "registration: colour size " << rgb.width << "x" << rgb.height
        << "; expected at least 1x1";
    throw InputError(msg.str());
  }
  checkPinhole(K_depth, "K_depth");
  checkPinhole(rgb.K, "K_rgb");
  validatePose(T_rgb_depth, "rigid transform");
}

void DepthRegistration::registerNormals(
    const ScalarMap& depth_m, const NormalMap& normals_depth,
    const ScalarMap* confidence_depth, const CameraIntrinsics& K_depth,
    const TargetCamera& rgb, const RigidTransform& T_rgb_depth,
    NormalMap& normals_rgb, ScalarMap* confidence_rgb, ScalarMap* depth_rgb) {
  registerNormals(depth_m, normals_depth, confidence_depth,
                  TargetCamera(K_depth, depth_m.width(), depth_m.height()), rgb,
                  T_rgb_depth, normals_rgb, confidence_rgb, depth_rgb);
}

void DepthRegistration::prepareRays(const TargetCamera& depth_camera) {
  if (rays_valid_ && sameCamera(rays_camera_, depth_camera)) return;
  const CameraIntrinsics& K = depth_camera.K;
  const int W = depth_camera.width, H = depth_camera.height;
  rays_.resize(2 * static_cast<std::size_t>(W) * H);
  for (int v = 0; v < H; ++v) {
    for (int u = 0; u < W; ++u) {
      // (x_d, y_d) = K^-1 (u, v, 1); the ray is its undistorted (x, y).
      const double x_d = (u - K.cx()) / K.fx(), y_d = (v - K.cy()) / K.fy();
      double x = kNaN, y = kNaN;
      if (!depth_camera.distortion.undistort(x_d, y_d, &x, &y)) x = y = kNaN;
      const std::size_t i = 2 * (static_cast<std::size_t>(v) * W + u);
      rays_[i] = x;
      rays_[i + 1] = y;
    }
  }
  rays_camera_ = depth_camera;
  rays_valid_ = true;
}

void DepthRegistration::registerNormals(
    const ScalarMap& depth_m, const NormalMap& normals_depth,
    const ScalarMap* confidence_depth, const TargetCamera& depth_camera,
    const TargetCamera& rgb, const RigidTransform& T_rgb_depth,
    NormalMap& normals_rgb, ScalarMap* confidence_rgb, ScalarMap* depth_rgb) {
  check(depth_m, normals_depth, confidence_depth, depth_camera.K, rgb,
        T_rgb_depth, confidence_rgb);
  if (depth_camera.width != depth_m.width() ||
      depth_camera.height != depth_m.height()) {
    throw InputError(
        "registration: the depth camera's size differs from the "
        "depth map's");
  }
  const double r2_max = distortedFieldRadius2(rgb);
  prepareRays(depth_camera);
  const int W = rgb.width, H = rgb.height;
  zbuffer_.resize(W, H, 1);
  zbuffer_.fill(kFar);
  normals_rgb.resize(W, H, 3);
  normals_rgb.fill(kNaN);
  if (confidence_rgb != nullptr) {
    confidence_rgb->resize(W, H, 1);
    confidence_rgb->fill(0.0f);
  }
  const CameraIntrinsics& K_rgb = rgb.K;
  const bool distorted_rgb = !rgb.distortion.isIdentity();
  const int footprint = settings_.splat == Splat::k2x2 ? 1 : 0;
  for (int v = 0; v < depth_m.height(); ++v) {
    for (int u = 0; u < depth_m.width(); ++u) {
      const float z = depth_m.at(0, v, u);
      const float n[3] = {normals_depth.at(0, v, u), normals_depth.at(1, v, u),
                          normals_depth.at(2, v, u)};
      if (!(z > 0.0f) || !std::isfinite(z) || !isValidNormal(n[0], n[1], n[2]))
        continue;
      const std::size_t ray =
          2 * (static_cast<std::size_t>(v) * depth_m.width() + u);
      if (!std::isfinite(rays_[ray])) continue;  // distortion not invertible
      Point p = transformPixel(rays_[ray], rays_[ray + 1], z, n, T_rgb_depth);
      if (!(p.X_rgb[2] > 0.0)) continue;  // behind the colour camera
      double x = p.X_rgb[0] / p.X_rgb[2], y = p.X_rgb[1] / p.X_rgb[2];
      if (distorted_rgb) {
        // Beyond the image's undistorted border the model may fold back.
        if (!(x * x + y * y <= r2_max)) continue;
        rgb.distortion.distort(x, y, &x, &y);
      }
      // (u', v') = K_rgb (x_d, y_d, 1).
      const double u_rgb = K_rgb.fx() * x + K_rgb.cx();
      const double v_rgb = K_rgb.fy() * y + K_rgb.cy();
      // Far outside the image (also keeps the int conversion defined).
      if (!(u_rgb > -2.0 && u_rgb < W + 1.0 && v_rgb > -2.0 && v_rgb < H + 1.0))
        continue;
      const int u0 = footprint ? static_cast<int>(std::floor(u_rgb))
                               : static_cast<int>(std::lround(u_rgb));
      const int v0 = footprint ? static_cast<int>(std::floor(v_rgb))
                               : static_cast<int>(std::lround(v_rgb));
      if (settings_.face_camera) {
        const double facing = p.n_rgb[0] * p.X_rgb[0] +
                              p.n_rgb[1] * p.X_rgb[1] + p.n_rgb[2] * p.X_rgb[2];
        if (facing > 0.0) {
          for (double& c : p.n_rgb) c = -c;
        }
      }
      for (int y_px = v0; y_px <= v0 + footprint; ++y_px) {
        for (int x_px = u0; x_px <= u0 + footprint; ++x_px) {
          if (x_px < 0 || y_px < 0 || x_px >= W || y_px >= H) continue;
          if (p.X_rgb[2] >= zbuffer_.at(0, y_px, x_px))
            continue;  // nearer wins
          zbuffer_.at(0, y_px, x_px) = static_cast<float>(p.X_rgb[2]);
          for (int c = 0; c < 3; ++c) {
            normals_rgb.at(c, y_px, x_px) = static_cast<float>(p.n_rgb[c]);
          }
          if (confidence_rgb != nullptr) {
            confidence_rgb->at(0, y_px, x_px) = confidence_depth->at(0, v, u);
          }
        }
      }
    }
  }
  if (depth_rgb != nullptr) {
    depth_rgb->resize(W, H, 1);
    const float* zb = zbuffer_.data();
    float* out = depth_rgb->data();
    for (std::size_t i = 0; i < zbuffer_.pixelCount(); ++i) {
      out[i] = zb[i] == kFar ? kNaN : zb[i];
    }
  }
}

void registerNormals(const ScalarMap& depth_m, const NormalMap& normals_depth,
                     const ScalarMap* confidence_depth,
                     const CameraIntrinsics& K_depth, const TargetCamera& rgb,
                     const RigidTransform& T_rgb_depth,
                     const RegistrationSettings& settings,
                     NormalMap& normals_rgb, ScalarMap* confidence_rgb,
                     ScalarMap* depth_rgb) {
  DepthRegistration registration(settings);
  registration.registerNormals(depth_m, normals_depth, confidence_depth,
                               K_depth, rgb, T_rgb_depth, normals_rgb,
                               confidence_rgb, depth_rgb);
}

}  // namespace depth
}  // namespace normal_fusion
