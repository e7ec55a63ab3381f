// The comparison peers (OpenCV ximgproc filters on normal maps) do what users
// expect: denoise, keep unit length, fill small holes by normalized
// convolution.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "eval/peers.h"
#include "normal_fusion/errors.h"
#include "normal_fusion/metrics.h"
#include "test_util.h"

namespace normal_fusion {
namespace {

TEST(Peers, EachPeerDenoisesAndKeepsUnitLength) {
  NormalMap gt;
  FusionProblem problem = test::twoPlaneScene(96, 64, &gt);
  const NormalMap noisy = test::noisy(gt, 0.3, 21);
  const double psnr_noisy = psnr(noisy, gt);
  for (peers::PeerFilter filter : peers::allPeers()) {
    double best = -1e9;
    for (const peers::PeerSetting& setting : peers::settingsGrid(filter)) {
      const NormalMap out = peers::applyPeer(noisy, problem.image, setting);
      for (std::size_t i = 0; i < out.pixelCount(); ++i) {
        const float len2 = out.plane(0)[i] * out.plane(0)[i] +
                           out.plane(1)[i] * out.plane(1)[i] +
                           out.plane(2)[i] * out.plane(2)[i];
        ASSERT_NEAR(len2, 1.0f, 1e-4)
            << peers::name(filter) << " " << setting.label();
      }
      best = std::max(best, psnr(out, gt));
    }
    EXPECT_GT(best, psnr_noisy + 3.0) << peers::name(filter);
  }
}

TEST(Peers, HolesAreFilledByNormalizedConvolution) {
  NormalMap gt;
  FusionProblem problem = test::twoPlaneScene(64, 48, &gt);
  NormalMap holed = gt;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (int y = 20; y < 24; ++y) {
    for (int x = 5; x < 9; ++x) {
      for (int c = 0; c < 3; ++c) holed.at(c, y, x) = nan;
    }
  }
  for (peers::PeerFilter filter : peers::allPeers()) {
    const peers::PeerSetting setting = peers::settingsGrid(filter)[4];
    const NormalMap out = peers::applyPeer(holed, problem.image, setting);
    for (int y = 20; y < 24; ++y) {
      for (int x = 5; x < 9; ++x) {
        float d = 0.0f;
        for (int c = 0; c < 3; ++c) d += out.at(c, y, x) * gt.at(c, y, x);
        EXPECT_GT(d, 0.99f) << peers::name(filter) << " at " << x << "," << y;
      }
    }
  }
  EXPECT_THROW(
      peers::applyPeer(NormalMap(10, 10, 3), ColorImage(9, 10, 1),
                       peers::settingsGrid(peers::PeerFilter::kGuided)[0]),
      InputError);
}

}  // namespace
}  // namespace normal_fusion
