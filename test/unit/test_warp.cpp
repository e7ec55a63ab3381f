// Rotation-compensated warm start: warping the previous frame's normals by the
// camera rotation predicts the current frame's normals.
#include <gtest/gtest.h>

#include <cmath>

#include "normal_fusion/errors.h"
#include "normal_fusion/synthetic.h"
#include "normal_fusion/warp.h"

namespace normal_fusion {
namespace {

/// Share of pixels whose normals agree within `degrees`.
double shareWithin(const NormalMap& a, const NormalMap& b, double degrees) {
  const double cos_limit = std::cos(degrees * M_PI / 180.0);
  int ok = 0;
  for (std::size_t i = 0; i < a.pixelCount(); ++i) {
    double d = 0.0;
    for (int c = 0; c < 3; ++c) d += a.plane(c)[i] * b.plane(c)[i];
    ok += d >= cos_limit;
  }
  return static_cast<double>(ok) / a.pixelCount();
}

TEST(Warp, RotationWarpPredictsTheNextFrame) {
  // 2 degrees apart: about 5 of the 160 columns enter from outside the
  // previous view and cannot be predicted.
  const auto frames = synthetic::renderSequence(1, 160, 120, 3, 1.0);
  const synthetic::Frame& prev = frames.front();
  const synthetic::Frame& cur = frames.back();
  SolverState state;
  state.normals = prev.normals_gt;
  state.dual_h = PlanarImage(160, 120, 3, 0.0f);
  state.dual_v = PlanarImage(160, 120, 3, 0.0f);
  state.dual_data.assign(1, PlanarImage(160, 120, 3, 0.0f));
  const double unwarped = shareWithin(prev.normals_gt, cur.normals_gt, 3.0);
  warpStateByRotation(state, cur.K,
                      synthetic::relativeRotation(cur.pose, prev.pose));
  const double warped = shareWithin(state.normals, cur.normals_gt, 3.0);
  EXPECT_GT(warped, 0.85);
  EXPECT_GT(warped, unwarped + 0.2);
  EXPECT_TRUE(state.compatible(160, 120, 1));
  // Unit normals where predicted; NaN only in the few uncovered columns.
  int uncovered = 0;
  for (std::size_t i = 0; i < state.normals.pixelCount(); ++i) {
    double len2 = 0.0;
    for (int c = 0; c < 3; ++c) {
      len2 += state.normals.plane(c)[i] * state.normals.plane(c)[i];
    }
    if (std::isnan(len2)) {
      ++uncovered;
    } else {
      ASSERT_NEAR(len2, 1.0, 1e-4);
    }
  }
  EXPECT_GT(uncovered, 0);
  EXPECT_LT(uncovered, 10 * 120);
}

TEST(Warp, IdentityKeepsTheStateAndBadRotationThrows) {
  const synthetic::Frame frame = synthetic::renderScene(0, 64, 48);
  SolverState state;
  state.normals = frame.normals_gt;
  const std::array<double, 9> I{{1, 0, 0, 0, 1, 0, 0, 0, 1}};
  warpStateByRotation(state, frame.K, I);
  for (std::size_t i = 0; i < state.normals.pixelCount() * 3; ++i) {
    ASSERT_NEAR(state.normals.data()[i], frame.normals_gt.data()[i], 1e-5);
  }
  const std::array<double, 9> not_rotation{{2, 0, 0, 0, 1, 0, 0, 0, 1}};
  EXPECT_THROW(warpStateByRotation(state, frame.K, not_rotation), InputError);
}

}  // namespace
}  // namespace normal_fusion
