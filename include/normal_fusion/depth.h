// Surface normals and their confidence from a depth image (no ROS).
//
// Depth follows REP 118: z along the optical axis (not the range along the
// ray); 16UC1 in millimetres with 0 = no depth, 32FC1 in metres with NaN (and
// 0, +-Inf) = no depth. Inside the library depth is a one-plane ScalarMap in
// metres with NaN where there is none.
//
// Normals are unit vectors in the depth image's optical frame (x right, y
// down, z forward), facing the camera (n . r <= 0, r = K^-1 (u, v, 1)), NaN
// where unknown (no depth at the pixel, too few neighbours).
//
// Methods:
//   central_difference: n ~ (P(u+1, v) - P(u-1, v)) x (P(u, v+1) - P(u, v-1))
//     of the back-projected points P = z K^-1 (u, v, 1). Fast; the four
//     neighbours are taken as they are, so at a depth discontinuity the normal
//     mixes both sides (its confidence is low there, see below).
//   plane_fit: a least-squares plane over the (2 window_radius + 1)^2 window
//     around the pixel, without the neighbours across a depth discontinuity
//     (|z - z_c| > tau(z_c)). The plane n . P = d is written in inverse depth,
//     1 / z = g . r (g = -n / d), which is linear in the pixel offsets:
//     1 / z(u + du, v + dv) = A du + B dv + C, and g = K^T (A, B, C - A u -
//     B v). Under the noise model sigma_z = a z^2, the inverse depth has the
//     constant standard deviation a, so this least-squares fit (along the
//     rays) is the maximum-likelihood plane; it is exact for planes.
//
// Discontinuity threshold (plane_fit's neighbours and the edge distance):
//   tau(z) = discontinuity_ratio z + discontinuity_noise_sigmas sqrt(2) a z^2
// (the relative jump plus the noise of a difference of two depths).
//
// Confidence, in [0, 1], 0 where the normal is unknown:
//   c = exp(-(sigma_n / s0)^2) * min(1, |n . v| + sigma_n) * min(1, d_edge / r)
//   sigma_n: the angular standard deviation (radians) of the normal from the
//     depth noise (sigma_{1/z} = a): with S the inverse of the fit's normal
//     matrix sum (du, dv, 1)(du, dv, 1)^T over the neighbours used (for
//     central_difference: its four neighbours), J = K^T [1 0 0; 0 1 0;
//     -u -v 1] and m = J^T n, sigma_n^2 = a^2 d^2 (tr(J S J^T) - m^T S m)
//     (first order; d = the plane's distance to the camera centre). It grows
//     about linearly with depth and falls with the window size.
//   |n . v|: v the unit viewing ray; 1 facing the camera, 0 at grazing view.
//     It is taken of the noisy normal, so it is known only to within
//     sigma_n and is raised by it (capped at 1): a normal that its noise
//     makes uncertain is discounted by the noise term, not again by a view
//     angle that the same noise drew.
//   d_edge: city-block distance in pixels from the pixel centre to the
//     nearest depth discontinuity between two 4-neighbours (0.5 next to one);
//     r = edge_distance (0: no edge factor).
//   s0 = normal_sigma_scale.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <string>

#include "normal_fusion/types.h"

namespace normal_fusion {
namespace depth {

/// How normals are computed from depth.
enum class NormalMethod {
  kCentralDifference,  ///< "central_difference"
  kPlaneFit,           ///< "plane_fit"
};

/// "central_difference" or "plane_fit"; throws ParameterError otherwise.
NormalMethod normalMethodFromString(const std::string& name);
std::string toString(NormalMethod method);

/// Every setting of depth-to-normals, with its default.
struct DepthNormalSettings {
  NormalMethod method = NormalMethod::kPlaneFit;
  /// plane_fit: the window is (2 window_radius + 1)^2 pixels; 1 .. 10.
  int window_radius = 2;
  /// Relative depth jump that counts as a discontinuity; > 0, <= 1.
  double discontinuity_ratio = 0.05;
  /// Noise part of the discontinuity threshold, in standard deviations of
  /// the difference of two depths; >= 0.
  double discontinuity_noise_sigmas = 3.0;
  /// a in sigma_z = a z^2 (1 / m): about 0.0014 .. 0.0029 for a Kinect v1
  /// (Khoshelham and Elberink 2012), 0.0025 a typical structured-light or
  /// stereo camera; >= 0 (0: no noise term in tau, sigma_n = 0).
  double noise_coefficient = 0.0025;
  /// s0 of the confidence (radians); > 0. Wide enough that normals of far
  /// or noisy depth keep part of their weight instead of none.
  double normal_sigma_scale = 2.0;
  /// r of the confidence's edge factor (pixels); >= 0, 0 = off.
  double edge_distance = 3.0;
  /// Threads for the rows (the results do not depend on it); 1 .. 256.
  int num_threads = 1;

  /// Throws ParameterError naming the first setting out of its range.
  void validate() const;
};

/// tau(z) of the header comment.
inline double discontinuityThreshold(double z, const DepthNormalSettings& s) {
  return s.discontinuity_ratio * z + s.discontinuity_noise_sigmas *
                                         std::sqrt(2.0) * s.noise_coefficient *
                                         z * z;
}

/// The confidence formula of the header comment: sigma_n in radians,
/// cos_view = |n . v| (raised by sigma_n here), edge_distance_px = d_edge.
/// NaN sigma_n gives 0.
inline double confidenceOf(double sigma_n, double cos_view,
                           double edge_distance_px,
                           const DepthNormalSettings& s) {
  if (!(sigma_n >= 0.0)) return 0.0;
  const double q = sigma_n / s.normal_sigma_scale;
  const double edge = s.edge_distance > 0.0
                          ? std::min(1.0, edge_distance_px / s.edge_distance)
                          : 1.0;
  const double c =
      std::exp(-q * q) * std::min(1.0, std::abs(cos_view) + sigma_n) * edge;
  return c >= 0.0 ? c : 0.0;
}

/// REP 118 16UC1: millimetres (unsigned 16-bit, host byte order), 0 = no
/// depth; to metres, NaN where missing. `data` points at row 0 (any
/// alignment), rows `step_bytes` apart. Returns the number of pixels with
/// depth. Throws InputError for a size below 1 x 1 or a step shorter than a
/// row.
std::size_t depthFromMillimetres(const void* data, int width, int height,
                                 std::size_t step_bytes, ScalarMap& depth_m);

/// REP 118 32FC1: metres; NaN, 0, negative and infinite values (REP 118: +Inf
/// too far, -Inf too near) are no depth (NaN). Same layout and errors as
/// depthFromMillimetres. Returns the number of pixels with depth.
std::size_t depthFromMetres(const void* data, int width, int height,
                            std::size_t step_bytes, ScalarMap& depth_m);

/// Computes normals (and their confidence) from depth; keeps its buffers
/// between frames (no allocation when the size stays the same).
class DepthNormalEstimator {
 public:
  /// Throws ParameterError for invalid settings.
  explicit DepthNormalEstimator(
      const DepthNormalSettings& settings = DepthNormalSettings());

  /// Throws ParameterError for invalid settings (the old ones then stay).
  void setSettings(const DepthNormalSettings& settings);
  const DepthNormalSettings& settings() const { return settings_; }

  /// depth_m: one plane, metres, NaN (or <= 0, non-finite) = no depth. K:
  /// pinhole with fx, fy > 0 and last row (0, 0, 1), finite rays at every
  /// pixel (CameraIntrinsics::validateForImage). Writes `normals` (3 planes)
  /// and, when given, `confidence` (1 plane), both at the depth's size.
  /// Throws InputError for a depth map without exactly one plane, an empty
  /// one, or an unusable K.
  void compute(const ScalarMap& depth_m, const CameraIntrinsics& K,
               NormalMap& normals, ScalarMap* confidence = nullptr);

 private:
  void prepare(const ScalarMap& depth_m, int pad);
  void edgeDistance();

  DepthNormalSettings settings_;
  int pad_ = 0;
  PlanarImage z_pad_;  ///< depth padded by pad_ on each side (NaN)
  PlanarImage w_pad_;  ///< 1 / z, padded alike
  PlanarImage edge_;   ///< d_edge per pixel, capped
};

/// One-shot form of DepthNormalEstimator::compute.
void depthToNormals(const ScalarMap& depth_m, const CameraIntrinsics& K,
                    const DepthNormalSettings& settings, NormalMap& normals,
                    ScalarMap* confidence = nullptr);

}  // namespace depth
}  // namespace normal_fusion
