// Locks in the accuracy on what robots feed the fusion: with its default
// parameters the regularizer is ahead of every peer (OpenCV ximgproc joint
// bilateral, guided, fast global smoother, domain transform), each at its
// best setting of its grid, in PSNR and in mean angular error, on a small
// textured room seen by a structured-light camera (normals of its noisy
// depth by the driver's windowed plane fit), scored on the pixels with
// input as evaluate scores them.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "eval/depth_camera.h"
#include "eval/peers.h"
#include "eval/synthetic.h"
#include "normal_fusion/depth.h"
#include "normal_fusion/metrics.h"
#include "normal_fusion/solver.h"

namespace normal_fusion {
namespace {

constexpr int kWidth = 192;
constexpr int kHeight = 144;

TEST(RobotClaim, DefaultsBeatEveryPeerOnATexturedRoomsDepthNormals) {
  const synthetic::Frame frame =
      synthetic::renderScene(synthetic::kTexturedRoomScene, kWidth, kHeight);
  const synthetic::DepthCameraModel camera = synthetic::structuredLightCamera();
  const ScalarMap depth_m = synthetic::simulateDepthCamera(frame, camera, 11);
  depth::DepthNormalSettings depth_settings;
  depth_settings.noise_coefficient = camera.noise_coefficient;
  NormalMap input;
  depth::depthToNormals(depth_m, frame.K, depth_settings, input);
  // The pixels with input and ground truth.
  ScalarMap mask(kWidth, kHeight, 1);
  for (std::size_t i = 0; i < mask.pixelCount(); ++i) {
    mask.data()[i] = std::isfinite(input.plane(0)[i]) ? 1.0f : 0.0f;
  }
  FusionProblem problem;
  problem.image = frame.image;
  problem.K = frame.K;
  NormalInput normal_input;
  normal_input.normals = input;
  problem.inputs = {normal_input};
  const NormalMap out = Solver(SolverSettings()).solve(problem);
  const double reg_psnr = psnr(out, frame.normals_gt, mask);
  const double reg_angle = angularError(out, frame.normals_gt, mask).mean_deg;
  for (peers::PeerFilter filter : peers::allPeers()) {
    double best_psnr = -1e9, best_angle = 1e9;
    for (const peers::PeerSetting& setting : peers::settingsGrid(filter)) {
      const NormalMap filtered = peers::applyPeer(input, frame.image, setting);
      best_psnr = std::max(best_psnr, psnr(filtered, frame.normals_gt, mask));
      best_angle = std::min(
          best_angle, angularError(filtered, frame.normals_gt, mask).mean_deg);
    }
    std::printf("%s: best %.2f dB, %.2f deg; regularizer %.2f dB, %.2f deg\n",
                peers::name(filter).c_str(), best_psnr, best_angle, reg_psnr,
                reg_angle);
    EXPECT_GT(reg_psnr, best_psnr) << peers::name(filter);
    EXPECT_LT(reg_angle, best_angle) << peers::name(filter);
  }
}

}  // namespace
}  // namespace normal_fusion
