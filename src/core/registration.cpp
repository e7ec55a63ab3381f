#include "normal_fusion/registration.h"

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
  check(depth_m, normals_depth, confidence_depth, K_depth, rgb, T_rgb_depth,
        confidence_rgb);
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
  const int footprint = settings_.splat == Splat::k2x2 ? 1 : 0;
  ray_x_.resize(static_cast<std::size_t>(depth_m.width()));
  for (int u = 0; u < depth_m.width(); ++u) {
    ray_x_[u] = (u - K_depth.cx()) / K_depth.fx();
  }
  for (int v = 0; v < depth_m.height(); ++v) {
    const double ray_y = (v - K_depth.cy()) / K_depth.fy();
    for (int u = 0; u < depth_m.width(); ++u) {
      const float z = depth_m.at(0, v, u);
      const float n[3] = {normals_depth.at(0, v, u), normals_depth.at(1, v, u),
                          normals_depth.at(2, v, u)};
      if (!(z > 0.0f) || !std::isfinite(z) || !isValidNormal(n[0], n[1], n[2]))
        continue;
      Point p = transformPixel(ray_x_[u], ray_y, z, n, T_rgb_depth);
      if (!(p.X_rgb[2] > 0.0)) continue;  // behind the colour camera
      // (u', v') = K_rgb P_rgb / z_rgb.
      const double u_rgb = K_rgb.fx() * p.X_rgb[0] / p.X_rgb[2] + K_rgb.cx();
      const double v_rgb = K_rgb.fy() * p.X_rgb[1] / p.X_rgb[2] + K_rgb.cy();
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
      for (int y = v0; y <= v0 + footprint; ++y) {
        for (int x = u0; x <= u0 + footprint; ++x) {
          if (x < 0 || y < 0 || x >= W || y >= H) continue;
          if (p.X_rgb[2] >= zbuffer_.at(0, y, x)) continue;  // nearer wins
          zbuffer_.at(0, y, x) = static_cast<float>(p.X_rgb[2]);
          for (int c = 0; c < 3; ++c) {
            normals_rgb.at(c, y, x) = static_cast<float>(p.n_rgb[c]);
          }
          if (confidence_rgb != nullptr) {
            confidence_rgb->at(0, y, x) = confidence_depth->at(0, v, u);
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
