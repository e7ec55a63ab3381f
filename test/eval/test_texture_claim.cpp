// Locks in that texture is not copied into the geometry: on one flat plane
// carrying a high-contrast checkerboard, with the normals a driver user
// computes from a structured-light camera's noisy depth, the regularizer's
// output turns no more from one cell to the next than inside a cell.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <vector>

#include "eval/synthetic.h"
#include "normal_fusion/depth.h"
#include "normal_fusion/solver.h"

namespace normal_fusion {
namespace {

constexpr int kWidth = 160;
constexpr int kHeight = 120;
constexpr int kCell = 10;  // checkerboard cell side, pixels

struct TexturedPlane {
  ColorImage image;
  CameraIntrinsics K;
  NormalMap normals_gt;
  ScalarMap depth_m;
};

/// A plane 1.5 m in front of the camera, turned from it by about 14 degrees,
/// under a checkerboard of kCell-pixel cells (grey 0.15 and 0.85).
TexturedPlane texturedPlane() {
  TexturedPlane scene;
  scene.K = CameraIntrinsics(0.9 * kWidth, 0.9 * kWidth, 0.5 * (kWidth - 1),
                             0.5 * (kHeight - 1));
  const double len = std::sqrt(0.25 * 0.25 + 0.2 * 0.2 + 1.0);
  const double n[3] = {0.25 / len, -0.2 / len, -1.0 / len};
  const double offset = n[2] * 1.5;  // n . X on the plane, X0 = (0, 0, 1.5)
  scene.image = ColorImage(kWidth, kHeight, 3);
  scene.normals_gt = NormalMap(kWidth, kHeight, 3);
  scene.depth_m = ScalarMap(kWidth, kHeight, 1);
  for (int v = 0; v < kHeight; ++v) {
    for (int u = 0; u < kWidth; ++u) {
      const double ray[3] = {(u - scene.K.cx()) / scene.K.fx(),
                             (v - scene.K.cy()) / scene.K.fy(), 1.0};
      const double t = offset / (n[0] * ray[0] + n[1] * ray[1] + n[2]);
      scene.depth_m.at(0, v, u) = static_cast<float>(t);
      const bool dark = ((u / kCell) + (v / kCell)) % 2 == 0;
      for (int c = 0; c < 3; ++c) {
        scene.image.at(c, v, u) = dark ? 0.15f : 0.85f;
        scene.normals_gt.at(c, v, u) = static_cast<float>(n[c]);
      }
    }
  }
  return scene;
}

double angleDeg(const NormalMap& a, int y0, int x0, int y1, int x1) {
  double dot = 0.0;
  for (int c = 0; c < 3; ++c) dot += a.at(c, y0, x0) * a.at(c, y1, x1);
  return std::acos(std::max(-1.0, std::min(1.0, dot))) * 180.0 / M_PI;
}

TEST(TextureClaim, NoNormalStepsAtTheTexturesCellBorders) {
  const TexturedPlane scene = texturedPlane();
  FusionProblem problem;
  problem.image = scene.image;
  problem.K = scene.K;
  // A structured-light camera's depth (sigma_z = 0.0025 z^2, 1 mm steps)
  // and the driver's default windowed plane fit.
  const ScalarMap noisy = synthetic::addDepthNoise(
      scene.depth_m, 0.0025, synthetic::kDepthQuantizationM, 0.0, 7);
  depth::DepthNormalSettings depth_settings;
  NormalMap input;
  depth::depthToNormals(noisy, scene.K, depth_settings, input);
  NormalInput normal_input;
  normal_input.normals = input;
  problem.inputs = {normal_input};
  const NormalMap out = Solver(SolverSettings()).solve(problem);

  // Mean turn between 4-neighbours that straddle a cell border and between
  // those inside one cell, away from the image border.
  double border_sum = 0.0, inside_sum = 0.0;
  int border_count = 0, inside_count = 0;
  for (int y = 4; y < kHeight - 4; ++y) {
    for (int x = 4; x < kWidth - 4; ++x) {
      for (const int d : {0, 1}) {
        const int y1 = y + d, x1 = x + 1 - d;
        const double turn = angleDeg(out, y, x, y1, x1);
        const bool border =
            (x / kCell != x1 / kCell) || (y / kCell != y1 / kCell);
        (border ? border_sum : inside_sum) += turn;
        ++(border ? border_count : inside_count);
      }
    }
  }
  const double border_turn = border_sum / border_count;
  const double inside_turn = inside_sum / inside_count;
  double error_sum = 0.0;
  for (int y = 0; y < kHeight; ++y) {
    for (int x = 0; x < kWidth; ++x) {
      double dot = 0.0;
      for (int c = 0; c < 3; ++c) {
        dot += out.at(c, y, x) * scene.normals_gt.at(c, y, x);
      }
      error_sum += std::acos(std::max(-1.0, std::min(1.0, dot)));
    }
  }
  std::printf(
      "turn across cell borders %.3f deg, inside cells %.3f deg, "
      "mean error %.3f deg\n",
      border_turn, inside_turn, error_sum / (kWidth * kHeight) * 180.0 / M_PI);
  // Copied texture shows as a step at every border (cells of their own
  // normal): the turn there many times the one inside.
  EXPECT_LT(border_turn, 1.5 * inside_turn + 0.05);
}

}  // namespace
}  // namespace normal_fusion
