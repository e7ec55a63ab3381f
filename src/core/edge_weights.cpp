// Image-driven anisotropic weights w_h, w_v of the smoothness term:
// Gaussian pre-smoothing, 3x3 Sobel gradients, w = max(w_min, g(|grad|)).
#include <algorithm>
#include <cmath>
#include <vector>

#include "normal_fusion/errors.h"
#include "normal_fusion/solver.h"

namespace normal_fusion {
namespace {

/// Separable Gaussian blur of one plane, replicated borders.
void gaussianBlur(const float* src, float* dst, int W, int H, double sigma,
                  std::vector<float>& scratch) {
  const std::size_t N = static_cast<std::size_t>(W) * H;
  if (sigma <= 0.0) {
    std::copy(src, src + N, dst);
    return;
  }
  const int radius = std::max(1, static_cast<int>(std::ceil(3.0 * sigma)));
  std::vector<float> kernel(2 * radius + 1);
  double total = 0.0;
  for (int k = -radius; k <= radius; ++k) {
    const double v = std::exp(-0.5 * k * k / (sigma * sigma));
    kernel[k + radius] = static_cast<float>(v);
    total += v;
  }
  for (float& v : kernel) v = static_cast<float>(v / total);
  scratch.resize(N);
  // Horizontal pass into scratch.
  for (int y = 0; y < H; ++y) {
    const float* row = src + static_cast<std::size_t>(y) * W;
    float* out = scratch.data() + static_cast<std::size_t>(y) * W;
    for (int x = 0; x < W; ++x) {
      float acc = 0.0f;
      for (int k = -radius; k <= radius; ++k) {
        const int xx = std::min(std::max(x + k, 0), W - 1);
        acc += kernel[k + radius] * row[xx];
      }
      out[x] = acc;
    }
  }
  // Vertical pass into dst.
  for (int y = 0; y < H; ++y) {
    float* out = dst + static_cast<std::size_t>(y) * W;
    for (int x = 0; x < W; ++x) out[x] = 0.0f;
    for (int k = -radius; k <= radius; ++k) {
      const int yy = std::min(std::max(y + k, 0), H - 1);
      const float* row = scratch.data() + static_cast<std::size_t>(yy) * W;
      const float kv = kernel[k + radius];
      for (int x = 0; x < W; ++x) out[x] += kv * row[x];
    }
  }
}

/// Normalized 3x3 Sobel derivatives (divided by 8: a unit ramp per pixel
/// gives 1), replicated borders.
void sobel(const float* img, float* g_x, float* g_y, int W, int H) {
  auto at = [&](int x, int y) {
    x = std::min(std::max(x, 0), W - 1);
    y = std::min(std::max(y, 0), H - 1);
    return img[static_cast<std::size_t>(y) * W + x];
  };
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const float gx = (at(x + 1, y - 1) + 2.0f * at(x + 1, y) + at(x + 1, y + 1)) -
                       (at(x - 1, y - 1) + 2.0f * at(x - 1, y) + at(x - 1, y + 1));
      const float gy = (at(x - 1, y + 1) + 2.0f * at(x, y + 1) + at(x + 1, y + 1)) -
                       (at(x - 1, y - 1) + 2.0f * at(x, y - 1) + at(x + 1, y - 1));
      const std::size_t i = static_cast<std::size_t>(y) * W + x;
      g_x[i] = gx / 8.0f;
      g_y[i] = gy / 8.0f;
    }
  }
}

}  // namespace

PlanarImage computeEdgeWeights(const ColorImage& image,
                               const EdgeWeightSettings& settings) {
  if (image.empty() || (image.channels() != 1 && image.channels() != 3)) {
    throw InputError("edge weights: expected a 1- or 3-channel image, got " +
                     std::to_string(image.channels()) + " channels");
  }
  const int W = image.width(), H = image.height();
  const std::size_t N = image.pixelCount();
  PlanarImage weights(W, H, 2, 1.0f);
  if (!settings.enabled) return weights;

  // Gradient magnitude per direction: of the luminance, or the largest over
  // the colour channels.
  std::vector<float> mag_h(N, 0.0f), mag_v(N, 0.0f);
  std::vector<float> plane(N), blurred(N), g_x(N), g_y(N), scratch;
  std::vector<int> channels;
  if (image.channels() == 3 && settings.color_mode == EdgeColorMode::kLuminance) {
    for (std::size_t i = 0; i < N; ++i) {
      plane[i] = 0.299f * image.plane(0)[i] + 0.587f * image.plane(1)[i] +
                 0.114f * image.plane(2)[i];
    }
    channels = {-1};
  } else {
    for (int c = 0; c < image.channels(); ++c) channels.push_back(c);
  }
  for (int c : channels) {
    const float* src = c < 0 ? plane.data() : image.plane(c);
    gaussianBlur(src, blurred.data(), W, H, settings.smoothing_sigma, scratch);
    sobel(blurred.data(), g_x.data(), g_y.data(), W, H);
    for (std::size_t i = 0; i < N; ++i) {
      mag_h[i] = std::max(mag_h[i], std::abs(g_x[i]));
      mag_v[i] = std::max(mag_v[i], std::abs(g_y[i]));
    }
  }

  auto weight_of = [&](float g) {
    const double gb = std::pow(static_cast<double>(g), settings.beta);
    const double w = settings.function == EdgeWeightFunction::kExponential
                         ? std::exp(-settings.alpha * gb)
                         : 1.0 / (1.0 + settings.alpha * gb);
    return static_cast<float>(std::max(settings.w_min, w));
  };
  // The difference n(x+1) - n(x) straddles two pixels: use the stronger edge.
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const std::size_t i = static_cast<std::size_t>(y) * W + x;
      const float gh = x + 1 < W ? std::max(mag_h[i], mag_h[i + 1]) : mag_h[i];
      const float gv = y + 1 < H ? std::max(mag_v[i], mag_v[i + W]) : mag_v[i];
      weights.plane(0)[i] = weight_of(gh);
      weights.plane(1)[i] = weight_of(gv);
    }
  }
  return weights;
}

}  // namespace normal_fusion
