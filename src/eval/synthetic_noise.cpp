// Noise models of the synthetic scenes (paper noise, depth-camera noise,
// sparse accurate samples) and the normals of a depth map.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <random>
#include <sstream>

#include "eval/synthetic.h"
#include "eval/synthetic_internal.h"
#include "normal_fusion/errors.h"

namespace normal_fusion {
namespace synthetic {

using namespace internal;  // NOLINT: the helpers shared with the ray caster

namespace {

/// Draws n' = (n + sigma g) / |n + sigma g|, g ~ N(0, I), in place.
void perturbNormal(double sigma, std::mt19937_64* rng,
                   std::normal_distribution<double>* gauss, float* n) {
  double d[3];
  for (int c = 0; c < 3; ++c) d[c] = n[c] + sigma * (*gauss)(*rng);
  if (sigma == 0.0) return;  // exact copy, the draws keep the stream aligned
  const double len = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
  if (!(len > 1e-12)) return;
  for (int c = 0; c < 3; ++c) n[c] = static_cast<float>(d[c] / len);
}

}  // namespace

NormalMap addPaperNoise(const NormalMap& normals, double sigma,
                        std::uint64_t seed) {
  requireNormalMap("addPaperNoise", normals);
  requireRange("addPaperNoise: sigma", sigma, 0.0, 1e6);
  NormalMap out = normals;
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> gauss(0.0, 1.0);
  float* px = out.plane(0);
  float* py = out.plane(1);
  float* pz = out.plane(2);
  for (std::size_t i = 0; i < out.pixelCount(); ++i) {
    float n[3] = {px[i], py[i], pz[i]};
    const bool valid = isValidNormal(n[0], n[1], n[2]);
    // Draw for every pixel so that a pixel's noise ignores the others' mask.
    perturbNormal(sigma, &rng, &gauss, n);
    if (!valid) continue;
    px[i] = n[0];
    py[i] = n[1];
    pz[i] = n[2];
  }
  return out;
}

ScalarMap addDepthNoise(const ScalarMap& depth, double depth_sigma_at_1m,
                        double quantization_m, double dropout,
                        std::uint64_t seed) {
  if (depth.channels() != 1) {
    std::ostringstream msg;
    msg << "addDepthNoise: expected a depth map of 1 channel, got "
        << depth.channels();
    throw InputError(msg.str());
  }
  requireRange("addDepthNoise: depth_sigma_at_1m", depth_sigma_at_1m, 0.0, 1e3);
  requireRange("addDepthNoise: quantization_m", quantization_m, 0.0, 1e3);
  requireRange("addDepthNoise: dropout", dropout, 0.0, 1.0);
  ScalarMap out = depth;
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> gauss(0.0, 1.0);
  std::uniform_real_distribution<double> uniform01(0.0, 1.0);
  float* z_out = out.data();
  for (std::size_t i = 0; i < out.pixelCount(); ++i) {
    const double g = gauss(rng);
    const double keep = uniform01(rng);
    const double z = z_out[i];
    if (!std::isfinite(z) || !(z > 0.0)) {
      z_out[i] = kMissing;
      continue;
    }
    // Axial noise grows with z^2: z + sigma_1m z^2 g.
    double z_noisy = z + depth_sigma_at_1m * z * z * g;
    // Quantization: nearest multiple of q.
    if (quantization_m > 0.0) {
      z_noisy = quantization_m * std::round(z_noisy / quantization_m);
    }
    const bool lost = keep < dropout || !(z_noisy > 0.0);
    z_out[i] = lost ? kMissing : static_cast<float>(z_noisy);
  }
  return out;
}

NormalMap normalsFromDepth(const ScalarMap& depth, const CameraIntrinsics& K) {
  if (depth.channels() != 1) {
    std::ostringstream msg;
    msg << "normalsFromDepth: expected a depth map of 1 channel, got "
        << depth.channels();
    throw InputError(msg.str());
  }
  const std::array<double, 9> K_inv = K.inverse();
  const int width = depth.width();
  const int height = depth.height();
  NormalMap normals(width, height, 3, kMissing);
  const auto valid_depth = [&](int y, int x) {
    const float z = depth.at(0, y, x);
    return std::isfinite(z) && z > 0.0f;
  };
  // Back-projection P(u, v) = z K^-1 (u, v, 1).
  const auto point = [&](int y, int x) {
    const Vec3 ray = multiply(
        K_inv, Vec3{{static_cast<double>(x), static_cast<double>(y), 1.0}});
    return scale(ray, static_cast<double>(depth.at(0, y, x)));
  };
#pragma omp parallel for schedule(static)
  for (int y = 1; y < height - 1; ++y) {
    for (int x = 1; x < width - 1; ++x) {
      if (!valid_depth(y, x) || !valid_depth(y, x - 1) ||
          !valid_depth(y, x + 1) || !valid_depth(y - 1, x) ||
          !valid_depth(y + 1, x)) {
        continue;
      }
      // Central differences along u and v, and their cross product.
      const Vec3 du = sub(point(y, x + 1), point(y, x - 1));
      const Vec3 dv = sub(point(y + 1, x), point(y - 1, x));
      Vec3 n = cross(du, dv);
      const double len = std::sqrt(dot(n, n));
      if (!(len > 0.0) || !std::isfinite(len)) continue;
      n = scale(n, 1.0 / len);
      // Face the camera: n . K^-1 (u, v, 1) <= 0.
      const Vec3 ray = multiply(
          K_inv, Vec3{{static_cast<double>(x), static_cast<double>(y), 1.0}});
      if (dot(n, ray) > 0.0) n = scale(n, -1.0);
      for (int c = 0; c < 3; ++c) {
        normals.at(c, y, x) = static_cast<float>(n[c]);
      }
    }
  }
  return normals;
}

NormalMap normalsFromNoisyDepth(const Frame& frame, double depth_sigma_at_1m,
                                double dropout, std::uint64_t seed) {
  return normalsFromDepth(addDepthNoise(frame.depth, depth_sigma_at_1m,
                                        kDepthQuantizationM, dropout, seed),
                          frame.K);
}

NormalMap sparseAccurate(const NormalMap& normals_gt, double density,
                         double sigma, std::uint64_t seed) {
  requireNormalMap("sparseAccurate", normals_gt);
  requireRange("sparseAccurate: density", density, 0.0, 1.0);
  requireRange("sparseAccurate: sigma", sigma, 0.0, 1e6);
  NormalMap out(normals_gt.width(), normals_gt.height(), 3, kMissing);
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> gauss(0.0, 1.0);
  std::uniform_real_distribution<double> uniform01(0.0, 1.0);
  for (std::size_t i = 0; i < out.pixelCount(); ++i) {
    float n[3] = {normals_gt.plane(0)[i], normals_gt.plane(1)[i],
                  normals_gt.plane(2)[i]};
    // Keep with probability `density`; draw for every pixel (mask-independent).
    const bool keep = uniform01(rng) < density;
    perturbNormal(sigma, &rng, &gauss, n);
    if (!keep || !isValidNormal(normals_gt.plane(0)[i], normals_gt.plane(1)[i],
                                normals_gt.plane(2)[i])) {
      continue;
    }
    for (int c = 0; c < 3; ++c) out.plane(c)[i] = n[c];
  }
  return out;
}

Mat3 relativeRotation(const Pose& cur, const Pose& prev) {
  return multiply(cur.R, transpose(prev.R));
}

}  // namespace synthetic
}  // namespace normal_fusion
