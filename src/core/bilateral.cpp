// The paper's baseline: cross-bilateral filter of a normal map guided by the
// image's luminance, averaging with the extrinsic (Euclidean, normalized) mean.
#include "normal_fusion/bilateral.h"

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <limits>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include "normal_fusion/errors.h"
#include "normal_fusion/settings.h"

namespace normal_fusion {
namespace {

/// Entries of the intensity lookup table, spanning differences in [0, 1].
constexpr int kIntensityTableSize = 4096;
/// Floors of the two weight factors: their product stays a normal float, so a
/// pixel with at least one valid neighbour always gets a positive weight sum.
constexpr float kMinSpatialWeight = 1e-15f;
constexpr float kMinIntensityWeight = 1e-20f;

std::string sizeText(const PlanarImage& image) {
  std::ostringstream text;
  text << image.width() << "x" << image.height() << "x" << image.channels();
  return text.str();
}

void validate(const NormalMap& normals, const ColorImage& guide,
              const BilateralSettings& settings) {
  if (normals.channels() != 3) {
    throw InputError(
        "crossBilateralFilter: expected a 3-plane normal map, got " +
        sizeText(normals));
  }
  if ((guide.channels() != 1 && guide.channels() != 3) ||
      !guide.sameSize(normals)) {
    throw InputError(
        "crossBilateralFilter: expected a 1- or 3-plane guide of " +
        std::to_string(normals.width()) + "x" +
        std::to_string(normals.height()) + ", got " + sizeText(guide));
  }
  if (settings.half_window < 0) {
    throw ParameterError(
        "crossBilateralFilter: expected half_window >= 0, got " +
        std::to_string(settings.half_window));
  }
  if (!(settings.sigma_spatial > 0.0) ||
      !std::isfinite(settings.sigma_spatial)) {
    throw ParameterError(
        "crossBilateralFilter: expected a finite sigma_spatial > 0, got " +
        std::to_string(settings.sigma_spatial));
  }
  if (!(settings.sigma_intensity > 0.0) ||
      !std::isfinite(settings.sigma_intensity)) {
    throw ParameterError(
        "crossBilateralFilter: expected a finite sigma_intensity > 0, got " +
        std::to_string(settings.sigma_intensity));
  }
  if (settings.num_threads < 0) {
    throw ParameterError(
        "crossBilateralFilter: expected num_threads >= 0, got " +
        std::to_string(settings.num_threads));
  }
}

/// Guide luminance clamped to [0, 1]; non-finite values read as 0.
std::vector<float> luminanceOf(const ColorImage& guide) {
  const std::size_t count = guide.pixelCount();
  std::vector<float> luminance(count);
  for (std::size_t i = 0; i < count; ++i) {
    // Y = 0.299 R + 0.587 G + 0.114 B for a colour guide, the grey value else.
    const float value = guide.channels() == 3 ? 0.299f * guide.plane(0)[i] +
                                                    0.587f * guide.plane(1)[i] +
                                                    0.114f * guide.plane(2)[i]
                                              : guide.plane(0)[i];
    luminance[i] = value >= 0.0f ? (value <= 1.0f ? value : 1.0f) : 0.0f;
  }
  return luminance;
}

/// Spatial kernel exp(-(dx^2 + dy^2) / (2 sigma_S^2)) over the window, row by
/// row (side = 2 half_window + 1).
std::vector<float> spatialKernel(const BilateralSettings& settings) {
  const int w = settings.half_window;
  const int side = 2 * w + 1;
  std::vector<float> spatial_weight(static_cast<std::size_t>(side) * side);
  const double inv_two_var_s =
      1.0 / (2.0 * settings.sigma_spatial * settings.sigma_spatial);
  for (int dy = -w; dy <= w; ++dy) {
    for (int dx = -w; dx <= w; ++dx) {
      const double weight = std::exp(-(dx * dx + dy * dy) * inv_two_var_s);
      spatial_weight[(dy + w) * side + (dx + w)] =
          std::max(kMinSpatialWeight, static_cast<float>(weight));
    }
  }
  return spatial_weight;
}

/// Intensity table exp(-d^2 / (2 sigma_I^2)) for |I(x) - I(x')| = d in [0, 1].
std::vector<float> intensityTable(const BilateralSettings& settings) {
  std::vector<float> intensity_weight(kIntensityTableSize);
  const double inv_two_var_i =
      1.0 / (2.0 * settings.sigma_intensity * settings.sigma_intensity);
  for (int k = 0; k < kIntensityTableSize; ++k) {
    const double d = static_cast<double>(k) / (kIntensityTableSize - 1);
    intensity_weight[k] =
        std::max(kMinIntensityWeight,
                 static_cast<float>(std::exp(-d * d * inv_two_var_i)));
  }
  return intensity_weight;
}

/// Unit input normals, with missing ones stored as the zero vector so that
/// they drop out of the weighted sums; `valid` is 1 or 0.
struct UnitNormals {
  std::vector<float> x, y, z, valid;
};

UnitNormals unitNormalsOf(const NormalMap& normals) {
  const std::size_t count = normals.pixelCount();
  std::vector<float> unit_x(count), unit_y(count), unit_z(count), valid(count);
  for (std::size_t i = 0; i < count; ++i) {
    const float x = normals.plane(0)[i], y = normals.plane(1)[i],
                z = normals.plane(2)[i];
    if (isValidNormal(x, y, z)) {
      const float inv_len = 1.0f / std::sqrt(x * x + y * y + z * z);
      unit_x[i] = x * inv_len;
      unit_y[i] = y * inv_len;
      unit_z[i] = z * inv_len;
      valid[i] = 1.0f;
    } else {
      unit_x[i] = unit_y[i] = unit_z[i] = valid[i] = 0.0f;
    }
  }
  return {std::move(unit_x), std::move(unit_y), std::move(unit_z),
          std::move(valid)};
}

}  // namespace

NormalMap crossBilateralFilter(const NormalMap& normals,
                               const ColorImage& guide,
                               const BilateralSettings& settings) {
  validate(normals, guide, settings);
  const int width = normals.width();
  const int height = normals.height();
  const std::size_t count = normals.pixelCount();
  const float nan = std::numeric_limits<float>::quiet_NaN();
  NormalMap filtered(width, height, 3, nan);
  if (count == 0) return filtered;

  const int w = settings.half_window;
  const int side = 2 * w + 1;
  const std::vector<float> spatial_weight = spatialKernel(settings);
  const std::vector<float> intensity_weight = intensityTable(settings);
  const float table_scale = static_cast<float>(kIntensityTableSize - 1);
  const std::vector<float> luminance = luminanceOf(guide);
  const UnitNormals unit = unitNormalsOf(normals);

  const int threads = resolveThreadCount(settings.num_threads);
  const float* lum = luminance.data();
  const float* nx = unit.x.data();
  const float* ny = unit.y.data();
  const float* nz = unit.z.data();
  const float* ok = unit.valid.data();
  const float* kernel = spatial_weight.data();
  const float* table = intensity_weight.data();
  float* out_x = filtered.plane(0);
  float* out_y = filtered.plane(1);
  float* out_z = filtered.plane(2);

#pragma omp parallel for num_threads(threads) schedule(dynamic, 4)
  for (int y = 0; y < height; ++y) {
    const int y0 = std::max(0, y - w), y1 = std::min(height - 1, y + w);
    for (int x = 0; x < width; ++x) {
      const int x0 = std::max(0, x - w), x1 = std::min(width - 1, x + w);
      const float centre = lum[static_cast<std::size_t>(y) * width + x];
      float sum_x = 0.0f, sum_y = 0.0f, sum_z = 0.0f, sum_w = 0.0f;
      for (int yy = y0; yy <= y1; ++yy) {
        // Window row yy, columns x0..x1, and the matching kernel entries.
        const std::size_t first = static_cast<std::size_t>(yy) * width + x0;
        const float* kernel_row = kernel + (yy - y + w) * side + (x0 - x + w);
        for (int t = 0; t <= x1 - x0; ++t) {
          const std::size_t j = first + t;
          // Range weight from the table at |I(x) - I(x')| in [0, 1].
          const int k =
              static_cast<int>(std::fabs(lum[j] - centre) * table_scale + 0.5f);
          // Weight = spatial Gaussian x range Gaussian, zero for missing
          // normals.
          const float weight = kernel_row[t] * table[k] * ok[j];
          sum_x += weight * nx[j];
          sum_y += weight * ny[j];
          sum_z += weight * nz[j];
          sum_w += weight;
        }
      }
      // Extrinsic mean: the weighted Euclidean mean, projected onto the sphere.
      const float len =
          std::sqrt(sum_x * sum_x + sum_y * sum_y + sum_z * sum_z);
      const std::size_t i = static_cast<std::size_t>(y) * width + x;
      if (sum_w > 0.0f && len > 1e-6f * sum_w) {
        out_x[i] = sum_x / len;
        out_y[i] = sum_y / len;
        out_z[i] = sum_z / len;
      }
    }
  }
  return filtered;
}

}  // namespace normal_fusion
