// Full-motion warm start: the previous map moved through its depth by the
// camera's rotation and translation, with a z-buffer.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>
#include <string>

#include "eval/synthetic.h"
#include "normal_fusion/errors.h"
#include "normal_fusion/warp.h"
#include "normal_fusion/warp_motion.h"
#include "test_util.h"

namespace normal_fusion {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

/// Random unit normals facing the camera, and duals of L inputs with random
/// values (all of W x H).
SolverState randomState(int W, int H, int L, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> uniform(-1.0f, 1.0f);
  SolverState state;
  state.resize(W, H, L);
  for (std::size_t i = 0; i < state.normals.pixelCount(); ++i) {
    float n[3] = {uniform(rng), uniform(rng), -1.5f};
    const float len = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    for (int c = 0; c < 3; ++c) state.normals.plane(c)[i] = n[c] / len;
  }
  auto fill = [&](PlanarImage& image) {
    for (std::size_t k = 0; k < 3 * image.pixelCount(); ++k) {
      image.data()[k] = uniform(rng);
    }
  };
  fill(state.dual_h);
  fill(state.dual_v);
  for (PlanarImage& q : state.dual_data) fill(q);
  return state;
}

bool isNaNPixel(const NormalMap& normals, int x, int y) {
  return std::isnan(normals.at(0, y, x)) && std::isnan(normals.at(1, y, x)) &&
         std::isnan(normals.at(2, y, x));
}

TEST(MotionWarp, TranslationOfAFrontoParallelPlaneShiftsTheMap) {
  // fx = 32 and z = 2 m: t = (0.1875, -0.125) m moves every pixel by exactly
  // (+3, -2) pixels (all values exact in binary).
  const int W = 48, H = 32, L = 1;
  const CameraIntrinsics K(32.0, 32.0, 23.5, 15.5);
  const SolverState previous = randomState(W, H, L, 7);
  const ScalarMap depth(W, H, 1, 2.0f);
  Pose T;
  T.t = {{0.1875, -0.125, 0.0}};
  SolverState state = previous;
  warpStateByMotion(state, depth, K, T);
  ASSERT_TRUE(state.compatible(W, H, L));
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const int sx = x - 3, sy = y + 2;
      if (sx < 0 || sy >= H) {
        EXPECT_TRUE(isNaNPixel(state.normals, x, y)) << x << "," << y;
        for (int c = 0; c < 3; ++c) {
          EXPECT_EQ(state.dual_h.at(c, y, x), 0.0f);
          EXPECT_EQ(state.dual_data[0].at(c, y, x), 0.0f);
        }
        continue;
      }
      for (int c = 0; c < 3; ++c) {
        EXPECT_NEAR(state.normals.at(c, y, x), previous.normals.at(c, sy, sx),
                    1e-6f)
            << x << "," << y;
        EXPECT_EQ(state.dual_v.at(c, y, x), previous.dual_v.at(c, sy, sx));
        EXPECT_EQ(state.dual_data[0].at(c, y, x),
                  previous.dual_data[0].at(c, sy, sx));
      }
    }
  }
}

TEST(MotionWarp, PureRotationAgreesWithTheRotationWarp) {
  // t = 0: the depth does not matter and both warps follow K R K^-1; they
  // differ in the sampling (nearest splat against a bilinear blend) only.
  const auto frames = synthetic::renderSequence(0, 96, 72, 2, 2.0);
  const Mat3 R = synthetic::relativeRotation(frames[1].pose, frames[0].pose);
  SolverState by_rotation;
  by_rotation.normals = frames[0].normals_gt;
  SolverState by_motion = by_rotation;
  warpStateByRotation(by_rotation, frames[1].K, R);
  Pose T;
  T.R = R;
  warpStateByMotion(by_motion, ScalarMap(96, 72, 1, 1.5f), frames[1].K, T);
  const double cos_limit = std::cos(1.0 * M_PI / 180.0);
  int compared = 0, agree = 0, motion_only_unknown = 0;
  for (int y = 3; y < 72 - 3; ++y) {
    for (int x = 3; x < 96 - 3; ++x) {
      if (isNaNPixel(by_rotation.normals, x, y)) continue;  // an edge
      if (isNaNPixel(by_motion.normals, x, y)) {
        ++motion_only_unknown;
        continue;
      }
      double dot = 0.0;
      for (int c = 0; c < 3; ++c) {
        dot += by_rotation.normals.at(c, y, x) * by_motion.normals.at(c, y, x);
      }
      ++compared;
      agree += dot >= cos_limit;
    }
  }
  EXPECT_EQ(motion_only_unknown, 0);
  EXPECT_GT(compared, 5000);
  EXPECT_GT(static_cast<double>(agree) / compared, 0.99);
}

/// A far wall (z = 4 m, normal (0, 0, -1)) behind a near patch (z = 1.25 m,
/// columns 16 .. 31 and rows 8 .. 23, normal n_patch), 64 x 32, fx = 32.
struct WallAndPatch {
  static constexpr int W = 64, H = 32;
  CameraIntrinsics K{32.0, 32.0, 31.5, 15.5};
  SolverState state;
  ScalarMap depth{W, H, 1, 4.0f};
  float n_patch[3] = {0.6f, 0.0f, -0.8f};

  WallAndPatch() {
    state.normals = NormalMap(W, H, 3, 0.0f);
    state.normals.fill(0.0f);
    for (int y = 0; y < H; ++y) {
      for (int x = 0; x < W; ++x) {
        const bool patch = x >= 16 && x < 32 && y >= 8 && y < 24;
        for (int c = 0; c < 3; ++c) {
          state.normals.at(c, y, x) =
              patch ? n_patch[c] : (c == 2 ? -1.0f : 0.0f);
        }
        if (patch) depth.at(0, y, x) = 1.25f;
      }
    }
  }
};

TEST(MotionWarp, TheNearSurfaceHidesTheFarOneAndDisocclusionsAreUnknown) {
  // t_x = 0.25 m: the wall moves by 2 pixels (onto pixel centres), the patch
  // by 6.4 (between them): the patch covers columns 22 .. 37 over the wall,
  // and the wall that it hid at columns 18 .. 21 has no previous observation.
  // The wall's splats lie nearer to the pixel centres: only the z-buffer
  // lets the patch win.
  WallAndPatch scene;
  Pose T;
  T.t = {{0.25, 0.0, 0.0}};
  warpStateByMotion(scene.state, scene.depth, scene.K, T);
  const NormalMap& n = scene.state.normals;
  for (int y = 8; y < 24; ++y) {
    for (int x = 18; x < 22; ++x) {
      EXPECT_TRUE(isNaNPixel(n, x, y)) << x << "," << y;
    }
    for (int x = 22; x < 38; ++x) {
      EXPECT_NEAR(n.at(0, y, x), scene.n_patch[0], 1e-6f) << x << "," << y;
      EXPECT_NEAR(n.at(2, y, x), scene.n_patch[2], 1e-6f) << x << "," << y;
    }
    for (int x = 38; x < WallAndPatch::W; ++x) {
      EXPECT_NEAR(n.at(2, y, x), -1.0f, 1e-6f) << x << "," << y;
    }
    EXPECT_TRUE(isNaNPixel(n, 0, y));  // from outside the previous view
    EXPECT_NEAR(n.at(2, y, 17), -1.0f, 1e-6f);
  }
}

TEST(MotionWarp, PixelsWithoutPreviousDepthPredictNothing) {
  WallAndPatch scene;
  for (int y = 0; y < WallAndPatch::H; ++y) {
    for (int x = 40; x < 48; ++x) scene.depth.at(0, y, x) = kNaN;
  }
  Pose T;  // no motion: each pixel where it was, if it has depth
  warpStateByMotion(scene.state, scene.depth, scene.K, T);
  for (int y = 0; y < WallAndPatch::H; ++y) {
    for (int x = 0; x < WallAndPatch::W; ++x) {
      EXPECT_EQ(isNaNPixel(scene.state.normals, x, y), x >= 40 && x < 48)
          << x << "," << y;
    }
  }
}

TEST(MotionWarp, FastWarpEqualsTheReference) {
  // A general motion (rotation and translation, splats between pixel
  // centres) of a rendered scene with its depth, some of it missing.
  const auto frames = synthetic::renderSequence(2, 48, 36, 2, 1.5);
  Pose T = synthetic::relativePose(frames[1].pose, frames[0].pose);
  T.t[0] += 0.03;
  T.t[2] -= 0.05;
  ScalarMap depth = frames[0].depth;
  for (int x = 0; x < 48; ++x) depth.at(0, 20, x) = kNaN;
  SolverState previous = randomState(48, 36, 2, 11);
  previous.normals = frames[0].normals_gt;
  SolverState reference = previous;
  internal::warpStateByMotionReference(reference, depth, frames[1].K, T);
  MotionWarpScratch scratch;
  for (int threads : {1, 3}) {
    SolverState fast = previous;
    warpStateByMotion(fast, depth, frames[1].K, T, scratch, threads);
    EXPECT_TRUE(test::identical(fast.normals, reference.normals)) << threads;
    EXPECT_TRUE(test::identical(fast.dual_h, reference.dual_h)) << threads;
    EXPECT_TRUE(test::identical(fast.dual_v, reference.dual_v)) << threads;
    EXPECT_TRUE(test::identical(fast.dual_data[1], reference.dual_data[1]));
  }
  // Reset duals: the same normals, zero duals.
  SolverState reset = previous;
  warpStateByMotion(reset, depth, frames[1].K, T, scratch, 2, DualWarp::kReset);
  EXPECT_TRUE(test::identical(reset.normals, reference.normals));
  EXPECT_TRUE(test::identical(reset.dual_h, PlanarImage(48, 36, 3, 0.0f)));
  EXPECT_TRUE(
      test::identical(reset.dual_data[0], PlanarImage(48, 36, 3, 0.0f)));
  // Some pixels predicted, some not (disoccluded, entering the view).
  int unknown = 0;
  for (int y = 0; y < 36; ++y) {
    for (int x = 0; x < 48; ++x) unknown += isNaNPixel(reference.normals, x, y);
  }
  EXPECT_GT(unknown, 0);
  EXPECT_LT(unknown, 48 * 36 / 4);
}

TEST(MotionWarp, AStreamReusesTheScratchBuffers) {
  WallAndPatch scene;
  scene.state.resize(WallAndPatch::W, WallAndPatch::H, 1);
  Pose T;
  T.t = {{0.01, 0.0, -0.02}};
  MotionWarpScratch scratch;
  warpStateByMotion(scene.state, scene.depth, scene.K, T, scratch, 2);
  const float* a = scene.state.normals.data();
  const float* b = scratch.state.normals.data();
  const std::uint32_t* z = scratch.nearest_depth_bits.data();
  scene.state.resize(WallAndPatch::W, WallAndPatch::H, 1);  // solver's duals
  for (int k = 0; k < 2; ++k) {
    warpStateByMotion(scene.state, scene.depth, scene.K, T, scratch, 2);
    EXPECT_EQ(scene.state.normals.data(), k == 0 ? b : a);
    EXPECT_EQ(scratch.state.normals.data(), k == 0 ? a : b);
    EXPECT_EQ(scratch.nearest_depth_bits.data(), z);
  }
}

TEST(MotionWarp, BadInputsThrowWithAClearMessage) {
  WallAndPatch scene;
  auto message = [&](const ScalarMap& depth, const Pose& T) -> std::string {
    SolverState state = scene.state;
    try {
      warpStateByMotion(state, depth, scene.K, T);
    } catch (const InputError& e) {
      return e.what();
    }
    return "no error";
  };
  Pose T;
  EXPECT_NE(message(ScalarMap(32, 32, 1, 1.0f), T)
                .find("previous depth is 32x32 with 1 plane(s); expected one "
                      "plane of 64x32"),
            std::string::npos);
  EXPECT_NE(message(ScalarMap(64, 32, 3, 1.0f), T).find("previous depth"),
            std::string::npos);
  Pose scaled;
  scaled.R = {{2, 0, 0, 0, 1, 0, 0, 0, 1}};
  EXPECT_NE(message(scene.depth, scaled).find("R is not a rotation matrix"),
            std::string::npos);
  Pose infinite;
  infinite.t[1] = std::numeric_limits<double>::infinity();
  EXPECT_NE(message(scene.depth, infinite).find("t_cur_prev has a non-finite"),
            std::string::npos);
  Pose nan_t;
  nan_t.t[2] = std::numeric_limits<double>::quiet_NaN();
  EXPECT_NE(message(scene.depth, nan_t).find("non-finite"), std::string::npos);
  SolverState empty;
  EXPECT_THROW(warpStateByMotion(empty, scene.depth, scene.K, T), InputError);
}

}  // namespace
}  // namespace normal_fusion
