// The per-input noise estimate across scales (docs/algorithm.md, Data terms):
// the spread each window around a grid of centres reads at growing radii,
// its median per radius; and the window sums of the local statistics.
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

/// sigma_r around the window's least-squares plane from its moments m =
/// (n, Su, Sv, Suu, Suv, Svv, F_c, Fu_c, Fv_c): each component of f fitted as
/// a + b u + c v over the valid pixels at offsets (u, v); the residual RSS =
/// sum |f|^2 - sum_c b_c^T A^-1 b_c (A the moments of the mask, b_c those of
/// f_c) read as white noise. -1 where fewer than 4 valid pixels or pixels
/// on one line leave the plane undetermined.
float planeModelSigma(const std::array<double, 15>& m) {
  const double n = m[0];
  if (n < 4.0) return -1.0f;
  // Moments about the valid pixels' centroid (mu, mv).
  const double mu = m[1] / n, mv = m[2] / n;
  const double cuu = m[3] - m[1] * mu, cvv = m[5] - m[2] * mv;
  const double cuv = m[4] - m[1] * mv;
  const double det = cuu * cvv - cuv * cuv;
  if (!(det > 1e-6 * std::max(1.0, cuu * cvv))) return -1.0f;
  double rss = n;  // sum |f|^2 = n (unit normals)
  for (int c = 0; c < 3; ++c) {
    const double f = m[6 + c], fu = m[9 + c], fv = m[12 + c];
    // Covariances of f_c with u and v about the centroid; the plane's share
    // of the sum of squares is f^2 / n + g^T C^-1 g.
    const double gu = fu - f * mu, gv = fv - f * mv;
    rss -=
        f * f / n + (cvv * gu * gu - 2.0 * cuv * gu * gv + cuu * gv * gv) / det;
  }
  // E RSS = sigma^2 (n - 3) per component (3 fitted coefficients); the
  // estimate's median is what is read, and the median of a chi with few
  // degrees of freedom (2 (n - 3): two tangent axes) lies below its
  // root-mean-square by (1 - 2 / (9 dof))^(3/2) (Wilson-Hilferty).
  const double dof_per_axis = n - 3.0;
  const double median_bias = std::pow(1.0 - 1.0 / (9.0 * dof_per_axis), 1.5);
  return static_cast<float>(std::sqrt(std::max(0.0, rss) / dof_per_axis) /
                            median_bias);
}

/// sigma_r around the window's mean from its valid count n and resultant
/// (sx, sy, sz); -1 below 2 samples.
float meanModelSigma(double n, double sx, double sy, double sz) {
  if (n < 2.0) return -1.0f;
  // s^2 = 2 (1 - R), R = |sum f| / n: the mean squared distance of unit
  // vectors from their normalized mean.
  const double R = std::sqrt(sx * sx + sy * sy + sz * sz) / n;
  const double s2 = std::max(0.0, 2.0 * (1.0 - R));
  // E s^2 = sigma^2 (1 - 1 / n) for n independent samples.
  return static_cast<float>(std::sqrt(s2 / std::max(1.0 - 1.0 / n, 0.5)));
}

}  // namespace

float windowSpreadAt(const PlanarImage& data, int r, int x, int y,
                     bool plane_residual) {
  const int W = data.width(), H = data.height();
  // The window's moments (see planeModelSigma), offsets from (x, y).
  std::array<double, 15> m{};
  for (int row = std::max(0, y - r); row <= std::min(H - 1, y + r); ++row) {
    const double v = row - y;
    const std::size_t off = static_cast<std::size_t>(row) * W;
    for (int col = std::max(0, x - r); col <= std::min(W - 1, x + r); ++col) {
      const double f[3] = {data.plane(0)[off + col], data.plane(1)[off + col],
                           data.plane(2)[off + col]};
      if (!(f[0] * f[0] + f[1] * f[1] + f[2] * f[2] > 0.0)) continue;
      const double u = col - x;
      m[0] += 1.0;
      m[1] += u;
      m[2] += v;
      m[3] += u * u;
      m[4] += u * v;
      m[5] += v * v;
      for (int c = 0; c < 3; ++c) {
        m[6 + c] += f[c];
        m[9 + c] += u * f[c];
        m[12 + c] += v * f[c];
      }
    }
  }
  return plane_residual ? planeModelSigma(m)
                        : meanModelSigma(m[0], m[6], m[7], m[8]);
}

namespace {

/// The grid's centres whose own pixel the input observes.
std::size_t observedCentres(const PlanarImage& data, int stride, int cols,
                            int rows) {
  std::size_t count = 0;
  for (int j = 0; j < rows; ++j) {
    for (int i = 0; i < cols; ++i) {
      const std::size_t p =
          static_cast<std::size_t>(stride / 2 + j * stride) * data.width() +
          stride / 2 + i * stride;
      const float fx = data.plane(0)[p], fy = data.plane(1)[p],
                  fz = data.plane(2)[p];
      count += fx * fx + fy * fy + fz * fz > 0.0f ? 1 : 0;
    }
  }
  return count;
}

}  // namespace

int noiseSampleStride(int width, int height) {
  const double pixels = static_cast<double>(width) * height;
  return std::max(1, static_cast<int>(std::sqrt(pixels / kNoiseSamples)));
}

NoiseEstimate estimateNoise(const PlanarImage& data, int base_radius,
                            int max_radius, int threads, bool plane_residual) {
  NoiseEstimate estimate;
  const int W = data.width(), H = data.height();
  // The windows around a grid of centres: the median of about a thousand
  // reads the image's as well as that of every pixel (its relative error
  // about 1.25 / sqrt(samples) of the windows' spread), at a small share of
  // the cost.
  const int stride = noiseSampleStride(W, H);
  const int cols = (W + stride - 1 - stride / 2) / stride;
  const int rows = (H + stride - 1 - stride / 2) / stride;
  const std::size_t centres = static_cast<std::size_t>(cols) * rows;
  // The spreads of one radius and the ones of the counted centres (grown
  // once, then reused).
  thread_local std::vector<float> spread, base_spread, samples;
  releaseIfOversized(spread, centres);
  releaseIfOversized(base_spread, centres);
  releaseIfOversized(samples, centres);
  spread.resize(centres);
  base_spread.resize(centres);
  samples.reserve(centres);
  for (int r = base_radius; estimate.scales < kMaxNoiseScales;) {
    float* out = estimate.scales == 0 ? base_spread.data() : spread.data();
#pragma omp parallel for num_threads(threads) schedule(static)
    for (int j = 0; j < rows; ++j) {
      for (int i = 0; i < cols; ++i) {
        out[static_cast<std::size_t>(j) * cols + i] =
            windowSpreadAt(data, r, stride / 2 + i * stride,
                           stride / 2 + j * stride, plane_residual);
      }
    }
    // Median over the centres whose base window reads a spread (the wider
    // windows hold it too), so that every scale counts the same centres.
    samples.clear();
    for (std::size_t i = 0; i < centres; ++i) {
      if (base_spread[i] >= 0.0f) samples.push_back(out[i]);
    }
    if (plane_residual && estimate.scales == 0 &&
        samples.size() < observedCentres(data, stride, cols, rows) / 2) {
      // A sparse input's base windows seldom determine a plane: its
      // reading would rest on a few centres, so it keeps the mean model.
      return estimateNoise(data, base_radius, max_radius, threads, false);
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
