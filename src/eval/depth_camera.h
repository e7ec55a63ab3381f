// Depth as structured-light and time-of-flight cameras deliver it: noise
// growing with z^2, millimetre steps, flying pixels along depth edges and
// dropouts (random, at grazing angles and on dark surfaces).
#pragma once

#include <cstdint>
#include <string>

#include "eval/synthetic.h"
#include "normal_fusion/types.h"

namespace normal_fusion {
namespace synthetic {

/// What the camera does to the true depth, in the order applied.
struct DepthCameraModel {
  std::string name;
  /// a in sigma_z = a z^2 (1 / m).
  double noise_coefficient = 0.0025;
  /// Depth step (metres); 0: none.
  double quantization_m = 0.001;
  /// A 4-neighbour deeper by more than this share of z makes a depth edge.
  double edge_ratio = 0.04;
  /// Share of the pixels next to a depth edge whose depth is a mix of both
  /// sides: z = t z + (1 - t) z_other, t uniform in [0, 1].
  double flying_share = 0.3;
  /// Share of the pixels lost at random.
  double random_dropout = 0.01;
  /// |n . v| below this is lost with probability 1 - |n . v| / grazing_cos
  /// (v the viewing ray): returns fade at grazing incidence.
  double grazing_cos = 0.25;
  /// Image luminance below this is lost with probability 1 - L /
  /// dark_luminance: dark surfaces return too little light.
  double dark_luminance = 0.08;

  /// Throws ParameterError naming the first value out of its range.
  void validate() const;
};

/// A structured-light camera (Kinect v1, RealSense-like): a = 0.0025 / m,
/// 1 mm steps, some flying pixels.
DepthCameraModel structuredLightCamera();
/// A time-of-flight camera: a = 0.0012 / m, 1 mm steps, many flying pixels
/// (each pixel integrates light from both sides of an edge).
DepthCameraModel timeOfFlightCamera();

/// The camera's depth of a rendered frame (NaN where lost); uses the frame's
/// depth, ground-truth normals (grazing angle) and image (dark surfaces).
/// Deterministic for a given seed; a pixel's draws do not depend on which
/// others are lost.
ScalarMap simulateDepthCamera(const Frame& frame, const DepthCameraModel& model,
                              std::uint64_t seed);

}  // namespace synthetic
}  // namespace normal_fusion
