// Edge-aware filters that people use today to clean normal maps (OpenCV's
// ximgproc module), applied the way users apply them: to the three channels,
// guided by the image, then renormalized. The comparison peers of `evaluate`.
#pragma once

#include <string>
#include <vector>

#include "normal_fusion/types.h"

namespace normal_fusion {
namespace peers {

enum class PeerFilter {
  kJointBilateral,      ///< cv::ximgproc::jointBilateralFilter
  kGuided,              ///< cv::ximgproc::guidedFilter
  kFastGlobalSmoother,  ///< cv::ximgproc::fastGlobalSmootherFilter (FGS)
  kDomainTransform,     ///< cv::ximgproc::dtFilter (normalized convolution)
};

/// One setting of a peer: two parameters whose meaning depends on the filter.
///  - joint bilateral: a = sigma_space (pixels; window 2 * ceil(2 a) + 1),
///    b = sigma_color (guide in [0, 1]);
///  - guided: a = radius (pixels), b = eps (guide in [0, 1]);
///  - FGS: a = lambda, b = sigma_color (8-bit guide units);
///  - domain transform: a = sigma_spatial (pixels), b = sigma_color ([0, 1]).
struct PeerSetting {
  PeerFilter filter = PeerFilter::kJointBilateral;
  double a = 0.0;
  double b = 0.0;
  std::string label() const;
};

std::string name(PeerFilter filter);
std::vector<PeerFilter> allPeers();

/// A small grid of settings around each filter's usual range.
std::vector<PeerSetting> settingsGrid(PeerFilter filter);

/// Filters a normal map guided by `guide` (1 or 3 planes in [0, 1]). Missing
/// pixels (NaN or zero) are handled by normalized convolution: the filter runs
/// on the valid normals (0 elsewhere) and on the validity mask, and their
/// ratio is renormalized, so holes are filled where the filter reaches. Pixels
/// the filter cannot reach stay missing (NaN). Throws InputError on size or
/// channel mismatch.
NormalMap applyPeer(const NormalMap& normals, const ColorImage& guide,
                    const PeerSetting& setting);

}  // namespace peers
}  // namespace normal_fusion
