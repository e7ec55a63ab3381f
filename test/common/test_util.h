// Small, self-contained scenes and helpers for the solver's unit tests.
#pragma once

#include <cmath>
#include <random>

#include "normal_fusion/solver.h"

namespace normal_fusion {
namespace test {

/// A W x H view of two planes meeting in a vertical crease at x = W/2, both
/// facing the camera; the image is bright on the left, dark on the right, so
/// the image edge coincides with the geometric one.
inline FusionProblem twoPlaneScene(int W, int H, NormalMap* gt) {
  FusionProblem problem;
  problem.K = CameraIntrinsics(0.9 * W, 0.9 * W, (W - 1) / 2.0, (H - 1) / 2.0);
  problem.image = ColorImage(W, H, 1);
  gt->resize(W, H, 3);
  const float a = 0.5f;
  const float left[3] = {a / std::sqrt(1 + a * a), 0.0f,
                         -1.0f / std::sqrt(1 + a * a)};
  const float right[3] = {-a / std::sqrt(1 + a * a), 0.0f,
                          -1.0f / std::sqrt(1 + a * a)};
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const bool is_left = x < W / 2;
      for (int c = 0; c < 3; ++c)
        gt->at(c, y, x) = is_left ? left[c] : right[c];
      problem.image.at(0, y, x) = is_left ? 0.8f : 0.3f;
    }
  }
  return problem;
}

/// A W x H view of a vertical cylinder filling the image: the normal turns
/// smoothly from 60 degrees left to 60 degrees right; shaded image.
inline FusionProblem cylinderScene(int W, int H, NormalMap* gt) {
  FusionProblem problem;
  problem.K = CameraIntrinsics(0.9 * W, 0.9 * W, (W - 1) / 2.0, (H - 1) / 2.0);
  problem.image = ColorImage(W, H, 1);
  gt->resize(W, H, 3);
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const float theta = (2.0f * x / (W - 1) - 1.0f) * 1.0472f;
      gt->at(0, y, x) = std::sin(theta);
      gt->at(1, y, x) = 0.0f;
      gt->at(2, y, x) = -std::cos(theta);
      problem.image.at(0, y, x) = 0.2f + 0.6f * std::cos(theta);
    }
  }
  return problem;
}

/// Random values in [-scale, scale] in every channel.
inline PlanarImage randomImage(int W, int H, int channels, std::uint64_t seed,
                               float scale = 1.0f) {
  PlanarImage image(W, H, channels);
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<float> dist(-scale, scale);
  for (std::size_t i = 0; i < image.pixelCount() * channels; ++i) {
    image.data()[i] = dist(rng);
  }
  return image;
}

/// The paper's noise model: n' = (n + N(0, sigma^2 I)) normalized.
inline NormalMap noisy(const NormalMap& n, double sigma, std::uint64_t seed) {
  NormalMap out(n.width(), n.height(), 3);
  std::mt19937_64 rng(seed);
  std::normal_distribution<float> dist(0.0f, static_cast<float>(sigma));
  for (std::size_t i = 0; i < n.pixelCount(); ++i) {
    float v[3];
    for (int c = 0; c < 3; ++c) v[c] = n.plane(c)[i] + dist(rng);
    const float len = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    for (int c = 0; c < 3; ++c) out.plane(c)[i] = v[c] / len;
  }
  return out;
}

/// Same size and every value equal, NaN equal to NaN.
inline bool identical(const PlanarImage& a, const PlanarImage& b) {
  if (!a.sameSize(b) || a.channels() != b.channels()) return false;
  for (std::size_t i = 0; i < a.pixelCount() * a.channels(); ++i) {
    const float u = a.data()[i], v = b.data()[i];
    if (!(u == v || (std::isnan(u) && std::isnan(v)))) return false;
  }
  return true;
}

/// Mean squared distance |a - b|^2 over pixels valid in both.
inline double meanSquaredError(const NormalMap& a, const NormalMap& b) {
  double sum = 0.0;
  int count = 0;
  for (std::size_t i = 0; i < a.pixelCount(); ++i) {
    if (!isValidNormal(a.plane(0)[i], a.plane(1)[i], a.plane(2)[i]) ||
        !isValidNormal(b.plane(0)[i], b.plane(1)[i], b.plane(2)[i])) {
      continue;
    }
    for (int c = 0; c < 3; ++c) {
      const double d = a.plane(c)[i] - b.plane(c)[i];
      sum += d * d;
    }
    ++count;
  }
  return count > 0 ? sum / count : 0.0;
}

}  // namespace test
}  // namespace normal_fusion
