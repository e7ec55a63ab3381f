// The paper's baseline: cross-bilateral filtering of a normal map guided by the
// image.
#pragma once

#include "normal_fusion/types.h"

namespace normal_fusion {

struct BilateralSettings {
  int half_window = 5;         ///< w: the window is (2w+1) x (2w+1)
  double sigma_spatial = 3.0;  ///< Gaussian on pixel distance, in pixels
  double sigma_intensity =
      0.1;  ///< Gaussian on guide intensity difference ([0,1] scale)
  int num_threads = 0;  ///< 0 = all hardware threads
};

/// Extrinsic mean: the weighted Euclidean mean of the valid neighbouring
/// normals, normalized. The guide is the image's luminance (1 or 3 planes).
/// Pixels with no valid neighbour stay missing (NaN).
NormalMap crossBilateralFilter(const NormalMap& normals,
                               const ColorImage& guide,
                               const BilateralSettings& settings);

}  // namespace normal_fusion
