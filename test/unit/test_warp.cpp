// Rotation-compensated warm start: warping the previous frame's normals by the
// camera rotation predicts the current frame's normals.
#include <gtest/gtest.h>

#include <algorithm>
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
  // Unit normals where predicted; NaN only where the pixel comes from outside
  // the previous image or from between previous pixels more than
  // kMaxBlendDegrees apart (an edge of the map).
  const auto R = synthetic::relativeRotation(cur.pose, prev.pose);
  const auto K_inv = cur.K.inverse();
  const auto& Km = cur.K.K;
  const double cos_limit = std::cos(kMaxBlendDegrees * M_PI / 180.0);
  int uncovered = 0, at_edges = 0;
  for (int y = 0; y < 120; ++y) {
    for (int x = 0; x < 160; ++x) {
      double len2 = 0.0;
      for (int c = 0; c < 3; ++c) {
        len2 += state.normals.at(c, y, x) * state.normals.at(c, y, x);
      }
      if (!std::isnan(len2)) {
        ASSERT_NEAR(len2, 1.0, 1e-4);
        continue;
      }
      // Where the pixel comes from: u_prev ~ K R^T K^-1 (x, y, 1).
      const double r[3] = {K_inv[0] * x + K_inv[1] * y + K_inv[2],
                           K_inv[3] * x + K_inv[4] * y + K_inv[5],
                           K_inv[6] * x + K_inv[7] * y + K_inv[8]};
      double q[3];
      for (int i = 0; i < 3; ++i) {
        q[i] = R[i] * r[0] + R[3 + i] * r[1] + R[6 + i] * r[2];
      }
      const double w = Km[6] * q[0] + Km[7] * q[1] + Km[8] * q[2];
      const double u = (Km[0] * q[0] + Km[1] * q[1] + Km[2] * q[2]) / w;
      const double v = (Km[3] * q[0] + Km[4] * q[1] + Km[5] * q[2]) / w;
      if (!(u >= 0.0 && v >= 0.0 && u <= 159.0 && v <= 119.0)) {
        ++uncovered;
        continue;
      }
      const int x0 = static_cast<int>(u), y0 = static_cast<int>(v);
      const int x1 = std::min(x0 + 1, 159), y1 = std::min(y0 + 1, 119);
      const int xs[4] = {x0, x1, x0, x1}, ys[4] = {y0, y0, y1, y1};
      double min_dot = 1.0;
      for (int a = 0; a < 4; ++a) {
        for (int b = a + 1; b < 4; ++b) {
          double d = 0.0;
          for (int c = 0; c < 3; ++c) {
            d += prev.normals_gt.at(c, ys[a], xs[a]) *
                 prev.normals_gt.at(c, ys[b], xs[b]);
          }
          min_dot = std::min(min_dot, d);
        }
      }
      EXPECT_LT(min_dot, cos_limit) << "NaN at " << x << "," << y
                                    << " inside the previous image and "
                                       "not at an edge of its map";
      ++at_edges;
    }
  }
  EXPECT_GT(uncovered, 0);
  EXPECT_LT(uncovered, 10 * 120);
  EXPECT_GT(at_edges, 0);
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
