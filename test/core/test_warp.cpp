// Rotation-compensated warm start: warping the previous frame's normals by the
// camera rotation predicts the current frame's normals.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>

#include "eval/synthetic.h"
#include "normal_fusion/errors.h"
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

/// A state of a scene's normals (with a few NaN holes) and random duals for
/// L inputs.
SolverState randomState(const NormalMap& normals, int L, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> dual(-1.0f, 1.0f);
  const int W = normals.width(), H = normals.height();
  SolverState state;
  state.normals = normals;
  state.dual_h = PlanarImage(W, H, 3);
  state.dual_v = PlanarImage(W, H, 3);
  state.dual_data.assign(L, PlanarImage(W, H, 3));
  for (PlanarImage* p : {&state.dual_h, &state.dual_v, &state.dual_data[0],
                         &state.dual_data[L - 1]}) {
    for (std::size_t i = 0; i < p->pixelCount() * 3; ++i)
      p->data()[i] = dual(rng);
  }
  for (int k = 0; k < 40; ++k) {
    const int i = static_cast<int>(rng() % normals.pixelCount());
    for (int c = 0; c < 3; ++c) state.normals.plane(c)[i] = NAN;
  }
  return state;
}

void expectSameImage(const PlanarImage& a, const PlanarImage& b,
                     const char* what) {
  ASSERT_TRUE(a.sameSize(b)) << what;
  for (std::size_t i = 0; i < a.pixelCount() * a.channels(); ++i) {
    const float x = a.data()[i], y = b.data()[i];
    if (std::isnan(x) || std::isnan(y)) {
      ASSERT_TRUE(std::isnan(x) && std::isnan(y)) << what << " at " << i;
    } else {
      ASSERT_NEAR(x, y, 1e-5f * std::max(1.0f, std::abs(y)))
          << what << " at " << i;
    }
  }
}

/// The live stream's warp (threads, reused scratch) writes exactly what the
/// per-pixel reference writes, frame after frame, duals included.
TEST(Warp, FastWarpEqualsTheReference) {
  const auto frames = synthetic::renderSequence(2, 96, 72, 4, 1.5);
  for (int threads : {1, 2, 3}) {
    SolverState fast = randomState(frames[0].normals_gt, 2, 7);
    SolverState reference = fast;
    SolverState scratch;
    for (std::size_t k = 1; k < frames.size(); ++k) {
      const auto R =
          synthetic::relativeRotation(frames[k].pose, frames[k - 1].pose);
      warpStateByRotation(fast, frames[k].K, R, scratch, threads);
      internal::warpStateByRotationReference(reference, frames[k].K, R);
      ASSERT_TRUE(fast.compatible(96, 72, 2));
      expectSameImage(fast.normals, reference.normals, "normals");
      expectSameImage(fast.dual_h, reference.dual_h, "p_h");
      expectSameImage(fast.dual_v, reference.dual_v, "p_v");
      for (int l = 0; l < 2; ++l) {
        expectSameImage(fast.dual_data[l], reference.dual_data[l], "q_l");
      }
    }
  }
  // DualWarp::kReset: the same normals, every dual zero.
  {
    SolverState fast = randomState(frames[0].normals_gt, 2, 11);
    SolverState reference = fast, scratch;
    const auto R = synthetic::relativeRotation(frames[1].pose, frames[0].pose);
    warpStateByRotation(fast, frames[1].K, R, scratch, 2, DualWarp::kReset);
    internal::warpStateByRotationReference(reference, frames[1].K, R);
    ASSERT_TRUE(fast.compatible(96, 72, 2));
    expectSameImage(fast.normals, reference.normals, "normals");
    for (const PlanarImage* p :
         {&fast.dual_h, &fast.dual_v, &fast.dual_data[0], &fast.dual_data[1]}) {
      for (std::size_t i = 0; i < p->pixelCount() * 3; ++i) {
        ASSERT_EQ(p->data()[i], 0.0f) << i;
      }
    }
  }
  // Without duals: normals warped, no duals.
  SolverState bare;
  bare.normals = frames[0].normals_gt;
  SolverState bare_reference = bare, scratch;
  const auto R = synthetic::relativeRotation(frames[1].pose, frames[0].pose);
  warpStateByRotation(bare, frames[1].K, R, scratch, 2);
  internal::warpStateByRotationReference(bare_reference, frames[1].K, R);
  expectSameImage(bare.normals, bare_reference.normals, "normals");
  EXPECT_TRUE(bare.dual_h.empty());
  EXPECT_TRUE(bare.dual_data.empty());
}

}  // namespace
}  // namespace normal_fusion
