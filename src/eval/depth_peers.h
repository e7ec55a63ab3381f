// Normals from depth by OpenCV contrib's rgbd module (cv::rgbd::RgbdNormals),
// in the library's convention (include/normal_fusion/depth.h): the peers of
// the library's depth-to-normals estimators in `evaluate` and the benchmarks.
#pragma once

#include <string>
#include <vector>

#include "normal_fusion/types.h"

namespace normal_fusion {
namespace depth_peers {

/// The methods of cv::rgbd::RgbdNormals.
enum class OpenCvNormalMethod {
  kFals,     ///< RGBD_NORMALS_METHOD_FALS (least squares on the points)
  kLinemod,  ///< RGBD_NORMALS_METHOD_LINEMOD (depth gradient, fixed window)
  kSri,      ///< RGBD_NORMALS_METHOD_SRI (spherical range image)
};

/// "FALS", "LINEMOD" or "SRI".
std::string name(OpenCvNormalMethod method);
std::vector<OpenCvNormalMethod> allOpenCvMethods();

/// OpenCV's default window (pixels, one of 1, 3, 5, 7).
constexpr int kDefaultWindow = 5;

/// Normals of `depth_m` (one plane, metres along the optical axis; NaN, <= 0
/// or non-finite = no depth) by one RgbdNormals method with the given window
/// (1, 3, 5 or 7; LINEMOD's window is fixed by OpenCV and ignores it). The
/// result is in the depth's optical frame, unit, facing the camera (n . r <=
/// 0 with r = K^-1 (u, v, 1): OpenCV only makes n_z <= 0), NaN where the
/// pixel has no depth or OpenCV gives no finite normal. FALS and SRI get the
/// back-projected points P = z K^-1 (u, v, 1), LINEMOD the depth. Throws
/// InputError for a depth map without exactly one plane, an empty one, an
/// unusable K or another window.
NormalMap opencvDepthNormals(const ScalarMap& depth_m,
                             const CameraIntrinsics& K,
                             OpenCvNormalMethod method,
                             int window = kDefaultWindow);

}  // namespace depth_peers
}  // namespace normal_fusion
