// Image-driven anisotropic weights w_h, w_v of the smoothness term:
// Gaussian pre-smoothing, 3x3 Sobel gradients, w = max(w_min, g(|grad|)).
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <vector>

#include "normal_fusion/detail/multiversion.h"
#include "normal_fusion/detail/solver_internal.h"
#include "normal_fusion/errors.h"
#include "normal_fusion/solver.h"

namespace normal_fusion {
namespace {

/// Separable Gaussian blur of one plane, replicated borders.
void gaussianBlur(const float* src, float* dst, int W, int H, double sigma,
                  internal::EdgeWeightScratch& scratch, int threads) {
  const std::size_t N = static_cast<std::size_t>(W) * H;
  if (sigma <= 0.0) {
    std::copy(src, src + N, dst);
    return;
  }
  const int radius = std::max(1, static_cast<int>(std::ceil(3.0 * sigma)));
  std::vector<float>& kernel = scratch.kernel;
  kernel.resize(2 * radius + 1);
  double total = 0.0;
  for (int k = -radius; k <= radius; ++k) {
    total += std::exp(-0.5 * k * k / (sigma * sigma));
  }
  for (int k = -radius; k <= radius; ++k) {
    kernel[k + radius] =
        static_cast<float>(std::exp(-0.5 * k * k / (sigma * sigma)) / total);
  }
  float* tmp = scratch.blur.data();
#pragma omp parallel num_threads(threads)
  {
    // Horizontal pass into the scratch plane.
#pragma omp for schedule(static)
    for (int y = 0; y < H; ++y) {
      const float* row = src + static_cast<std::size_t>(y) * W;
      float* out = tmp + static_cast<std::size_t>(y) * W;
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
#pragma omp for schedule(static)
    for (int y = 0; y < H; ++y) {
      float* out = dst + static_cast<std::size_t>(y) * W;
      for (int x = 0; x < W; ++x) out[x] = 0.0f;
      for (int k = -radius; k <= radius; ++k) {
        const int yy = std::min(std::max(y + k, 0), H - 1);
        const float* row = tmp + static_cast<std::size_t>(yy) * W;
        const float kv = kernel[k + radius];
        for (int x = 0; x < W; ++x) out[x] += kv * row[x];
      }
    }
  }
}

/// Normalized 3x3 Sobel derivatives (divided by 8: a unit ramp per pixel
/// gives 1), replicated borders; keeps the running maximum of |g_x|, |g_y|.
void sobelMagnitudeMax(const float* img, float* mag_h, float* mag_v, int W,
                       int H, int threads) {
#pragma omp parallel for num_threads(threads) schedule(static)
  for (int y = 0; y < H; ++y) {
    const float* up = img + static_cast<std::size_t>(std::max(y - 1, 0)) * W;
    const float* mid = img + static_cast<std::size_t>(y) * W;
    const float* down =
        img + static_cast<std::size_t>(std::min(y + 1, H - 1)) * W;
    for (int x = 0; x < W; ++x) {
      const int xl = std::max(x - 1, 0), xr = std::min(x + 1, W - 1);
      const float gx = (up[xr] + 2.0f * mid[xr] + down[xr]) -
                       (up[xl] + 2.0f * mid[xl] + down[xl]);
      const float gy = (down[xl] + 2.0f * down[x] + down[xr]) -
                       (up[xl] + 2.0f * up[x] + up[xr]);
      const std::size_t i = static_cast<std::size_t>(y) * W + x;
      mag_h[i] = std::max(mag_h[i], std::abs(gx) / 8.0f);
      mag_v[i] = std::max(mag_v[i], std::abs(gy) / 8.0f);
    }
  }
}

/// Forward differences |I(x+1) - I(x)|, |I(y+1) - I(y)| (0 on the last
/// column / row): the edge between exactly the two pixels that the normals'
/// differences couple; keeps the running maximum.
void differenceMagnitudeMax(const float* img, float* mag_h, float* mag_v, int W,
                            int H, int threads) {
#pragma omp parallel for num_threads(threads) schedule(static)
  for (int y = 0; y < H; ++y) {
    const float* row = img + static_cast<std::size_t>(y) * W;
    const float* next =
        img + static_cast<std::size_t>(std::min(y + 1, H - 1)) * W;
    float* out_h = mag_h + static_cast<std::size_t>(y) * W;
    float* out_v = mag_v + static_cast<std::size_t>(y) * W;
    for (int x = 0; x < W; ++x) {
      const int xr = std::min(x + 1, W - 1);
      out_h[x] = std::max(out_h[x], std::abs(row[xr] - row[x]));
      out_v[x] = std::max(out_v[x], std::abs(next[x] - row[x]));
    }
  }
}

/// g <- max(w_min, exp(scale g)) over a row (scale g <= 0), branch-free and
/// vectorised: exp(t) = 2^k exp(r), k = round(t / ln 2), r = t - k ln 2 in
/// [-ln 2 / 2, ln 2 / 2] (ln 2 split in two for exactness), exp(r) by its
/// Taylor polynomial to r^7, 2^k built in the exponent bits; t below -87
/// (exp < 1.7e-38) is clamped there. Relative error below 2e-7 against the
/// double exp of the same g while exp(t) >= 0.05 (below, the float product
/// scale g carries more rounding; the weights are floored at w_min there).
NF_MULTIVERSION
void exponentialWeightRow(int W, float scale, float w_min,
                          float* __restrict g) {
  constexpr float kLog2e = 1.44269504088896341f;
  constexpr float kLn2Hi = 0.693359375f;
  constexpr float kLn2Lo = -2.12194440e-4f;
  for (int x = 0; x < W; ++x) {
    const float t = std::max(scale * g[x], -87.0f);
    // k = round(t / ln 2) for t <= 0 (truncation of t / ln 2 - 0.5).
    const int k = static_cast<int>(t * kLog2e - 0.5f);
    const float kf = static_cast<float>(k);
    const float r = (t - kf * kLn2Hi) - kf * kLn2Lo;
    float p = 1.0f / 5040.0f;
    p = p * r + 1.0f / 720.0f;
    p = p * r + 1.0f / 120.0f;
    p = p * r + 1.0f / 24.0f;
    p = p * r + 1.0f / 6.0f;
    p = p * r + 0.5f;
    p = p * r + 1.0f;
    p = p * r + 1.0f;
    const std::int32_t bits = (k + 127) << 23;
    float two_k;
    std::memcpy(&two_k, &bits, sizeof(two_k));
    g[x] = std::max(w_min, p * two_k);
  }
}

/// The gradient magnitude per direction into scratch.mag_h, mag_v (sized and
/// zeroed): of the luminance, or the largest over the colour channels.
void gradientMagnitudes(const ColorImage& image,
                        const EdgeWeightSettings& settings,
                        internal::EdgeWeightScratch& scratch, int threads) {
  const int W = image.width(), H = image.height();
  const std::size_t N = image.pixelCount();
  const bool luminance =
      image.channels() == 3 && settings.color_mode == EdgeColorMode::kLuminance;
  const int passes = luminance ? 1 : image.channels();
  for (int c = 0; c < passes; ++c) {
    const float* src = image.plane(c);
    if (luminance) {
      for (std::size_t i = 0; i < N; ++i) {
        scratch.plane[i] = 0.299f * image.plane(0)[i] +
                           0.587f * image.plane(1)[i] +
                           0.114f * image.plane(2)[i];
      }
      src = scratch.plane.data();
    }
    // Pre-smoothing (none at sigma 0: the plane itself).
    const float* smoothed = src;
    if (settings.smoothing_sigma > 0.0) {
      gaussianBlur(src, scratch.blurred.data(), W, H, settings.smoothing_sigma,
                   scratch, threads);
      smoothed = scratch.blurred.data();
    }
    if (settings.gradient == EdgeGradient::kSobel) {
      sobelMagnitudeMax(smoothed, scratch.mag_h.data(), scratch.mag_v.data(), W,
                        H, threads);
    } else {
      differenceMagnitudeMax(smoothed, scratch.mag_h.data(),
                             scratch.mag_v.data(), W, H, threads);
    }
  }
}

/// The weights of one row's links from their gradients, in place in w_h
/// and w_v: w = max(w_min, exp(-alpha g^beta)) or max(w_min, 1 / (1 + alpha
/// g^beta)); the common case (exponential, beta = 1) in float, vectorised.
void weightsFromGradientRow(const EdgeWeightSettings& settings, int W,
                            float* w_h, float* w_v) {
  const bool exponential =
      settings.function == EdgeWeightFunction::kExponential;
  const double alpha = settings.alpha, beta = settings.beta;
  const float w_min = static_cast<float>(settings.w_min);
  if (exponential && beta == 1.0) {
    const float minus_alpha = static_cast<float>(-alpha);
    exponentialWeightRow(W, minus_alpha, w_min, w_h);
    exponentialWeightRow(W, minus_alpha, w_min, w_v);
    return;
  }
  auto weight_of = [&](float g) {
    const double gb = beta == 1.0 ? g : std::pow(static_cast<double>(g), beta);
    const double w =
        exponential ? std::exp(-alpha * gb) : 1.0 / (1.0 + alpha * gb);
    return std::max(w_min, static_cast<float>(w));
  };
  for (int x = 0; x < W; ++x) {
    w_h[x] = weight_of(w_h[x]);
    w_v[x] = weight_of(w_v[x]);
  }
}

/// The weight of each link from the gradient magnitudes in scratch.
void linkWeights(const EdgeWeightSettings& settings,
                 const internal::EdgeWeightScratch& scratch,
                 PlanarImage& weights, int threads) {
  const int W = weights.width(), H = weights.height();
  const float* mag_h = scratch.mag_h.data();
  const float* mag_v = scratch.mag_v.data();
  // The difference n(x+1) - n(x) straddles two pixels: with Sobel gradients
  // (centred on pixels) use the stronger of the two; forward differences
  // already sit between them.
  const bool centred = settings.gradient == EdgeGradient::kSobel;
#pragma omp parallel for num_threads(threads) schedule(static)
  for (int y = 0; y < H; ++y) {
    const std::size_t row = static_cast<std::size_t>(y) * W;
    float* w_h = weights.plane(0) + row;
    float* w_v = weights.plane(1) + row;
    // The gradient on each link, into the weight rows first.
    for (int x = 0; x < W; ++x) {
      const std::size_t i = row + x;
      w_h[x] =
          centred && x + 1 < W ? std::max(mag_h[i], mag_h[i + 1]) : mag_h[i];
      w_v[x] =
          centred && y + 1 < H ? std::max(mag_v[i], mag_v[i + W]) : mag_v[i];
    }
    weightsFromGradientRow(settings, W, w_h, w_v);
  }
}

/// True when the weights come from the forward differences of the largest
/// channel (or the only one) of the unsmoothed image: one pass per row then
/// gives the gradients and the weights (fusedForwardWeights()).
bool fusable(const ColorImage& image, const EdgeWeightSettings& settings) {
  const bool luminance =
      image.channels() == 3 && settings.color_mode == EdgeColorMode::kLuminance;
  return !luminance && settings.smoothing_sigma <= 0.0 &&
         settings.gradient == EdgeGradient::kForwardDifference;
}

/// g_h = max_c |I_c(x+1) - I_c(x)|, g_v = max_c |I_c(y+1) - I_c(y)| of one
/// row (0 on the last column; `next` is the row itself on the last row), in
/// differenceMagnitudeMax()'s order of the channels: the same maxima (the
/// last column's |I(x) - I(x)| never raises one).
NF_MULTIVERSION
void forwardDifferenceRow(int W, int channels, const float* const* row,
                          const float* const* next, float* __restrict g_h,
                          float* __restrict g_v) {
  for (int x = 0; x < W; ++x) {
    g_h[x] = 0.0f;
    g_v[x] = 0.0f;
  }
  for (int c = 0; c < channels; ++c) {
    const float* __restrict r = row[c];
    const float* __restrict n = next[c];
    for (int x = 0; x + 1 < W; ++x) {
      g_h[x] = std::max(g_h[x], std::abs(r[x + 1] - r[x]));
    }
    for (int x = 0; x < W; ++x)
      g_v[x] = std::max(g_v[x], std::abs(n[x] - r[x]));
  }
}

/// computeEdgeWeightsInto() where fusable(): per row, the forward
/// differences straight into the weight rows, then their weights
/// (weightsFromGradientRow(), as linkWeights(); without the gradient
/// planes' passes).
void fusedForwardWeights(const ColorImage& image,
                         const EdgeWeightSettings& settings,
                         PlanarImage& weights, int threads) {
  const int W = image.width(), H = image.height(), C = image.channels();
#pragma omp parallel for num_threads(threads) schedule(static)
  for (int y = 0; y < H; ++y) {
    const std::size_t row = static_cast<std::size_t>(y) * W;
    const std::size_t below =
        static_cast<std::size_t>(std::min(y + 1, H - 1)) * W;
    const float* here[3] = {};
    const float* next[3] = {};
    for (int c = 0; c < C; ++c) {
      here[c] = image.plane(c) + row;
      next[c] = image.plane(c) + below;
    }
    float* w_h = weights.plane(0) + row;
    float* w_v = weights.plane(1) + row;
    forwardDifferenceRow(W, C, here, next, w_h, w_v);
    weightsFromGradientRow(settings, W, w_h, w_v);
  }
}

}  // namespace

namespace internal {

std::size_t EdgeWeightScratch::bytesHeld() const {
  std::size_t bytes = 0;
  for (const std::vector<float>* v :
       {&mag_h, &mag_v, &plane, &blurred, &blur, &kernel}) {
    bytes += internal::bytesHeld(*v);
  }
  return bytes;
}

void computeEdgeWeightsInto(const ColorImage& image,
                            const EdgeWeightSettings& settings,
                            PlanarImage& weights, EdgeWeightScratch& scratch,
                            int threads) {
  if (image.empty() || (image.channels() != 1 && image.channels() != 3)) {
    throw InputError("edge weights: expected a 1- or 3-channel image, got " +
                     std::to_string(image.channels()) + " channels");
  }
  const int W = image.width(), H = image.height();
  weights.resize(W, H, 2);
  if (!settings.enabled) {
    weights.fill(1.0f);
    return;
  }
  if (fusable(image, settings)) {
    fusedForwardWeights(image, settings, weights, threads);
    return;
  }
  computeEdgeWeightsPassByPass(image, settings, weights, scratch, threads);
}

void computeEdgeWeightsPassByPass(const ColorImage& image,
                                  const EdgeWeightSettings& settings,
                                  PlanarImage& weights,
                                  EdgeWeightScratch& scratch, int threads) {
  const int W = image.width(), H = image.height();
  const std::size_t N = image.pixelCount();
  weights.resize(W, H, 2);
  if (!settings.enabled) {
    weights.fill(1.0f);
    return;
  }
  for (std::vector<float>* v : {&scratch.mag_h, &scratch.mag_v, &scratch.plane,
                                &scratch.blurred, &scratch.blur}) {
    v->resize(N);
  }
  std::fill(scratch.mag_h.begin(), scratch.mag_h.end(), 0.0f);
  std::fill(scratch.mag_v.begin(), scratch.mag_v.end(), 0.0f);

  gradientMagnitudes(image, settings, scratch, threads);
  linkWeights(settings, scratch, weights, threads);
}

}  // namespace internal

PlanarImage computeEdgeWeights(const ColorImage& image,
                               const EdgeWeightSettings& settings) {
  PlanarImage weights;
  internal::EdgeWeightScratch scratch;
  internal::computeEdgeWeightsInto(image, settings, weights, scratch, 1);
  return weights;
}

}  // namespace normal_fusion
