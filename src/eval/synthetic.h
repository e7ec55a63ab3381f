// Synthetic indoor-like scenes with exact ground-truth normals; noise models.
//
// World frame of the scenes: x forward (into the room), y left, z up, metres.
// Every scene is a closed room, so with the camera inside it every pixel sees a
// surface (no background pixels). Shading is Lambertian: ambient light, one
// directional light and one point light, no shadows.
#pragma once

#include <cstdint>
#include <vector>

#include "normal_fusion/geometry.h"
#include "normal_fusion/types.h"

namespace normal_fusion {
namespace synthetic {

/// Camera pose (T_cam_world): world point X maps to camera point R X + t.
using Pose = normal_fusion::Pose;

/// Rotation of the camera from `prev` to `cur`: R_cur_prev = R_cur_world
/// R_prev_world^T (the argument warpStateByRotation takes).
Mat3 relativeRotation(const Pose& cur, const Pose& prev);

/// One rendered view.
struct Frame {
  ColorImage image;      ///< 3 planes R, G, B in [0, 1], textured and shaded
  NormalMap normals_gt;  ///< exact unit normals in the camera optical frame,
                         ///< facing the camera (n . K^-1 (u, v, 1) <= 0)
  ScalarMap depth;       ///< z-depth in metres (NaN where no surface)
  CameraIntrinsics K;
  Pose pose;
  double stamp = 0.0;  ///< seconds (sequences)
};

/// Scenes: 0 = room with boxes, 1 = room with cylinders and spheres (and a
/// pedestal box), 2 = cluttered mix (a table with boxes and a sphere on it, a
/// rotated box, spheres). Each has textured planes (checkerboard, stripes,
/// posters: image edges without geometric edges) and geometric edges of weak
/// contrast (a box turned by 45 degrees whose two front faces share albedo and
/// light).
constexpr int kNumScenes = 3;

/// Scenes of what robots see, beyond the three rooms (evaluate's textured,
/// curved, depth-camera and stereo cases):
/// kTexturedRoomScene: checkerboards of 5, 12 and 30 cm cells on the walls
///   and the floor, posters and a high-contrast random texture, boxes whose
///   faces carry them, and creases of weak contrast (two faces of one albedo
///   under the same light: a box turned by 45 degrees, a wedge on the floor).
/// kTexturedCornerScene: a room corner seen at an angle, with the same
///   kinds of texture on walls, floor and boxes, and weak creases alike.
/// kCurvedLargeScene, kCurvedSmallScene: cylinders, spheres and tori (lying
///   and standing) of large (0.2 - 0.6 m) and small (0.04 - 0.2 m) sizes in a
///   room with a random texture on its walls (for stereo).
constexpr int kTexturedRoomScene = 3;
constexpr int kTexturedCornerScene = 4;
constexpr int kCurvedLargeScene = 5;
constexpr int kCurvedSmallScene = 6;
/// Every scene id is in 0 .. kNumSceneIds - 1.
constexpr int kNumSceneIds = 7;

/// Depth quantization step of normalsFromNoisyDepth: one millimetre, as a
/// 16-bit depth image in millimetres stores it.
constexpr double kDepthQuantizationM = 0.001;

/// The camera pose renderScene(scene_id, width, height) uses: inside the room,
/// looking into it, slightly downwards. Throws ParameterError for an unknown
/// id.
Pose defaultPose(int scene_id);

/// Renders scene `scene_id` at width x height from defaultPose(scene_id), with
/// fx = fy = 0.9 * width, cx = (width - 1) / 2, cy = (height - 1) / 2 (pixel
/// centres at integer coordinates; horizontal field of view 2 atan(1 / 1.8),
/// about 58 degrees). One ray per pixel centre, no anti-aliasing.
/// Throws ParameterError for an unknown id or a size below 1 x 1.
Frame renderScene(int scene_id, int width, int height);

/// Renders scene `scene_id` from a given pose. Throws ParameterError when the
/// rotation is not orthonormal or the camera centre lies outside the room.
Frame renderScene(int scene_id, int width, int height, const Pose& pose);

/// renderScene with every material's texture replaced by its base colour:
/// the same geometry (normals, depth) without the texture's image edges.
Frame renderUntextured(int scene_id, int width, int height, const Pose& pose);

/// A slowly moving camera: `num_frames` views at `fps` (stamp k / fps), panning
/// about the world's vertical axis by `degrees_per_frame` per frame and moving
/// 2.5 mm per frame along a circle of 0.25 m radius. Frame 0 has the default
/// pose. Throws ParameterError for num_frames < 1, fps <= 0 or non-finite
/// values.
std::vector<Frame> renderSequence(int scene_id, int width, int height,
                                  int num_frames,
                                  double degrees_per_frame = 0.3,
                                  double fps = 30.0);

/// The camera's motion from `prev` to `cur`: T_cur_prev (X_cur = R X_prev +
/// t), the argument warpStateByMotion takes.
Pose relativePose(const Pose& cur, const Pose& prev);

/// A translating camera: `num_frames` views at `fps` (stamp k / fps) with the
/// default orientation, the camera moving by `step_cam` metres per frame
/// along its own axes (x right, y down, z forward) from the default pose.
/// Throws ParameterError for num_frames < 1, fps <= 0, non-finite values or
/// a camera centre outside the room.
std::vector<Frame> renderTranslation(int scene_id, int width, int height,
                                     int num_frames, const Vec3& step_cam,
                                     double fps = 30.0);

/// The paper's noise: n' = d / |d|, d = n + (r_x, r_y, r_z),
/// r_i ~ N(0, sigma^2). Missing pixels stay missing. Deterministic for a given
/// seed (the noise of a pixel does not depend on which others are missing).
NormalMap addPaperNoise(const NormalMap& normals, double sigma,
                        std::uint64_t seed);

/// Depth-camera noise on a z-depth map: z' = q round((z + e) / q) with
/// e ~ N(0, (depth_sigma_at_1m z^2)^2) and q = quantization_m (no rounding when
/// q = 0); then a `dropout` share of the pixels (in [0, 1]) set to NaN at
/// random. Missing (NaN) depths stay missing. Deterministic for a given seed.
ScalarMap addDepthNoise(const ScalarMap& depth, double depth_sigma_at_1m,
                        double quantization_m, double dropout,
                        std::uint64_t seed);

/// Normals of a z-depth map: back-projects the pixels with K, takes the cross
/// product of the central differences (P(u+1, v) - P(u-1, v)) x
/// (P(u, v+1) - P(u, v-1)), normalizes it and turns it to face the camera.
/// NaN at the image border and where the pixel or one of its four neighbours
/// lacks depth.
NormalMap normalsFromDepth(const ScalarMap& depth, const CameraIntrinsics& K);

/// Structured noise as a depth camera makes it:
/// normalsFromDepth(addDepthNoise(frame.depth, depth_sigma_at_1m,
/// kDepthQuantizationM, dropout, seed), frame.K).
NormalMap normalsFromNoisyDepth(const Frame& frame, double depth_sigma_at_1m,
                                double dropout, std::uint64_t seed);

/// Sparse and accurate: each pixel with a valid ground-truth normal is kept
/// with probability `density` (in [0, 1]) and gets paper noise of `sigma`; all
/// others are missing (NaN).
NormalMap sparseAccurate(const NormalMap& normals_gt, double density,
                         double sigma, std::uint64_t seed);

}  // namespace synthetic
}  // namespace normal_fusion
