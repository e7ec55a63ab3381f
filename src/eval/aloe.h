// Middlebury's Aloe pair (2006), as Debian's opencv-doc ships it: the left
// and right views and the left view's ground-truth disparity in whole pixels
// (0 where unknown), 1282 x 1110.
#pragma once

#include <string>

#include "normal_fusion/types.h"

namespace normal_fusion {
namespace aloe {

/// Where opencv-doc installs the files.
constexpr const char* kDefaultDirectory =
    "/usr/share/doc/opencv-doc/examples/data";

struct AloeSettings {
  std::string directory = kDefaultDirectory;
  /// The pair is reduced by this factor (area average), 1 .. 8.
  int downscale = 2;
  /// The files carry no calibration: the focal length of Middlebury's
  /// 2005 / 2006 rig (3740 px at full size) and z = f b / d without a
  /// disparity offset; a 40 mm baseline puts the scene at 0.7 - 3.5 m. The
  /// baseline only scales the depth (the normals do not depend on it).
  double focal_full_px = 3740.0;
  double baseline_m = 0.04;
  /// Half window of the ground truth's plane fit (pixels of the reduced
  /// size): the fit spans several whole-pixel steps of the disparity.
  int gt_window_radius = 8;
};

struct AloeData {
  bool found = false;
  std::string note;        ///< why not found: the missing file
  ColorImage left, right;  ///< reduced, 3 planes in [0, 1]
  /// Ground-truth disparity of the left view at the reduced size, in its
  /// pixels; NaN where unknown or where a reduced pixel spans a jump.
  ScalarMap disparity_gt;
  ScalarMap depth_gt;    ///< f b / d, NaN where unknown
  NormalMap normals_gt;  ///< the plane fit of the ground-truth disparity
  CameraIntrinsics K;    ///< of the reduced size, principal point centred
  double baseline_m = 0.0;
};

/// True when the three files are in `directory`.
bool available(const std::string& directory);

/// Loads and reduces the pair; found = false with a note when a file is
/// missing. Throws InputError for a file that cannot be decoded or images
/// of unequal size, ParameterError for settings out of range.
AloeData load(const AloeSettings& settings = AloeSettings());

/// Ground-truth normals from a disparity map: z = f b / d, then the
/// library's plane fit over (2 window_radius + 1)^2 pixels (inverse depth is
/// affine in the pixel on a plane, so this is a plane fit of the disparity),
/// without neighbours across a jump of more than 5 % of the depth.
NormalMap normalsFromDisparity(const ScalarMap& disparity_px,
                               const CameraIntrinsics& K, double baseline_m,
                               int window_radius);

}  // namespace aloe
}  // namespace normal_fusion
