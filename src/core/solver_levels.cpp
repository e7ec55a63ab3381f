// The levels of a solve: the coarser pyramid levels, the cold start, the
// upsampling of a coarser level's result, the projection onto the sphere
// after an outer step, and a warm start made usable.
#include "normal_fusion/detail/solver_levels.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include "normal_fusion/detail/multiversion.h"

namespace normal_fusion {
namespace internal {

namespace {

/// The largest finite float (comparisons against it reject infinities and
/// NaN alike).
constexpr float kFloatMax = std::numeric_limits<float>::max();

}  // namespace

/// The next coarser level (into reused buffers): 2x2 blocks, validity-weighted
/// means of the data (normalized), weights averaged and doubled (the data term
/// scales with area, the smoothness term with length), K scaled, edge weights
/// recomputed.
void downsampleInto(const PreparedLevel& fine, const SolverSettings& settings,
                    PreparedLevel& coarse, EdgeWeightScratch& scratch,
                    int threads) {
  const int W = (fine.width + 1) / 2, H = (fine.height + 1) / 2;
  const int L = fine.num_inputs;
  coarse.width = W;
  coarse.height = H;
  coarse.num_inputs = L;
  coarse.K = fine.K.scaled(static_cast<double>(W) / fine.width,
                           static_cast<double>(H) / fine.height);
  coarse.K_inv = coarse.K.inverse();
  const ColorImage& fine_image = fine.guide();
  coarse.image.resize(W, H, fine_image.channels());
  coarse.problem_image = nullptr;
  coarse.data.resize(L);
  coarse.data_weight.resize(L);
  coarse.data_eps.resize(L);
  coarse.data_huber = fine.data_huber;
  for (int l = 0; l < L; ++l) {
    coarse.data[l].resize(W, H, 3);
    coarse.data_weight[l].resize(W, H, 1);
    coarse.data_eps[l].resize(W, H, 1);
  }
  long valid = 0;
#pragma omp parallel for num_threads(threads) schedule(static) reduction(+ : valid)
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const std::size_t j = static_cast<std::size_t>(y) * W + x;
      const int x0 = 2 * x, x1 = std::min(2 * x + 1, fine.width - 1);
      const int y0 = 2 * y, y1 = std::min(2 * y + 1, fine.height - 1);
      const int xs[4] = {x0, x1, x0, x1};
      const int ys[4] = {y0, y0, y1, y1};
      const int count = (x1 > x0 ? 2 : 1) * (y1 > y0 ? 2 : 1);
      // Blocks at an odd border repeat a pixel: visit each pixel once.
      auto duplicate = [&](int k) {
        return (k == 1 && x1 == x0) || (k == 2 && y1 == y0) ||
               (k == 3 && (x1 == x0 || y1 == y0));
      };
      for (int c = 0; c < fine_image.channels(); ++c) {
        float sum = 0.0f;
        for (int k = 0; k < 4; ++k) {
          if (!duplicate(k)) sum += fine_image.at(c, ys[k], xs[k]);
        }
        coarse.image.plane(c)[j] = sum / count;
      }
      bool any_valid = false;
      for (int l = 0; l < L; ++l) {
        double f_sum[3] = {0.0, 0.0, 0.0};
        double c_sum = 0.0, eps_sum = 0.0;
        for (int k = 0; k < 4; ++k) {
          if (duplicate(k)) continue;
          const float cw = fine.data_weight[l].at(0, ys[k], xs[k]);
          c_sum += cw;
          if (fine.data_huber) {
            eps_sum += cw * fine.data_eps[l].at(0, ys[k], xs[k]);
          }
          for (int c = 0; c < 3; ++c)
            f_sum[c] += cw * fine.data[l].at(c, ys[k], xs[k]);
        }
        const double len = std::sqrt(f_sum[0] * f_sum[0] + f_sum[1] * f_sum[1] +
                                     f_sum[2] * f_sum[2]);
        const bool ok = c_sum > 0.0 && len > 1e-9;
        for (int c = 0; c < 3; ++c) {
          coarse.data[l].plane(c)[j] =
              ok ? static_cast<float>(f_sum[c] / len) : 0.0f;
        }
        coarse.data_weight[l].plane(0)[j] =
            ok ? static_cast<float>(2.0 * c_sum / count) : 0.0f;
        // delta: the weighted mean of the block's thresholds.
        coarse.data_eps[l].plane(0)[j] =
            ok && fine.data_huber ? static_cast<float>(eps_sum / c_sum) : 0.0f;
        any_valid = any_valid || ok;
      }
      valid += any_valid ? 1 : 0;
    }
  }
  coarse.valid_pixels = static_cast<int>(valid);
  computeEdgeWeightsInto(coarse.image, settings.edges, coarse.edge_weight,
                         scratch, threads);
}

namespace {

/// Cold start of one pixel: the first input with a usable observation
/// (projected onto the visible set in soft mode), else -r/|r|.
void coldNormal(const PreparedLevel& level, VisibilityMode mode, int x, int y,
                float v[3]) {
  float r[3];
  level.ray(x, y, r);
  for (int l = 0; l < level.num_inputs; ++l) {
    if (level.data_weight[l].at(0, y, x) > 0.0f) {
      for (int c = 0; c < 3; ++c) v[c] = level.data[l].at(c, y, x);
      if (mode == VisibilityMode::kSoft) projectVisible(r, v);
      return;
    }
  }
  const float rl = std::sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2]);
  for (int c = 0; c < 3; ++c) v[c] = -r[c] / rl;
}

}  // namespace

void initializeCold(const PreparedLevel& level, VisibilityMode mode,
                    PlanarImage& n, int threads) {
  n.resizeKeepingCapacity(level.width, level.height, 3);
#pragma omp parallel for num_threads(threads) schedule(static)
  for (int y = 0; y < level.height; ++y) {
    for (int x = 0; x < level.width; ++x) {
      float v[3];
      coldNormal(level, mode, x, y, v);
      for (int c = 0; c < 3; ++c) n.at(c, y, x) = v[c];
    }
  }
}

namespace {

/// The domain transform's passes (Gastal & Oliveira 2011): three, each with
/// half the spatial extent of the one before, remove most of the stripes a
/// single separable pass leaves.
constexpr int kFilterPasses = 3;

/// Couplings below this are 0: no smoothing to speak of, and their squares
/// in later passes would be denormal floats, which are slow.
constexpr float kNoCoupling = 1e-9f;

/// The link a^(1/w) = exp(log_a / w) of an edge weight w, 0 below exp(-20)
/// (about kNoCoupling).
inline float coupling(float log_a, float w) {
  const float e = log_a / std::max(w, 1e-12f);
  return e > -20.0f ? std::exp(e) : 0.0f;
}

/// Rows of kRowGroup filtered together along x, so that their recursions
/// (one per row and plane) run side by side instead of each waiting on its
/// last step.
constexpr int kRowGroup = 4;

/// R rows from offset `row0` of the three planes u filtered in place by the
/// first-order recursive filter u[x] += c[x-1] (u[x-1] - u[x]) forward, then
/// u[x] += c[x] (u[x+1] - u[x]) backward, c[x] the coupling of x and x+1.
template <int R>
void filterRows(int W, std::size_t row0, const float* c, float* const u[3]) {
  for (int x = 1; x < W; ++x) {
    for (int r = 0; r < R; ++r) {
      const std::size_t j = row0 + static_cast<std::size_t>(r) * W + x;
      const float cj = c[j - 1];
      for (int k = 0; k < 3; ++k) u[k][j] += cj * (u[k][j - 1] - u[k][j]);
    }
  }
  for (int x = W - 2; x >= 0; --x) {
    for (int r = 0; r < R; ++r) {
      const std::size_t j = row0 + static_cast<std::size_t>(r) * W + x;
      const float cj = c[j];
      for (int k = 0; k < 3; ++k) u[k][j] += cj * (u[k][j + 1] - u[k][j]);
    }
  }
}

/// Columns x0 .. x1 - 1 of a plane filtered in place down then up the rows,
/// c(y) the coupling of rows y and y+1 (row-wise, so that it vectorises).
void filterColumns(int W, int H, int x0, int x1, const float* c, float* u) {
  for (int y = 1; y < H; ++y) {
    const float* cy = c + static_cast<std::size_t>(y - 1) * W;
    const float* up = u + static_cast<std::size_t>(y - 1) * W;
    float* row = u + static_cast<std::size_t>(y) * W;
    for (int x = x0; x < x1; ++x) row[x] += cy[x] * (up[x] - row[x]);
  }
  for (int y = H - 2; y >= 0; --y) {
    const float* cy = c + static_cast<std::size_t>(y) * W;
    const float* down = u + static_cast<std::size_t>(y + 1) * W;
    float* row = u + static_cast<std::size_t>(y) * W;
    for (int x = x0; x < x1; ++x) row[x] += cy[x] * (down[x] - row[x]);
  }
}

}  // namespace

void initializeFiltered(const PreparedLevel& level, VisibilityMode mode,
                        int radius, PlanarImage& scratch, PlanarImage& n,
                        int threads) {
  const int W = level.width, H = level.height, L = level.num_inputs;
  const std::size_t N = static_cast<std::size_t>(W) * H;
  n.resizeKeepingCapacity(W, H, 3);
  // Planes 0 - 2: sum_l c_l f_l; 3, 4: the couplings of the links h, v.
  scratch.resizeKeepingCapacity(W, H, 5);
  float* sum[3] = {scratch.plane(0), scratch.plane(1), scratch.plane(2)};
  float* c_h = scratch.plane(3);
  float* c_v = scratch.plane(4);
  const float* w_h = level.edge_weight.plane(0);
  const float* w_v = level.edge_weight.plane(1);
  // First pass: a = exp(-sqrt(2) / sigma_0), sigma_0 = radius sqrt(3)
  // 2^(P-1) / sqrt(4^P - 1), the link a^(1 / w) (a weak edge weight is a
  // long way).
  const double sigma0 = radius * std::sqrt(3.0) *
                        std::pow(2.0, kFilterPasses - 1) /
                        std::sqrt(std::pow(4.0, kFilterPasses) - 1.0);
  const float log_a = static_cast<float>(-std::sqrt(2.0) / sigma0);
#pragma omp parallel for num_threads(threads) schedule(static)
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const std::size_t j = static_cast<std::size_t>(y) * W + x;
      float v[3] = {0.0f, 0.0f, 0.0f};
      for (int l = 0; l < L; ++l) {
        const float cw = level.data_weight[l].plane(0)[j];
        for (int k = 0; k < 3; ++k) v[k] += cw * level.data[l].plane(k)[j];
      }
      for (int k = 0; k < 3; ++k) sum[k][j] = v[k];
      c_h[j] = x + 1 < W ? coupling(log_a, w_h[j]) : 0.0f;
      c_v[j] = y + 1 < H ? coupling(log_a, w_v[j]) : 0.0f;
    }
  }
  constexpr int kColumnBlock = 64;
  const int column_blocks = (W + kColumnBlock - 1) / kColumnBlock;
  for (int pass = 0; pass < kFilterPasses; ++pass) {
    if (pass > 0) {
      // Each pass halves sigma: a^(1/w) becomes its square.
#pragma omp parallel for num_threads(threads) schedule(static)
      for (std::size_t j = 0; j < N; ++j) {
        const float h = c_h[j] * c_h[j], v = c_v[j] * c_v[j];
        c_h[j] = h < kNoCoupling ? 0.0f : h;
        c_v[j] = v < kNoCoupling ? 0.0f : v;
      }
    }
#pragma omp parallel for num_threads(threads) schedule(static)
    for (int y = 0; y < H; y += kRowGroup) {
      const std::size_t row0 = static_cast<std::size_t>(y) * W;
      if (y + kRowGroup <= H) {
        filterRows<kRowGroup>(W, row0, c_h, sum);
      } else {
        for (int r = y; r < H; ++r) {
          filterRows<1>(W, static_cast<std::size_t>(r) * W, c_h, sum);
        }
      }
    }
#pragma omp parallel for num_threads(threads) schedule(static) collapse(2)
    for (int k = 0; k < 3; ++k) {
      for (int b = 0; b < column_blocks; ++b) {
        filterColumns(W, H, b * kColumnBlock,
                      std::min(W, (b + 1) * kColumnBlock), c_v, sum[k]);
      }
    }
  }
#pragma omp parallel for num_threads(threads) schedule(static)
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const std::size_t j = static_cast<std::size_t>(y) * W + x;
      float v[3] = {sum[0][j], sum[1][j], sum[2][j]};
      const float len2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
      // No data reached this pixel (or the inputs cancel): the data start.
      if (!(len2 > 1e-24f && len2 <= kFloatMax)) {
        coldNormal(level, mode, x, y, v);
      } else {
        const float inv = 1.0f / std::sqrt(len2);
        for (int k = 0; k < 3; ++k) v[k] *= inv;
        if (mode == VisibilityMode::kSoft) {
          float r[3];
          level.ray(x, y, r);
          projectVisible(r, v);
        }
      }
      for (int k = 0; k < 3; ++k) n.plane(k)[j] = v[k];
    }
  }
}

namespace {

/// One row of a warm start's normals made usable, branch-free
/// (vectorised): n / |n|, projected onto the visible set in soft mode
/// (projectVisible(), with the ray K^-1 (x, y, 1) in float); missing[x] = 1
/// where |n| is zero, tiny or not finite (n is then left for coldNormal()).
template <bool kSoft>
NF_MULTIVERSION void sanitizeWarmRow(int W, float y, const float* Ki,
                                     float* __restrict nx, float* __restrict ny,
                                     float* __restrict nz,
                                     unsigned char* __restrict missing) {
  const float ry0 = Ki[1] * y + Ki[2], ry1 = Ki[4] * y + Ki[5],
              ry2 = Ki[7] * y + Ki[8];
  for (int x = 0; x < W; ++x) {
    const float len2 = nx[x] * nx[x] + ny[x] * ny[x] + nz[x] * nz[x];
    // Not NaN, not infinite (both comparisons fail), not tiny.
    const bool usable = (len2 > 1e-12f) & (len2 <= kFloatMax);
    missing[x] = usable ? 0 : 1;
    const float inv = 1.0f / std::sqrt(usable ? len2 : 1.0f);
    float v0 = nx[x] * inv, v1 = ny[x] * inv, v2 = nz[x] * inv;
    if (kSoft) {
      const float fx = static_cast<float>(x);
      projectVisibleSelect(Ki[0] * fx + ry0, Ki[3] * fx + ry1, Ki[6] * fx + ry2,
                           v0, v1, v2);
    }
    nx[x] = usable ? v0 : nx[x];
    ny[x] = usable ? v1 : ny[x];
    nz[x] = usable ? v2 : nz[x];
  }
}

}  // namespace

/// Upsamples a coarse unit normal map bilinearly (pixel centres aligned),
/// normalizes, and projects onto the visible set in soft mode (rows shared by
/// `threads`).
void upsampleNormals(const PlanarImage& coarse, const PreparedLevel& fine,
                     VisibilityMode mode, PlanarImage& n, int threads) {
  n.resizeKeepingCapacity(fine.width, fine.height, 3);
  const double sx = static_cast<double>(coarse.width()) / fine.width;
  const double sy = static_cast<double>(coarse.height()) / fine.height;
#pragma omp parallel for num_threads(threads) schedule(static)
  for (int y = 0; y < fine.height; ++y) {
    const double cy =
        std::min(std::max(sy * (y + 0.5) - 0.5, 0.0), coarse.height() - 1.0);
    const int y0 = static_cast<int>(cy);
    const int y1 = std::min(y0 + 1, coarse.height() - 1);
    const float ty = static_cast<float>(cy - y0);
    for (int x = 0; x < fine.width; ++x) {
      const double cx =
          std::min(std::max(sx * (x + 0.5) - 0.5, 0.0), coarse.width() - 1.0);
      const int x0 = static_cast<int>(cx);
      const int x1 = std::min(x0 + 1, coarse.width() - 1);
      const float tx = static_cast<float>(cx - x0);
      float v[3];
      for (int c = 0; c < 3; ++c) {
        v[c] =
            (1 - ty) *
                ((1 - tx) * coarse.at(c, y0, x0) + tx * coarse.at(c, y0, x1)) +
            ty * ((1 - tx) * coarse.at(c, y1, x0) + tx * coarse.at(c, y1, x1));
      }
      float r[3];
      fine.ray(x, y, r);
      const float len = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
      if (len > 1e-6f) {
        for (float& value : v) value /= len;
      } else {
        const float rl = std::sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2]);
        for (int c = 0; c < 3; ++c) v[c] = -r[c] / rl;
      }
      if (mode == VisibilityMode::kSoft) projectVisible(r, v);
      for (int c = 0; c < 3; ++c) n.at(c, y, x) = v[c];
    }
  }
}

namespace {

/// v <- v / max(1, |v| / radius); radius 0 gives 0.
inline void clampToRadius(float& a, float& b, float& c, float radius) {
  const float len = std::sqrt(a * a + b * b + c * c);
  const float s = len > radius ? (radius > 0.0f ? radius / len : 0.0f) : 1.0f;
  a *= s;
  b *= s;
  c *= s;
}

/// The coarse dual at coarse link or pixel (xc, yc), 0 outside the image
/// and on the links past the last column (`along_x`) or row.
inline float coarseDual(const PlanarImage& src, int c, int xc, int yc,
                        bool link_h, bool link_v) {
  if (xc < 0 || yc < 0 || xc >= src.width() || yc >= src.height()) return 0.0f;
  if ((link_h && xc + 1 == src.width()) || (link_v && yc + 1 == src.height())) {
    return 0.0f;
  }
  return src.at(c, yc, xc);
}

/// One dual image carried up, clamped to `radius` (a plane of the fine
/// level). A smoothness dual (link_h or link_v) is linear along its links:
/// the fine link that crosses a coarse link takes its dual, the one inside
/// a coarse pixel the mean of its two coarse links, so that the fine
/// divergence is half the coarse one at every pixel (as the halved data
/// duals are); across its links and for the data duals it is constant.
void upsampleDual(const PlanarImage& src, float scale, const float* radius,
                  bool link_h, bool link_v, PlanarImage& dst, int threads) {
  const int W = dst.width(), H = dst.height();
#pragma omp parallel for num_threads(threads) schedule(static)
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const std::size_t i = static_cast<std::size_t>(y) * W + x;
      // Along the links: odd fine index 2k + 1 crosses coarse link k, even
      // 2k lies between coarse links k - 1 and k.
      const int along = link_h ? x : y;
      const int k = along / 2;
      float v[3];
      for (int c = 0; c < 3; ++c) {
        if (!link_h && !link_v) {
          v[c] = coarseDual(src, c, x / 2, y / 2, false, false);
        } else if (along % 2 == 1) {
          v[c] = link_h ? coarseDual(src, c, k, y / 2, true, false)
                        : coarseDual(src, c, x / 2, k, false, true);
        } else {
          v[c] =
              0.5f * (link_h ? coarseDual(src, c, k - 1, y / 2, true, false) +
                                   coarseDual(src, c, k, y / 2, true, false)
                             : coarseDual(src, c, x / 2, k - 1, false, true) +
                                   coarseDual(src, c, x / 2, k, false, true));
        }
        v[c] *= scale;
      }
      clampToRadius(v[0], v[1], v[2], radius[i]);
      const bool outside = (link_h && x + 1 == W) || (link_v && y + 1 == H);
      for (int c = 0; c < 3; ++c) dst.plane(c)[i] = outside ? 0.0f : v[c];
    }
  }
}

}  // namespace

void upsampleDuals(const PlanarImage& coarse_p_h, const PlanarImage& coarse_p_v,
                   const std::vector<PlanarImage>& coarse_q,
                   const PreparedLevel& fine, IterationState& state,
                   int threads) {
  upsampleDual(coarse_p_h, 1.0f, fine.edge_weight.plane(0), true, false,
               state.p_h, threads);
  upsampleDual(coarse_p_v, 1.0f, fine.edge_weight.plane(1), false, true,
               state.p_v, threads);
  for (int l = 0; l < fine.num_inputs; ++l) {
    upsampleDual(coarse_q[l], 0.5f, fine.data_weight[l].plane(0), false, false,
                 state.q[l], threads);
  }
}

/// n <- n / |n| per pixel (the projection onto the sphere; |n| >= 1 on the
/// tangent plane).
void normalizeInto(const PlanarImage& n, PlanarImage& out, int threads) {
  out.resizeKeepingCapacity(n.width(), n.height(), 3);
  const long N = static_cast<long>(n.pixelCount());
  const float* nx = n.plane(0);
  const float* ny = n.plane(1);
  const float* nz = n.plane(2);
  float* ox = out.plane(0);
  float* oy = out.plane(1);
  float* oz = out.plane(2);
#pragma omp parallel for num_threads(threads) schedule(static)
  for (long i = 0; i < N; ++i) {
    const float inv =
        1.0f / std::sqrt(nx[i] * nx[i] + ny[i] * ny[i] + nz[i] * nz[i]);
    ox[i] = nx[i] * inv;
    oy[i] = ny[i] * inv;
    oz[i] = nz[i] * inv;
  }
}

void sanitizeWarmStart(const PreparedLevel& level, VisibilityMode mode,
                       PlanarImage& n, std::vector<unsigned char>& unknown,
                       int threads) {
  const int W = level.width;
  unknown.resize(static_cast<std::size_t>(W) * level.height);
  const bool soft = mode == VisibilityMode::kSoft;
  const float Ki[9] = {
      static_cast<float>(level.K_inv[0]), static_cast<float>(level.K_inv[1]),
      static_cast<float>(level.K_inv[2]), static_cast<float>(level.K_inv[3]),
      static_cast<float>(level.K_inv[4]), static_cast<float>(level.K_inv[5]),
      static_cast<float>(level.K_inv[6]), static_cast<float>(level.K_inv[7]),
      static_cast<float>(level.K_inv[8])};
#pragma omp parallel for num_threads(threads) schedule(static)
  for (int y = 0; y < level.height; ++y) {
    const std::size_t row = static_cast<std::size_t>(y) * W;
    (soft ? sanitizeWarmRow<true>
          : sanitizeWarmRow<false>)(W, static_cast<float>(y), Ki,
                                    n.plane(0) + row, n.plane(1) + row,
                                    n.plane(2) + row, unknown.data() + row);
    // The missing ones start as a cold start would.
    for (int x = 0; x < W; ++x) {
      if (unknown[row + x] == 0) continue;
      float v[3];
      coldNormal(level, mode, x, y, v);
      for (int c = 0; c < 3; ++c) n.plane(c)[row + x] = v[c];
    }
  }
}
}  // namespace internal
}  // namespace normal_fusion
