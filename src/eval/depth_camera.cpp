// Depth-camera simulation: flying pixels, dropouts, z^2 noise, steps.
#include "eval/depth_camera.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <random>
#include <utility>

#include "eval/synthetic_internal.h"

namespace normal_fusion {
namespace synthetic {

using internal::kMissing;
using internal::requireRange;

void DepthCameraModel::validate() const {
  requireRange("DepthCameraModel: noise_coefficient", noise_coefficient, 0.0,
               1.0);
  requireRange("DepthCameraModel: quantization_m", quantization_m, 0.0, 1.0);
  requireRange("DepthCameraModel: edge_ratio", edge_ratio, 1e-6, 10.0);
  requireRange("DepthCameraModel: flying_share", flying_share, 0.0, 1.0);
  requireRange("DepthCameraModel: random_dropout", random_dropout, 0.0, 1.0);
  requireRange("DepthCameraModel: grazing_cos", grazing_cos, 0.0, 1.0);
  requireRange("DepthCameraModel: dark_luminance", dark_luminance, 0.0, 1.0);
}

DepthCameraModel structuredLightCamera() {
  DepthCameraModel m;
  m.name = "structured light";
  m.noise_coefficient = 0.0025;
  m.flying_share = 0.3;
  m.random_dropout = 0.01;
  return m;
}

DepthCameraModel timeOfFlightCamera() {
  DepthCameraModel m;
  m.name = "time of flight";
  m.noise_coefficient = 0.0012;
  m.flying_share = 0.8;
  m.random_dropout = 0.005;
  m.grazing_cos = 0.2;
  m.dark_luminance = 0.1;
  return m;
}

namespace {

/// Probability of a loss that fades in linearly below `threshold`.
double fadeLoss(double value, double threshold) {
  if (!(threshold > 0.0) || value >= threshold) return 0.0;
  return 1.0 - std::max(0.0, value) / threshold;
}

}  // namespace

ScalarMap simulateDepthCamera(const Frame& frame, const DepthCameraModel& model,
                              std::uint64_t seed) {
  model.validate();
  const ScalarMap& depth = frame.depth;
  const int width = depth.width(), height = depth.height();
  const std::array<double, 9> K_inv = frame.K.inverse();
  ScalarMap out(width, height, 1, kMissing);
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> gauss(0.0, 1.0);
  std::uniform_real_distribution<double> uniform01(0.0, 1.0);
  constexpr double kNoDepth = std::numeric_limits<double>::quiet_NaN();
  const auto z_at = [&](int y, int x) -> double {
    if (x < 0 || y < 0 || x >= width || y >= height) return kNoDepth;
    const double z = depth.at(0, y, x);
    return std::isfinite(z) && z > 0.0 ? z : kNoDepth;
  };
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      // Every draw for every pixel, so the stream stays aligned.
      const double g = gauss(rng);
      const double fly = uniform01(rng), mix = uniform01(rng);
      const double lose = uniform01(rng);
      double z = z_at(y, x);
      if (!std::isfinite(z)) continue;
      // Flying pixel: mixed with the neighbour across the largest jump.
      double z_other = z;
      for (const auto& o : {std::make_pair(0, 1), std::make_pair(0, -1),
                            std::make_pair(1, 0), std::make_pair(-1, 0)}) {
        const double zn = z_at(y + o.first, x + o.second);
        if (std::isfinite(zn) && std::abs(zn - z) > std::abs(z_other - z) &&
            std::abs(zn - z) > model.edge_ratio * std::min(z, zn)) {
          z_other = zn;
        }
      }
      if (z_other != z && fly < model.flying_share) {
        z = mix * z + (1.0 - mix) * z_other;
      }
      // Losses: at random, at grazing incidence, on dark surfaces.
      const Vec3 ray = internal::normalized(multiply(
          K_inv, Vec3{{static_cast<double>(x), static_cast<double>(y), 1.0}}));
      const double cos_view = std::abs(ray[0] * frame.normals_gt.at(0, y, x) +
                                       ray[1] * frame.normals_gt.at(1, y, x) +
                                       ray[2] * frame.normals_gt.at(2, y, x));
      const double luminance =
          (frame.image.at(0, y, x) + frame.image.at(1, y, x) +
           frame.image.at(2, y, x)) /
          3.0;
      const double p_keep = (1.0 - model.random_dropout) *
                            (1.0 - fadeLoss(cos_view, model.grazing_cos)) *
                            (1.0 - fadeLoss(luminance, model.dark_luminance));
      if (lose >= p_keep) continue;
      // Axial noise growing with z^2, then the camera's depth steps.
      z += model.noise_coefficient * z * z * g;
      if (model.quantization_m > 0.0) {
        z = model.quantization_m * std::round(z / model.quantization_m);
      }
      if (z > 0.0) out.at(0, y, x) = static_cast<float>(z);
    }
  }
  return out;
}

}  // namespace synthetic
}  // namespace normal_fusion
