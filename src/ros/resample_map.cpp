// Resampling of maps of another resolution than the image (conversions.h).
#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

#include "normal_fusion/errors.h"
#include "normal_fusion/ros/conversions.h"

namespace normal_fusion {
namespace node {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

std::string sizeText(int width, int height) {
  return std::to_string(width) + "x" + std::to_string(height);
}

/// The source samples around target pixel `t` along one axis (scale = source
/// size / target size, n = source size): the source coordinate of the target
/// pixel's centre, scale (t + 0.5) - 0.5 clamped to [0, n - 1], split into
/// the neighbours i0, i1 and the fraction f towards i1.
struct Bracket {
  double coordinate;
  int i0, i1;
  float f;
};
inline Bracket bracket(double scale, int t, int n) {
  const double c = std::min(std::max(scale * (t + 0.5) - 0.5, 0.0), n - 1.0);
  const int i0 = static_cast<int>(c);
  return {c, i0, std::min(i0 + 1, n - 1), static_cast<float>(c - i0)};
}

/// The source with its invalid normals zeroed, plus a 0/1 validity plane (4
/// planes).
void maskInvalidNormals(const PlanarImage& source, PlanarImage& masked) {
  masked.resize(source.width(), source.height(), 4);
  const std::size_t n = source.pixelCount();
  for (std::size_t i = 0; i < n; ++i) {
    const float x = source.plane(0)[i], y = source.plane(1)[i],
                z = source.plane(2)[i];
    const bool ok = isValidNormal(x, y, z);
    masked.plane(0)[i] = ok ? x : 0.0f;
    masked.plane(1)[i] = ok ? y : 0.0f;
    masked.plane(2)[i] = ok ? z : 0.0f;
    masked.plane(3)[i] = ok ? 1.0f : 0.0f;
  }
}

/// Bilinear resampling of a normal map, branch-free: the source copied with
/// its invalid normals zeroed plus a 0/1 validity plane (`masked`, 4
/// planes), then each target pixel the bilinear sum of its four neighbours
/// (an invalid one adds exact zeros, as if skipped), renormalized, NaN where
/// no neighbour with weight is valid.
void resampleNormalsBilinear(const PlanarImage& source, double sx, double sy,
                             PlanarImage& target, int threads,
                             PlanarImage* scratch) {
  const int w = source.width(), h = source.height();
  const int width = target.width(), height = target.height();
  PlanarImage local;
  PlanarImage& masked = scratch != nullptr ? *scratch : local;
  maskInvalidNormals(source, masked);
  const float* mx = masked.plane(0);
  const float* my = masked.plane(1);
  const float* mz = masked.plane(2);
  const float* mv = masked.plane(3);
#pragma omp parallel for num_threads(std::max(1, threads)) schedule(static)
  for (int y = 0; y < height; ++y) {
    const Bracket v = bracket(sy, y, h);
    const float fy = v.f;
    const std::size_t r0 = static_cast<std::size_t>(v.i0) * w;
    const std::size_t r1 = static_cast<std::size_t>(v.i1) * w;
    float* tx = target.plane(0) + static_cast<std::size_t>(y) * width;
    float* ty = target.plane(1) + static_cast<std::size_t>(y) * width;
    float* tz = target.plane(2) + static_cast<std::size_t>(y) * width;
    for (int x = 0; x < width; ++x) {
      const Bracket u = bracket(sx, x, w);
      const float fx = u.f;
      const std::size_t i[4] = {r0 + u.i0, r0 + u.i1, r1 + u.i0, r1 + u.i1};
      const float wk[4] = {(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy,
                           fx * fy};
      float ax = 0.0f, ay = 0.0f, az = 0.0f, total = 0.0f;
      for (int k = 0; k < 4; ++k) {
        ax += wk[k] * mx[i[k]];
        ay += wk[k] * my[i[k]];
        az += wk[k] * mz[i[k]];
        total += wk[k] * mv[i[k]];
      }
      // Back to unit length (the weighted mean of unit vectors is shorter).
      const float length = std::sqrt(ax * ax + ay * ay + az * az);
      const bool ok = total > 1e-6f && length > 1e-6f;
      tx[x] = ok ? ax / length : kNaN;
      ty[x] = ok ? ay / length : kNaN;
      tz[x] = ok ? az / length : kNaN;
    }
  }
}

/// Same aspect ratio: (width / w) / (height / h) within 1 %.
void checkSameAspect(int w, int h, int width, int height,
                     const std::string& topic) {
  const double ratio =
      (static_cast<double>(width) * h) / (static_cast<double>(height) * w);
  if (std::abs(ratio - 1.0) > 0.01) {
    throw InputError(topic + ": a " + sizeText(w, h) +
                     " map cannot be resampled to the image's " +
                     sizeText(width, height) +
                     ": expected the same aspect ratio");
  }
}

}  // namespace

void resampleMap(const PlanarImage& source, int width, int height,
                 Resampling method, bool is_normal_map,
                 const std::string& topic, PlanarImage& target, int threads,
                 PlanarImage* scratch) {
  const int w = source.width(), h = source.height(), C = source.channels();
  checkSameAspect(w, h, width, height, topic);
  target.resize(width, height, C);
  const double sx = static_cast<double>(w) / width;
  const double sy = static_cast<double>(h) / height;
  if (is_normal_map && method == Resampling::kBilinear && C == 3) {
    resampleNormalsBilinear(source, sx, sy, target, threads, scratch);
    return;
  }
  const std::size_t source_pixels = source.pixelCount();
  auto valid = [&](std::size_t i) {
    if (is_normal_map) {
      return isValidNormal(source.plane(0)[i], source.plane(1)[i],
                           source.plane(2)[i]);
    }
    for (int c = 0; c < C; ++c) {
      if (!std::isfinite(source.plane(c)[i])) return false;
    }
    return true;
  };
  // Rows in parallel: each target pixel is computed alone (same values on any
  // thread count).
#pragma omp parallel for num_threads(std::max(1, threads)) schedule(static)
  for (int y = 0; y < height; ++y) {
    const Bracket v = bracket(sy, y, h);
    for (int x = 0; x < width; ++x) {
      const Bracket u = bracket(sx, x, w);
      const std::size_t t = static_cast<std::size_t>(y) * width + x;
      float acc[4] = {0, 0, 0, 0};
      float total = 0.0f;
      if (method == Resampling::kNearest) {
        const std::size_t i =
            static_cast<std::size_t>(std::lround(v.coordinate)) * w +
            std::lround(u.coordinate);
        if (valid(i)) {
          for (int c = 0; c < C && c < 4; ++c) acc[c] = source.plane(c)[i];
          total = 1.0f;
        }
      } else {
        const float fx = u.f, fy = v.f;
        const int xs[4] = {u.i0, u.i1, u.i0, u.i1};
        const int ys[4] = {v.i0, v.i0, v.i1, v.i1};
        const float ws[4] = {(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy,
                             fx * fy};
        // Bilinear weights over the valid neighbours only.
        for (int k = 0; k < 4; ++k) {
          const std::size_t i = static_cast<std::size_t>(ys[k]) * w + xs[k];
          if (ws[k] <= 0.0f || i >= source_pixels || !valid(i)) continue;
          for (int c = 0; c < C && c < 4; ++c) {
            acc[c] += ws[k] * source.plane(c)[i];
          }
          total += ws[k];
        }
      }
      if (total <= 1e-6f) {
        for (int c = 0; c < C; ++c) target.plane(c)[t] = kNaN;
        continue;
      }
      if (is_normal_map) {
        // Back to unit length (the weighted mean of unit vectors is shorter).
        const float length =
            std::sqrt(acc[0] * acc[0] + acc[1] * acc[1] + acc[2] * acc[2]);
        for (int c = 0; c < 3; ++c) {
          target.plane(c)[t] = length > 1e-6f ? acc[c] / length : kNaN;
        }
      } else {
        for (int c = 0; c < C && c < 4; ++c) {
          target.plane(c)[t] = acc[c] / total;
        }
      }
    }
  }
}

}  // namespace node
}  // namespace normal_fusion
