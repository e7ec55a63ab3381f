// The per-input noise estimate across scales (docs/algorithm.md, Data terms):
// window sums of f at growing radii, the spread each window reads, its median
// over the image per radius.
#include "normal_fusion/detail/noise_estimate.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include "normal_fusion/detail/multiversion.h"
#include "normal_fusion/detail/solver_internal.h"

namespace normal_fusion {
namespace internal {

NF_MULTIVERSION
void columnSums(int W, const float* __restrict fx, const float* __restrict fy,
                const float* __restrict fz, float* __restrict sx,
                float* __restrict sy, float* __restrict sz,
                float* __restrict count) {
  for (int x = 0; x < W; ++x) {
    sx[x] += fx[x];
    sy[x] += fy[x];
    sz[x] += fz[x];
    count[x] +=
        fx[x] * fx[x] + fy[x] * fy[x] + fz[x] * fz[x] > 0.0f ? 1.0f : 0.0f;
  }
}

NF_MULTIVERSION
void windowSums(int W, int r, const float* __restrict in,
                float* __restrict out) {
  auto border = [&](int x) {
    float sum = 0.0f;
    for (int u = std::max(0, x - r); u <= std::min(W - 1, x + r); ++u) {
      sum += in[u];
    }
    out[x] = sum;
  };
  const int lo = std::min(r, W), hi = std::max(lo, W - r);
  for (int x = 0; x < lo; ++x) border(x);
  for (int x = hi; x < W; ++x) border(x);
  // Interior: whole windows, one shifted row at a time (vectorised).
  for (int x = lo; x < hi; ++x) out[x] = in[x - r];
  for (int d = 1 - r; d <= r; ++d) {
    for (int x = lo; x < hi; ++x) out[x] += in[x + d];
  }
}

void windowResultantRow(const PlanarImage& data, int r, int y,
                        WindowSumRows& rows) {
  float* const* col = rows.col;
  float* const* win = rows.win;
  const int W = data.width(), H = data.height();
  const int y0 = std::max(0, y - r), y1 = std::min(H - 1, y + r);
  for (int k = 0; k < 4; ++k) std::fill(col[k], col[k] + W, 0.0f);
  for (int v = y0; v <= y1; ++v) {
    const std::size_t off = static_cast<std::size_t>(v) * W;
    columnSums(W, data.plane(0) + off, data.plane(1) + off, data.plane(2) + off,
               col[0], col[1], col[2], col[3]);
  }
  for (int k = 0; k < 4; ++k) windowSums(W, r, col[k], win[k]);
}

namespace {

/// One row of sigma_r from the window sums (resultant s, valid count n).
/// Branch-free (vectorised).
NF_MULTIVERSION
void whiteNoiseSpreadRow(int W, const float* __restrict sx,
                         const float* __restrict sy, const float* __restrict sz,
                         const float* __restrict count,
                         float* __restrict sigma) {
  for (int x = 0; x < W; ++x) {
    const float n = std::max(count[x], 1.0f);
    // s^2 = 2 (1 - R), R = |sum f| / n: the mean squared distance of unit
    // vectors from their normalized mean.
    const float R =
        std::sqrt(sx[x] * sx[x] + sy[x] * sy[x] + sz[x] * sz[x]) / n;
    const float s2 = std::max(0.0f, 2.0f * (1.0f - R));
    // E s^2 = sigma^2 (1 - 1 / n) for n independent samples.
    const float unbiased = std::sqrt(s2 / std::max(1.0f - 1.0f / n, 0.5f));
    sigma[x] = count[x] >= 2.0f ? unbiased : -1.0f;
  }
}

}  // namespace

void whiteNoiseSpreadInto(const PlanarImage& data, int r, float* out,
                          int threads) {
  const int W = data.width(), H = data.height();
#pragma omp parallel num_threads(threads)
  {
    // Per thread: column sums (col_*) and window sums (win_*) of f and of
    // the valid count; grown once, then reused.
    thread_local std::vector<float> scratch;
    const std::size_t scratch_values =
        WindowSumRows::kRows * static_cast<std::size_t>(W);
    releaseIfOversized(scratch, scratch_values);
    if (scratch.size() < scratch_values) scratch.resize(scratch_values);
    WindowSumRows rows(scratch.data(), W);
#pragma omp for schedule(static)
    for (int y = 0; y < H; ++y) {
      // Resultant and count of the window around row y.
      windowResultantRow(data, r, y, rows);
      whiteNoiseSpreadRow(W, rows.win[0], rows.win[1], rows.win[2], rows.win[3],
                          out + static_cast<std::size_t>(y) * W);
    }
  }
}

NoiseEstimate estimateNoise(const PlanarImage& data, int base_radius,
                            int max_radius, int threads) {
  NoiseEstimate estimate;
  const std::size_t pixels = data.pixelCount();
  // The spreads of one radius and the ones of the counted pixels (grown
  // once, then reused).
  thread_local std::vector<float> spread, base_spread, samples;
  releaseIfOversized(spread, pixels);
  releaseIfOversized(base_spread, pixels);
  releaseIfOversized(samples, pixels);
  spread.resize(pixels);
  base_spread.resize(pixels);
  samples.reserve(pixels);
  for (int r = base_radius; estimate.scales < kMaxNoiseScales;) {
    float* out = estimate.scales == 0 ? base_spread.data() : spread.data();
    whiteNoiseSpreadInto(data, r, out, threads);
    // Median over the pixels with 2 samples at the base radius (the wider
    // windows hold them too), so that every scale counts the same pixels.
    samples.clear();
    for (std::size_t i = 0; i < pixels; ++i) {
      if (base_spread[i] >= 0.0f) samples.push_back(out[i]);
    }
    if (samples.empty()) return NoiseEstimate();
    const auto middle = samples.begin() + samples.size() / 2;
    std::nth_element(samples.begin(), middle, samples.end());
    estimate.radius[estimate.scales] = r;
    estimate.sigma[estimate.scales] = *middle;
    ++estimate.scales;
    if (r >= max_radius) break;
    r = std::min(2 * r, max_radius);
  }
  // gain = max_r sigma_r / sigma_r0 (1 on a noise-free input), at most the
  // ratio of the widest window's side to the base one's: a correlation
  // longer than the widest window cannot be told from structure.
  const float base = estimate.sigma[0];
  const float longest =
      static_cast<float>(2 * estimate.radius[estimate.scales - 1] + 1) /
      static_cast<float>(2 * base_radius + 1);
  for (int k = 1; k < estimate.scales; ++k) {
    if (base > 0.0f) {
      estimate.gain = std::max(estimate.gain, estimate.sigma[k] / base);
    }
  }
  estimate.gain = std::min(estimate.gain, longest);
  return estimate;
}

}  // namespace internal
}  // namespace normal_fusion
