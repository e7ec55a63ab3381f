// Registration of depth-camera normals into the colour image (no ROS).
//
// When depth and colour come from two cameras, the normals computed in the
// depth camera's optical frame are moved into the colour camera: every depth
// pixel with a depth and a normal is back-projected, P_depth = z K_depth^-1
// (u, v, 1), transformed, P_rgb = R P_depth + t (T_rgb_depth, metres), and
// projected with K_rgb into the colour image; its normal is rotated, n_rgb =
// R n_depth, and flipped where it faces away from the colour camera (n_rgb .
// P_rgb > 0), so that the convention of depth.h (normals face the camera)
// holds in the colour frame too.
//
// Occlusion: a z-buffer keeps, per colour pixel, the surface nearest to the
// colour camera (smallest z_rgb); a depth pixel without a normal is not
// projected and hides nothing.
//
// Footprint (Splat):
//   k2x2: each point is written to the 2x2 colour pixels around its
//     projection (the four nearest pixel centres), under the z-buffer; this
//     closes the one-pixel cracks that appear when the colour grid is as fine
//     as or finer than the depth grid, at the cost of foreground edges up to
//     one pixel wider. Holes larger than that stay unknown.
//   kNearest: only the nearest colour pixel; no hole is filled, every pixel
//     shown is hit by a depth pixel. With T = I and K_rgb = K_depth it is the
//     identity (k2x2 is not: a pixel also gets its neighbours' points).
// Colour pixels that no depth pixel reaches are unknown: NaN normal, 0
// confidence, NaN depth. The confidence shown is the depth pixel's, not
// re-weighted for the colour camera's view.
//
// Lens distortion (lens_distortion.h): a camera's `distortion` is undone
// when the depth pixels are back-projected (each pixel's ray undistorted once
// and kept while the depth camera stays the same) and applied when the points
// are projected into the colour image; points beyond the colour image's
// undistorted border are dropped, and a model that folds back inside it is
// refused. The normals themselves are computed by depth.h on the depth pixels
// as a pinhole camera would: a rectified depth image (the usual case) needs
// nothing more.
#pragma once

#include <array>
#include <string>
#include <vector>

#include "normal_fusion/geometry.h"
#include "normal_fusion/lens_distortion.h"
#include "normal_fusion/types.h"

namespace normal_fusion {
namespace depth {

/// The transform between the cameras: the library's one pose type
/// (geometry.h), p_rgb = R p_depth + t, R row-major, t in metres.
using RigidTransform = Pose;

/// How a projected depth pixel covers the colour image (header comment).
enum class Splat {
  kNearest,  ///< "nearest"
  k2x2,      ///< "2x2"
};

/// "nearest" or "2x2"; throws ParameterError otherwise.
Splat splatFromString(const std::string& name);
std::string toString(Splat splat);

struct RegistrationSettings {
  Splat splat = Splat::k2x2;
  /// Flip normals that face away from the colour camera after the rotation.
  bool face_camera = true;
};

/// A camera of the registration: intrinsics (pinhole, no skew), image size
/// and lens distortion (none by default).
struct TargetCamera {
  TargetCamera() = default;
  TargetCamera(const CameraIntrinsics& K_, int width_, int height_,
               const LensDistortion& distortion_ = LensDistortion())
      : K(K_), width(width_), height(height_), distortion(distortion_) {}

  CameraIntrinsics K;
  int width = 0;
  int height = 0;
  LensDistortion distortion;
};

/// Registers depth-camera normals into a colour camera; keeps its z-buffer
/// between frames (no allocation when the colour size stays the same).
class DepthRegistration {
 public:
  explicit DepthRegistration(
      const RegistrationSettings& settings = RegistrationSettings())
      : settings_(settings) {}

  void setSettings(const RegistrationSettings& settings) {
    settings_ = settings;
  }
  const RegistrationSettings& settings() const { return settings_; }

  /// depth_m: one plane, metres, NaN (or <= 0, non-finite) = no depth;
  /// normals_depth: three planes at the depth's size, in the depth optical
  /// frame; confidence_depth: one plane at that size, or null. Writes
  /// normals_rgb (3 planes), and, when given, confidence_rgb (requires
  /// confidence_depth; the confidence of the pixel shown) and depth_rgb (the
  /// z_rgb of the surface shown), all at the colour size. Throws InputError
  /// for mismatched sizes, an unusable K (skew included) or a colour size
  /// below 1 x 1, ParameterError for a T_rgb_depth that is not a rotation
  /// and translation.
  void registerNormals(const ScalarMap& depth_m, const NormalMap& normals_depth,
                       const ScalarMap* confidence_depth,
                       const CameraIntrinsics& K_depth, const TargetCamera& rgb,
                       const RigidTransform& T_rgb_depth,
                       NormalMap& normals_rgb, ScalarMap* confidence_rgb,
                       ScalarMap* depth_rgb = nullptr);

  /// The same with the depth camera's distortion: `depth_camera` has the
  /// depth map's size. Throws InputError as above, and for a distortion that
  /// cannot be inverted at a depth pixel or folds back inside the colour
  /// image.
  void registerNormals(const ScalarMap& depth_m, const NormalMap& normals_depth,
                       const ScalarMap* confidence_depth,
                       const TargetCamera& depth_camera,
                       const TargetCamera& rgb,
                       const RigidTransform& T_rgb_depth,
                       NormalMap& normals_rgb, ScalarMap* confidence_rgb,
                       ScalarMap* depth_rgb = nullptr);

 private:
  void check(const ScalarMap& depth_m, const NormalMap& normals_depth,
             const ScalarMap* confidence_depth, const CameraIntrinsics& K_depth,
             const TargetCamera& rgb, const RigidTransform& T_rgb_depth,
             const ScalarMap* confidence_rgb) const;

  /// Fills rays_ for the depth camera unless it is the one they are for.
  void prepareRays(const TargetCamera& depth_camera);

  RegistrationSettings settings_;
  ScalarMap zbuffer_;  ///< z_rgb of the surface shown per colour pixel
  /// The first two entries of each depth pixel's ray (x, y at z = 1),
  /// undistorted; NaN where the distortion cannot be inverted.
  std::vector<double> rays_;
  TargetCamera rays_camera_;  ///< the depth camera rays_ belong to
  bool rays_valid_ = false;
};

/// One-shot form of DepthRegistration::registerNormals.
void registerNormals(const ScalarMap& depth_m, const NormalMap& normals_depth,
                     const ScalarMap* confidence_depth,
                     const CameraIntrinsics& K_depth, const TargetCamera& rgb,
                     const RigidTransform& T_rgb_depth,
                     const RegistrationSettings& settings,
                     NormalMap& normals_rgb, ScalarMap* confidence_rgb,
                     ScalarMap* depth_rgb = nullptr);

}  // namespace depth
}  // namespace normal_fusion
