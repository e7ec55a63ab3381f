// Stereo depth for the evaluation: a rectified pair rendered by the ray
// caster (the left camera the reference), OpenCV's semi-global matching,
// and disparity to depth.
#pragma once

#include <string>

#include "eval/synthetic.h"
#include "normal_fusion/types.h"

namespace normal_fusion {
namespace stereo {

/// A rectified pair: the right camera is the left one moved by baseline_m
/// along its x axis (same rotation and intrinsics).
struct StereoPair {
  synthetic::Frame left;  ///< the reference: ground truth lies here
  synthetic::Frame right;
  double baseline_m = 0.0;
};

/// The pose of the right camera: the centre moved by baseline_m along the
/// left camera's x axis (to the right in its image).
synthetic::Pose rightCameraPose(const synthetic::Pose& left, double baseline_m);

/// Renders scene_id's pair from its default pose (the left camera). Throws
/// ParameterError for a baseline outside (0, 1] m or a right camera outside
/// the room.
StereoPair renderStereoPair(int scene_id, int width, int height,
                            double baseline_m);
/// The same from a given left pose.
StereoPair renderStereoPair(int scene_id, int width, int height,
                            double baseline_m, const synthetic::Pose& left);

/// Semi-global matching (OpenCV StereoSGBM, its 3-way mode).
struct SgbmSettings {
  int num_disparities = 64;  ///< search range in pixels, a multiple of 16
  int block_size = 5;        ///< odd
  int uniqueness_ratio = 10;
  int speckle_window = 100;
  int speckle_range = 2;
  int disp12_max_diff = 1;
  /// P1 = p1_factor * block_size^2, P2 = p2_factor * block_size^2 (one
  /// channel: the images' luminance).
  int p1_factor = 8, p2_factor = 32;
};

/// Left-view disparity in pixels (1/16-pixel steps), NaN where SGBM gives
/// none. The images: 3 planes in [0, 1] (their luminance is matched), the
/// same size. Throws InputError for unequal sizes.
ScalarMap sgbmDisparity(const ColorImage& left, const ColorImage& right,
                        const SgbmSettings& settings = SgbmSettings());

/// Disparity of an image `factor` times larger, at the reduced size: a block's
/// mean divided by the factor where all its pixels have a disparity within
/// one pixel of each other, NaN elsewhere (a block across a jump or a hole).
ScalarMap reduceDisparity(const ScalarMap& disparity_px, int factor);

/// z = f b / d for d > 0, NaN elsewhere (a rectified pair, f in pixels).
ScalarMap depthFromDisparity(const ScalarMap& disparity_px, double focal_px,
                             double baseline_m);

/// d = f b / z for z > 0, NaN elsewhere.
ScalarMap disparityFromDepth(const ScalarMap& depth_m, double focal_px,
                             double baseline_m);

/// Correlation of the depth error e = (z - z_true) / z_true^2 between pixels
/// `lag` apart along the rows, over the pairs where both have depth: near 0 for
/// a depth camera's per-pixel noise, near 1 for stereo's blobs and streaks. NaN
/// with fewer than two pairs.
double errorCorrelation(const ScalarMap& depth_m, const ScalarMap& truth_m,
                        int lag);

}  // namespace stereo
}  // namespace normal_fusion
