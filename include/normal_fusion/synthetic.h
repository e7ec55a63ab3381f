// Synthetic indoor-like scenes with exact ground-truth normals, and noise models.
#pragma once

#include <cstdint>
#include <vector>

#include "normal_fusion/types.h"

namespace normal_fusion {
namespace synthetic {

/// Camera pose: world point X maps to camera point R_cam_world * X + t_cam_world.
struct Pose {
  std::array<double, 9> R_cam_world{{1, 0, 0, 0, 1, 0, 0, 0, 1}};
  std::array<double, 3> t_cam_world{{0, 0, 0}};
};

/// One rendered view.
struct Frame {
  ColorImage image;        ///< 3 planes R, G, B in [0, 1], textured and shaded
  NormalMap normals_gt;    ///< exact unit normals in the camera optical frame, facing the camera
  ScalarMap depth;         ///< z-depth in metres (NaN where no surface)
  CameraIntrinsics K;
  Pose pose;
  double stamp = 0.0;      ///< seconds (sequences)
};

/// Scenes: 0 = room with boxes, 1 = room with cylinders and spheres,
/// 2 = cluttered mix (boxes on a table, a rotated box, spheres). Each has
/// textured planes (image edges without geometric edges) and geometric edges of
/// weak contrast (neighbouring faces of similar albedo and light).
constexpr int kNumScenes = 3;

/// Renders scene `scene_id` at width x height (fx = fy = 0.9 * width... chosen so
/// that the field of view is about 60 degrees horizontally).
Frame renderScene(int scene_id, int width, int height);

/// Renders scene `scene_id` from a given pose (the default pose is that of renderScene).
Frame renderScene(int scene_id, int width, int height, const Pose& pose);

/// A slowly moving camera: `num_frames` views at `fps`, rotating by about
/// `degrees_per_frame` and translating a few millimetres per frame.
std::vector<Frame> renderSequence(int scene_id, int width, int height,
                                  int num_frames, double degrees_per_frame = 0.3,
                                  double fps = 30.0);

/// The paper's noise: n' = d / |d|, d = n + (r_x, r_y, r_z), r_i ~ N(0, sigma^2).
/// Missing pixels stay missing. Deterministic for a given seed.
NormalMap addPaperNoise(const NormalMap& normals, double sigma, std::uint64_t seed);

/// Structured noise as a depth camera makes it: Gaussian depth noise with
/// standard deviation depth_sigma_at_1m * z^2, quantization, then normals from
/// the cross product of central differences of back-projected points (a 3x3
/// neighbourhood), oriented to face the camera. Pixels whose neighbourhood
/// lacks depth are missing; `dropout` is the share of depth pixels lost at random.
NormalMap normalsFromNoisyDepth(const Frame& frame, double depth_sigma_at_1m,
                                double dropout, std::uint64_t seed);

/// Sparse and accurate: a `density` share of the pixels (in [0, 1]) keep the
/// ground truth with paper noise of `sigma`; all others are missing.
NormalMap sparseAccurate(const NormalMap& normals_gt, double density, double sigma,
                         std::uint64_t seed);

}  // namespace synthetic
}  // namespace normal_fusion
