// The solver's outer loop: input preparation, initialization, the
// coarse-to-fine pyramid, and the majorize-minimize iteration around the
// Chambolle-Pock inner solver (kernels_reference.cpp / kernels_fast.cpp).
#include "normal_fusion/solver.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <limits>
#include <sstream>

#include "normal_fusion/detail/multiversion.h"
#include "normal_fusion/detail/solver_internal.h"
#include "normal_fusion/errors.h"

namespace normal_fusion {

using internal::InnerParams;
using internal::IterationState;
using internal::PreparedLevel;

namespace {

using Clock = std::chrono::steady_clock;

std::string sizeText(const PlanarImage& image) {
  std::ostringstream s;
  s << image.width() << "x" << image.height() << "x" << image.channels();
  return s.str();
}

/// Iterations per thread per sweep of the fast backend's temporal blocking.
constexpr int kBlockDepth = 6;
/// Pyramid depth chosen when pyramid_levels = 0 and more than 0.5% of the
/// pixels have no valid observation.
constexpr int kAutoPyramidLevels = 5;
/// Outer steps and relative tolerance of the coarser pyramid levels.
constexpr int kCoarseOuterSteps = 4;
constexpr double kCoarseTolerance = 1e-3;
/// Step balance of the coarser levels (SolverSettings::step_balance is for
/// the finest): they exist to carry normals far, into the holes of sparse
/// inputs, in few iterations, so the normals keep the larger steps. Measured
/// (evaluate --cases castle,fusion,stream): with 1 instead of 0.25 the
/// Castle pixels without input 21.39 -> 21.44 dB, its frames solved alone
/// 23.87 -> 23.92 dB, its stream 23.64 -> 23.65 dB; the rest unchanged.
constexpr double kCoarseStepBalance = 1.0;
/// Inner iterations per outer step of a warm start's local refinement: its
/// pixels start far from their solution (filled in) and gain from frequent
/// re-linearization.
constexpr int kRefineStepIterations = 5;
/// Step balance of the local refinement (SolverSettings::step_balance is for
/// whole-image iterations): its duals start reset and its filled normals far
/// from their solution, so the normals keep the larger steps. Measured
/// (bench_streaming, 6 frames): balance 1 leaves the live map 0.029 - 0.050 %
/// above the converged energy, 0.5 0.039 - 0.073 %, 2 0.033 - 0.072 %, and
/// 0.25 0.05 - 0.12 % and growing, 0.65 dB short on average.
constexpr double kRefineStepBalance = 1.0;
/// Safety factor on the predicted cost of the next step near the time
/// budget's end (the machine's speed varies from step to step).
constexpr double kBudgetMargin = 1.5;
/// Passes of the fill of a warm start's unknown pixels (each reaches one
/// pixel further from the known ones).
constexpr int kFillPasses = 16;

/// The largest finite float (comparisons against it reject infinities and
/// NaN alike).
constexpr float kFloatMax = std::numeric_limits<float>::max();

}  // namespace

namespace internal {

namespace {

/// One row of an input in the producer's convention to the optical frame:
/// f = M n_in / |M n_in| and c = weight * clamp(confidence, 0, 1) where the
/// normal is usable (finite, not zero; a non-finite confidence counts as 0);
/// f = 0, c = 0 elsewhere. Branch-free (vectorised); `confidence` is read
/// only with kHasConfidence.
template <bool kHasConfidence>
NF_MULTIVERSION void convertInputRow(
    int W, const float* M_in, float weight, const float* __restrict nx,
    const float* __restrict ny, const float* __restrict nz,
    const float* __restrict confidence, float* __restrict fx,
    float* __restrict fy, float* __restrict fz, float* __restrict c) {
  const float M[9] = {M_in[0], M_in[1], M_in[2], M_in[3], M_in[4],
                      M_in[5], M_in[6], M_in[7], M_in[8]};
  for (int x = 0; x < W; ++x) {
    const float ix = nx[x], iy = ny[x], iz = nz[x];
    // isValidNormal: not zero, not NaN, not infinite (NaN and overflow fail
    // both comparisons).
    const float s = ix * ix + iy * iy + iz * iz;
    const bool usable = (s > 1e-12f) & (s < 1e30f);
    // Clamped to [0, 1]; NaN and infinities count as 0.
    float conf = kHasConfidence ? confidence[x] : 1.0f;
    conf = ((conf >= 0.0f) & (conf <= kFloatMax)) ? std::min(conf, 1.0f) : 0.0f;
    const float ox = M[0] * ix + M[1] * iy + M[2] * iz;
    const float oy = M[3] * ix + M[4] * iy + M[5] * iz;
    const float oz = M[6] * ix + M[7] * iy + M[8] * iz;
    const float inv =
        1.0f / std::sqrt(std::max(ox * ox + oy * oy + oz * oz, 1e-30f));
    const float w = usable ? weight * conf : 0.0f;
    const bool keep = w > 0.0f;
    fx[x] = keep ? ox * inv : 0.0f;
    fy[x] = keep ? oy * inv : 0.0f;
    fz[x] = keep ? oz * inv : 0.0f;
    c[x] = keep ? w : 0.0f;
  }
}

/// True when the data terms carry Huber thresholds: the unsquared penalty
/// with a global or a local part of delta.
bool usesDataHuber(const SolverSettings& settings) {
  return settings.penalty == DataPenalty::kL2 &&
         (settings.data_eps > 0.0 || settings.data_eps_local > 0.0);
}

}  // namespace

bool prepareFinestInto(const FusionProblem& problem,
                       const SolverSettings& settings, PreparedLevel& level,
                       EdgeWeightScratch& scratch, int threads,
                       const std::atomic<bool>* cancel) {
  validateProblem(problem);
  const int W = problem.image.width(), H = problem.image.height();
  level.width = W;
  level.height = H;
  level.num_inputs = static_cast<int>(problem.inputs.size());
  level.K = problem.K;
  level.K_inv = problem.K.inverse();
  level.problem_image = &problem.image;
  computeEdgeWeightsInto(problem.image, settings.edges, level.edge_weight,
                         scratch, threads);
  // A stop request is read between the steps (each one pass or a few).
  if (stopRequested(cancel)) return false;
  level.data.resize(level.num_inputs);
  level.data_weight.resize(level.num_inputs);
  for (int l = 0; l < level.num_inputs; ++l) {
    level.data[l].resize(W, H, 3);
    level.data_weight[l].resize(W, H, 1);
  }
  const bool hard = settings.visibility == VisibilityMode::kHard;
  for (int l = 0; l < level.num_inputs; ++l) {
    if (stopRequested(cancel)) return false;
    const NormalInput& input = problem.inputs[l];
    float M[9];
    for (int k = 0; k < 9; ++k) M[k] = input.orientation.M[k];
    const float global_weight =
        static_cast<float>(settings.lambda * input.weight);
    const float* conf_in =
        input.confidence.empty() ? nullptr : input.confidence.plane(0);
#pragma omp parallel for num_threads(threads) schedule(static)
    for (int y = 0; y < H; ++y) {
      const std::size_t row = static_cast<std::size_t>(y) * W;
      (conf_in != nullptr
           ? convertInputRow<true>
           : convertInputRow<false>)(W, M, global_weight,
                                     input.normals.plane(0) + row,
                                     input.normals.plane(1) + row,
                                     input.normals.plane(2) + row,
                                     conf_in != nullptr ? conf_in + row
                                                        : nullptr,
                                     level.data[l].plane(0) + row,
                                     level.data[l].plane(1) + row,
                                     level.data[l].plane(2) + row,
                                     level.data_weight[l].plane(0) + row);
      if (hard) {
        // Facing away from the camera (r . f > 0): ignored.
        float* f[3] = {level.data[l].plane(0) + row,
                       level.data[l].plane(1) + row,
                       level.data[l].plane(2) + row};
        float* c = level.data_weight[l].plane(0) + row;
        for (int x = 0; x < W; ++x) {
          float r[3];
          level.ray(x, y, r);
          if (r[0] * f[0][x] + r[1] * f[1][x] + r[2] * f[2][x] > 0.0f) {
            f[0][x] = f[1][x] = f[2][x] = 0.0f;
            c[x] = 0.0f;
          }
        }
      }
    }
  }
  // Pixels with at least one usable observation.
  const int L = level.num_inputs;
  long valid = 0;
#pragma omp parallel for num_threads(threads) schedule(static) reduction(+ : valid)
  for (int y = 0; y < H; ++y) {
    const std::size_t row = static_cast<std::size_t>(y) * W;
    const float* c0 = level.data_weight[0].plane(0) + row;
    const float* c1 = L > 1 ? level.data_weight[1].plane(0) + row : c0;
    long count = 0;
    if (L <= 2) {
      for (int x = 0; x < W; ++x) count += c0[x] > 0.0f || c1[x] > 0.0f;
    } else {
      for (int x = 0; x < W; ++x) {
        bool any = false;
        for (int l = 0; l < L; ++l) {
          any = any || level.data_weight[l].plane(0)[row + x] > 0.0f;
        }
        count += any ? 1 : 0;
      }
    }
    valid += count;
  }
  level.valid_pixels = static_cast<int>(valid);
  if (stopRequested(cancel)) return false;
  if (settings.hole_link_weight < 1.0 && valid < static_cast<long>(W) * H) {
    weakenHoleLinks(level, static_cast<float>(settings.hole_link_weight),
                    threads);
  }
  // Local statistics of each input: Huber thresholds of the data terms
  // (unsquared penalty only) and the density correction of the weights.
  level.data_huber = usesDataHuber(settings);
  level.data_eps.resize(level.num_inputs);
  const bool means = settings.warm_refine_iterations > 0;
  level.data_mean.resize(means ? level.num_inputs : 0);
  for (int l = 0; l < level.num_inputs; ++l) {
    if (stopRequested(cancel)) return false;
    level.data_eps[l].resize(W, H, 1);
    if (means) level.data_mean[l].resize(W, H, 4);
    applyLocalStatistics(settings, level.data[l], level.data_eps[l],
                         level.data_weight[l],
                         means ? &level.data_mean[l] : nullptr, threads);
  }
  return true;
}

std::size_t PreparedLevel::bytesHeld() const {
  std::size_t bytes = edge_weight.bytesHeld() + image.bytesHeld();
  for (const std::vector<PlanarImage>* images :
       {&data, &data_weight, &data_eps, &data_mean}) {
    for (const PlanarImage& i : *images) bytes += i.bytesHeld();
  }
  return bytes;
}

void weakenHoleLinks(PreparedLevel& level, float factor, int threads) {
  const int W = level.width, H = level.height;
  // True when some input observes pixel (x, y) (c_l > 0).
  auto observed = [&level](int x, int y) {
    for (int l = 0; l < level.num_inputs; ++l) {
      if (level.data_weight[l].at(0, y, x) > 0.0f) return true;
    }
    return false;
  };
#pragma omp parallel for num_threads(threads) schedule(static)
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      if (observed(x, y)) continue;
      // w_h, w_v of the links to the right and below, when that pixel is not
      // observed either: w <- factor w.
      if (x + 1 < W && !observed(x + 1, y)) {
        level.edge_weight.at(0, y, x) *= factor;
      }
      if (y + 1 < H && !observed(x, y + 1)) {
        level.edge_weight.at(1, y, x) *= factor;
      }
    }
  }
}

namespace {

/// Adds one row of f (3 planes) and its validity (f != 0) to the column sums.
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

/// out(x) = sum of in(u), u = x - r .. x + r inside the row.
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

/// The thresholds delta, the density ratios and the spreads (-1 below 2
/// samples) of one row from its window sums (resultant s, valid count n) and
/// the window's row count. Branch-free (vectorised).
NF_MULTIVERSION
void localStatisticsRow(int W, int r, int rows, float eps_global,
                        float eps_local, const float* __restrict sx,
                        const float* __restrict sy, const float* __restrict sz,
                        const float* __restrict count,
                        const float* __restrict c, float* __restrict delta,
                        float* __restrict ratio, float* __restrict spread_out) {
  for (int x = 0; x < W; ++x) {
    const float n = count[x];
    const float window = static_cast<float>(
        rows * (std::min(W - 1, x + r) - std::max(0, x - r) + 1));
    // s = sqrt(2 (1 - R)), R = |sum f| / count: mean |f - m|^2 = 2 (1 - R)
    // for unit vectors around their normalized mean m; 0 below 2 samples.
    const float R = std::sqrt(sx[x] * sx[x] + sy[x] * sy[x] + sz[x] * sz[x]) /
                    std::max(n, 1.0f);
    const float spread = std::sqrt(std::max(0.0f, 2.0f * (1.0f - R))) *
                         (n >= 2.0f ? 1.0f : 0.0f);
    // delta(x) = data_eps + data_eps_local * s(x), at most 2 (the largest
    // distance of unit vectors).
    delta[x] = std::min(2.0f, eps_global + eps_local * spread);
    spread_out[x] = n >= 2.0f ? spread : -1.0f;
    // window / count where the density correction applies (c > 0,
    // 0 < n < window), else 1.
    const float applies =
        ((c[x] > 0.0f) & (n > 0.0f) & (n < window)) ? 1.0f : 0.0f;
    ratio[x] = 1.0f + applies * (window / std::max(n, 1.0f) - 1.0f);
  }
}

/// One row of the window means m = s / |s| of a resultant s (0 where |s| is
/// tiny) and the spread (-1 there). Branch-free (vectorised).
NF_MULTIVERSION
void meanSpreadRow(int W, const float* __restrict sx,
                   const float* __restrict sy, const float* __restrict sz,
                   const float* __restrict spread, float* __restrict mx,
                   float* __restrict my, float* __restrict mz,
                   float* __restrict m_spread) {
  for (int x = 0; x < W; ++x) {
    const float ax = sx[x], ay = sy[x], az = sz[x], s = spread[x];
    const float len = std::sqrt(ax * ax + ay * ay + az * az);
    const float some = len > 1e-6f ? 1.0f : 0.0f;
    const float inv = some / std::max(len, 1e-6f);
    mx[x] = ax * inv;
    my[x] = ay * inv;
    mz[x] = az * inv;
    m_spread[x] = some * s + (some - 1.0f);
  }
}

}  // namespace

void applyLocalStatistics(const SolverSettings& settings,
                          const PlanarImage& data, PlanarImage& data_eps,
                          PlanarImage& data_weight, PlanarImage* mean_spread,
                          int threads) {
  const int W = data.width(), H = data.height();
  const int r = settings.local_radius;
  const bool huber = usesDataHuber(settings);
  const bool density = settings.density_power > 0.0;
  const float density_power = static_cast<float>(settings.density_power);
  const float eps_global = static_cast<float>(settings.data_eps);
  const float eps_local = static_cast<float>(settings.data_eps_local);
  const float* fx = data.plane(0);
  const float* fy = data.plane(1);
  const float* fz = data.plane(2);
  float* delta = data_eps.plane(0);
  float* c = data_weight.plane(0);
  if (!huber && !density && mean_spread == nullptr) return;
#pragma omp parallel num_threads(threads)
  {
    // Per thread: window sums of f and of the valid count, down the columns
    // (col_*) and then along the row (win_*); grown once, then reused.
    // (Rows of a much wider image give their memory back.)
    thread_local std::vector<float> scratch;
    const std::size_t scratch_values = 11 * static_cast<std::size_t>(W);
    releaseIfOversized(scratch, scratch_values);
    if (scratch.size() < scratch_values) scratch.resize(scratch_values);
    float* ratio = scratch.data() + 8 * W;
    float* unused_delta = scratch.data() + 9 * W;
    float* spread = scratch.data() + 10 * W;
    float* col[4] = {scratch.data(), scratch.data() + W, scratch.data() + 2 * W,
                     scratch.data() + 3 * W};
    float* win[4] = {scratch.data() + 4 * W, scratch.data() + 5 * W,
                     scratch.data() + 6 * W, scratch.data() + 7 * W};
#pragma omp for schedule(static)
    for (int y = 0; y < H; ++y) {
      const int y0 = std::max(0, y - r), y1 = std::min(H - 1, y + r);
      // Resultant of the valid f in the window (f = 0 where missing) and
      // their count, separably: the rows y0 .. y1 summed per column ...
      for (int k = 0; k < 4; ++k) std::fill(col[k], col[k] + W, 0.0f);
      for (int v = y0; v <= y1; ++v) {
        const std::size_t off = static_cast<std::size_t>(v) * W;
        columnSums(W, fx + off, fy + off, fz + off, col[0], col[1], col[2],
                   col[3]);
      }
      // ... then the columns x - r .. x + r.
      for (int k = 0; k < 4; ++k) windowSums(W, r, col[k], win[k]);
      const std::size_t off = static_cast<std::size_t>(y) * W;
      // delta (written when the data terms use it) and the ratios.
      float* delta_row = huber ? delta + off : unused_delta;
      localStatisticsRow(W, r, y1 - y0 + 1, eps_global, eps_local, win[0],
                         win[1], win[2], win[3], c + off, delta_row, ratio,
                         spread);
      // The normalized window mean m and the spread s, before the density
      // correction changes c (0 and -1 where there is none).
      if (mean_spread != nullptr) {
        meanSpreadRow(W, win[0], win[1], win[2], spread,
                      mean_spread->plane(0) + off, mean_spread->plane(1) + off,
                      mean_spread->plane(2) + off, mean_spread->plane(3) + off);
      }
      // c(x) *= (window / count)^density_power: a sample of a sparse input
      // speaks for the pixels around it that the input misses.
      if (density_power == 1.0f) {
        for (int x = 0; x < W; ++x) c[off + x] *= ratio[x];
      } else if (density) {
        for (int x = 0; x < W; ++x) {
          if (ratio[x] != 1.0f) c[off + x] *= std::pow(ratio[x], density_power);
        }
      }
    }
  }
}

PreparedLevel prepareFinest(const FusionProblem& problem,
                            const SolverSettings& settings) {
  PreparedLevel level;
  EdgeWeightScratch scratch;
  prepareFinestInto(problem, settings, level, scratch,
                    resolveThreadCount(settings.num_threads));
  return level;
}

}  // namespace internal

namespace {

/// The next coarser level (into reused buffers): 2x2 blocks, validity-weighted
/// means of the data (normalized), weights averaged and doubled (the data term
/// scales with area, the smoothness term with length), K scaled, edge weights
/// recomputed.
void downsampleInto(const PreparedLevel& fine, const SolverSettings& settings,
                    PreparedLevel& coarse, internal::EdgeWeightScratch& scratch,
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
  internal::computeEdgeWeightsInto(coarse.image, settings.edges,
                                   coarse.edge_weight, scratch, threads);
}

/// Cold start of one pixel: the first input with a usable observation
/// (projected onto the visible set in soft mode), else -r/|r|.
void coldNormal(const PreparedLevel& level, VisibilityMode mode, int x, int y,
                float v[3]) {
  float r[3];
  level.ray(x, y, r);
  for (int l = 0; l < level.num_inputs; ++l) {
    if (level.data_weight[l].at(0, y, x) > 0.0f) {
      for (int c = 0; c < 3; ++c) v[c] = level.data[l].at(c, y, x);
      if (mode == VisibilityMode::kSoft) internal::projectVisible(r, v);
      return;
    }
  }
  const float rl = std::sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2]);
  for (int c = 0; c < 3; ++c) v[c] = -r[c] / rl;
}

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
      // projectVisible(): facing away (r . v > 0) -> onto the plane normal
      // to r, or -r / |r| when v is (nearly) r itself.
      const float fx = static_cast<float>(x);
      const float r0 = Ki[0] * fx + ry0, r1 = Ki[3] * fx + ry1,
                  r2 = Ki[6] * fx + ry2;
      const float rn = r0 * v0 + r1 * v1 + r2 * v2;
      const float rr = r0 * r0 + r1 * r1 + r2 * r2;
      const float m0 = v0 * rr - r0 * rn, m1 = v1 * rr - r1 * rn,
                  m2 = v2 * rr - r2 * rn;
      const float m_len = std::sqrt(m0 * m0 + m1 * m1 + m2 * m2);
      const bool away = rn > 0.0f;
      const bool degenerate = m_len <= 1e-6f * rr;
      const float inv_m = 1.0f / (degenerate ? 1.0f : m_len);
      const float inv_r = 1.0f / std::sqrt(rr);
      const float p0 = degenerate ? -r0 * inv_r : m0 * inv_m;
      const float p1 = degenerate ? -r1 * inv_r : m1 * inv_m;
      const float p2 = degenerate ? -r2 * inv_r : m2 * inv_m;
      v0 = away ? p0 : v0;
      v1 = away ? p1 : v1;
      v2 = away ? p2 : v2;
    }
    nx[x] = usable ? v0 : nx[x];
    ny[x] = usable ? v1 : ny[x];
    nz[x] = usable ? v2 : nz[x];
  }
}

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
      if (mode == VisibilityMode::kSoft) internal::projectVisible(r, v);
      for (int c = 0; c < 3; ++c) n.at(c, y, x) = v[c];
    }
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

}  // namespace

namespace internal {

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

double energy(const PreparedLevel& level, double huber_eps, DataPenalty penalty,
              const PlanarImage& normals, int num_threads) {
  const int W = level.width, H = level.height;
  double total = 0.0;
#pragma omp parallel for num_threads(num_threads) reduction(+ : total) schedule(static)
  for (int y = 0; y < H; ++y) {
    double row_sum = 0.0;
    for (int x = 0; x < W; ++x) {
      const double n[3] = {normals.at(0, y, x), normals.at(1, y, x),
                           normals.at(2, y, x)};
      // Data terms: sum_l c_l phi(n - f_l).
      row_sum +=
          dataEnergyAt(level, penalty, static_cast<std::size_t>(y) * W + x, n);
      // Smoothness: w_h huber(grad_h n) + w_v huber(grad_v n).
      if (x + 1 < W) {
        double g2 = 0.0;
        for (int ch = 0; ch < 3; ++ch) {
          const double g = normals.at(ch, y, x + 1) - n[ch];
          g2 += g * g;
        }
        row_sum += level.edge_weight.at(0, y, x) *
                   huberPenalty(std::sqrt(g2), huber_eps);
      }
      if (y + 1 < H) {
        double g2 = 0.0;
        for (int ch = 0; ch < 3; ++ch) {
          const double g = normals.at(ch, y + 1, x) - n[ch];
          g2 += g * g;
        }
        row_sum += level.edge_weight.at(1, y, x) *
                   huberPenalty(std::sqrt(g2), huber_eps);
      }
    }
    total += row_sum;
  }
  return total;
}

}  // namespace internal

void validateProblem(const FusionProblem& problem) {
  const ColorImage& image = problem.image;
  if (image.empty() || image.width() < 2 || image.height() < 2) {
    throw InputError("image: expected at least 2x2 pixels, got " +
                     sizeText(image));
  }
  if (image.channels() != 1 && image.channels() != 3) {
    throw InputError("image: expected 1 (grey) or 3 (RGB) channels, got " +
                     std::to_string(image.channels()));
  }
  // Every value finite (v - v is 0 exactly then, NaN otherwise); one
  // branch-free pass.
  const std::size_t total = image.pixelCount() * image.channels();
  const float* values = image.data();
  unsigned bad = 0;
  for (std::size_t i = 0; i < total; ++i) {
    bad |= values[i] - values[i] == 0.0f ? 0u : 1u;
  }
  if (bad != 0) {
    throw InputError(
        "image: expected finite intensities, found a non-finite value");
  }
  problem.K.validate();
  if (problem.inputs.empty()) {
    throw InputError(
        "inputs: expected at least one normal map (no data terms given)");
  }
  for (std::size_t l = 0; l < problem.inputs.size(); ++l) {
    const NormalInput& in = problem.inputs[l];
    const std::string name = "input " + std::to_string(l);
    if (in.normals.channels() != 3) {
      throw InputError(name + ": expected 3 channels (x, y, z), got " +
                       std::to_string(in.normals.channels()));
    }
    if (!in.normals.sameSize(image)) {
      throw InputError(name + ": expected the image's size " +
                       std::to_string(image.width()) + "x" +
                       std::to_string(image.height()) + ", got " +
                       sizeText(in.normals));
    }
    if (!in.confidence.empty() &&
        (in.confidence.channels() != 1 || !in.confidence.sameSize(image))) {
      throw InputError(
          name + ": expected a 1-channel confidence of the image's size, got " +
          sizeText(in.confidence));
    }
    if (!std::isfinite(in.weight) || in.weight < 0.0) {
      std::ostringstream msg;
      msg << name << ": weight = " << in.weight
          << ", expected a finite value >= 0";
      throw ParameterError(msg.str());
    }
    in.orientation.validate();
  }
}

bool SolverState::compatible(int width, int height, int num_inputs) const {
  return normals.width() == width && normals.height() == height &&
         normals.channels() == 3 && dual_h.sameSize(normals) &&
         dual_v.sameSize(normals) &&
         static_cast<int>(dual_data.size()) == num_inputs &&
         std::all_of(
             dual_data.begin(), dual_data.end(),
             [this](const PlanarImage& q) { return q.sameSize(normals); });
}

void SolverState::resize(int width, int height, int num_inputs) {
  normals.resize(width, height, 3);
  dual_h.resize(width, height, 3);
  dual_v.resize(width, height, 3);
  dual_data.resize(num_inputs);
  for (PlanarImage& q : dual_data) q.resize(width, height, 3);
}

void SolverState::clear() {
  normals = NormalMap();
  dual_h = PlanarImage();
  dual_v = PlanarImage();
  dual_data.clear();
}

std::size_t SolverState::bytesHeld() const {
  std::size_t bytes =
      normals.bytesHeld() + dual_h.bytesHeld() + dual_v.bytesHeld();
  for (const PlanarImage& q : dual_data) bytes += q.bytesHeld();
  return bytes;
}

namespace {

/// Seconds from `t` to now.
double secondsSince(Clock::time_point t) {
  return std::chrono::duration<double>(Clock::now() - t).count();
}

}  // namespace

class SolverImpl {
 public:
  explicit SolverImpl(const SolverSettings& settings) : settings_(settings) {
    settings_.validate();
  }

  SolverSettings settings_;

  /// Solves into `report` (its vectors keep their capacity: no allocation in
  /// steady state when the caller reuses it).
  void solve(const FusionProblem& problem, SolverState& out, bool warm,
             SolveReport& report) {
    const Clock::time_point start = Clock::now();
    solve_start_ = start;
    const Clock::time_point budget_start =
        has_budget_start_ ? budget_start_ : start;
    has_budget_start_ = false;
    setDeadline(budget_start, settings_.time_budget_ms);
    threads_ = resolveThreadCount(settings_.num_threads);
    if (refine_threads_.maxThreads() != threads_)
      refine_threads_.reset(threads_);
    cancelled_ = false;

    // Reset the report but keep its vectors' capacity.
    std::vector<double> energies, energy_seconds;
    energies.swap(report.energies);
    energy_seconds.swap(report.energy_seconds);
    report = SolveReport();
    energies.clear();
    energy_seconds.clear();
    report.energies.swap(energies);
    report.energy_seconds.swap(energy_seconds);
    report.energies.reserve(settings_.max_outer_iterations + 1);
    report.energy_seconds.reserve(settings_.max_outer_iterations + 1);

    // A request made before the call: nothing is done, `out` is unchanged.
    if (cancelled()) {
      finishCancelledBeforeStart(report, start);
      return;
    }
    if (levels_.empty()) levels_.resize(1);
    if (!internal::prepareFinestInto(problem, settings_, levels_[0],
                                     edge_scratch_, threads_,
                                     &cancel_request_)) {
      // Stopped while preparing the inputs (here and below, until the
      // levels start): `out` is unchanged.
      cancelled_ = true;
      finishCancelledBeforeStart(report, start);
      return;
    }
    const PreparedLevel& finest = levels_[0];
    const int W = finest.width, H = finest.height, L = finest.num_inputs;
    if (finest.valid_pixels == 0) {
      throw InputError(
          "inputs: no valid observation in any input (all missing, zero weight "
          "or, in hard visibility mode, facing away from the camera)");
    }
    // Throws on bad explicit steps before the state is touched.
    stepSizes(L, settings_.step_balance);
    report.num_inputs = L;
    report.valid_pixels = finest.valid_pixels;
    report.filled_pixels = W * H - finest.valid_pixels;
    fitBuffers(W, H);
    if (cancelled()) {
      finishCancelledBeforeStart(report, start);
      return;
    }

    const bool use_warm = warm && out.compatible(W, H, L);
    if (warm && !use_warm && has_deadline_) {
      // A stream's cold start (a warm start asked for, nothing usable to
      // start from) under a frame budget: its own budget (none by default),
      // since the warm frames after it carry its map on.
      setDeadline(budget_start, settings_.cold_start_budget_ms);
      report.cold_start_budget_used = true;
    }
    if (!use_warm && settings_.warm_refine_iterations > 0) {
      // The local refinement's buffers, for the warm starts to come (sized
      // for 1/16 of the pixels; they grow if a frame needs more).
      active_.preallocate(W, H);
      active_buffers_.preallocate(W, H, L, W * H / 16);
      unknown_.resize(static_cast<std::size_t>(W) * H);
      edge_scratch_map_.resize(static_cast<std::size_t>(W) * H);
      fill_pending_.reserve(static_cast<std::size_t>(W) * H);
    }
    report.warm_started = use_warm;
    remaining_inner_ = settings_.max_total_inner_iterations;

    int num_levels = 1;
    if (!use_warm) {
      // Coarse-to-fine on a cold start.
      int wanted = settings_.pyramid_levels;
      if (wanted == 0) {
        const double missing = 1.0 - static_cast<double>(finest.valid_pixels) /
                                         (static_cast<double>(W) * H);
        wanted = missing > 0.005 ? kAutoPyramidLevels : 1;
      }
      while (num_levels < wanted &&
             std::min(levels_[num_levels - 1].width,
                      levels_[num_levels - 1].height) >= 32 &&
             !cancelled()) {
        if (static_cast<int>(levels_.size()) <= num_levels)
          levels_.emplace_back();
        downsampleInto(levels_[num_levels - 1], settings_, levels_[num_levels],
                       edge_scratch_, threads_);
        ++num_levels;
      }
    }
    releaseUnusedLevels(num_levels);
    report.pyramid_levels = num_levels;
    if (cancelled()) {
      finishCancelledBeforeStart(report, start);
      return;
    }
    report.prepare_seconds = secondsSince(start);

    // Cancelled from here on, the finest level still sets up its start
    // (cheap: a pass or two, no iterations), so that `out` receives unit
    // normals of the problem's size.
    IterationState& s = state_;
    for (int li = num_levels - 1; li >= 0; --li) {
      // Cancelled: the finest level starts from the last level that ran.
      if (li > 0 && li + 1 < num_levels && cancelled()) continue;
      const PreparedLevel& level = levels_[li];
      s.resize(level.width, level.height, level.num_inputs);
      const bool finest_level = li == 0;
      if (finest_level && use_warm) {
        const Clock::time_point warm_start = Clock::now();
        // Warm start: the previous normals (sanitized) and duals, swapped in
        // rather than copied (same sizes: no allocation either way).
        std::swap(s.n0, out.normals);
        internal::sanitizeWarmStart(level, settings_.visibility, s.n0, unknown_,
                                    threads_);
        std::swap(s.p_h, out.dual_h);
        std::swap(s.p_v, out.dual_v);
        for (int l = 0; l < L; ++l) std::swap(s.q[l], out.dual_data[l]);
        // Pixels whose warm normal the current inputs contradict (content
        // that changed or moved unlike the warp assumed) count as unknown.
        const bool refine =
            settings_.warm_refine_iterations > 0 && !cancelled();
        if (refine) {
          report.inconsistent_pixels = internal::markInconsistentPixels(
              level, s.n0, settings_.local_radius, unknown_, threads_);
          // The edges of the warm map: seeds of the refinement too (their
          // warm normals kept as its start), since the camera's translation
          // moves them.
          report.edge_pixels = internal::markMapEdges(
              s.n0, unknown_, edge_scratch_map_, threads_);
        }
        if (refine && !cancelled() &&
            std::any_of(unknown_.begin(), unknown_.end(),
                        [](unsigned char u) { return u != 0; })) {
          active_.build(unknown_, W, H, settings_.warm_refine_radius);
          // Unknown pixels (1) are filled from their known neighbours (the
          // other seeds, 2, keep their warm normals); then the active pixels
          // are refined. unknown_ now says: known.
          for (unsigned char& u : unknown_) u = u == 1 ? 0 : 1;
          if (!cancelled()) {
            internal::fillUnknownPixels(
                level, settings_.huber_eps, settings_.penalty,
                settings_.visibility == VisibilityMode::kSoft, s.n0, unknown_,
                active_, kFillPasses, edge_scratch_map_, fill_pending_,
                threads_, &cancel_request_);
          }
          report.warm_start_seconds = secondsSince(warm_start);
          if (!cancelled()) refineActive(level, s, report);
          report.refine_seconds =
              secondsSince(warm_start) - report.warm_start_seconds;
        } else {
          report.warm_start_seconds = secondsSince(warm_start);
        }
      } else {
        if (li + 1 < num_levels) {
          upsampleNormals(coarse_result_, level, settings_.visibility, s.n0,
                          threads_);
        } else {
          initializeCold(level, settings_.visibility, s.n0, threads_);
        }
        s.p_h.fill(0.0f);
        s.p_v.fill(0.0f);
        for (PlanarImage& q : s.q) q.fill(0.0f);
      }
      if (cancelled()) {
        // Stopped: no iterations (the start stands).
      } else if (finest_level && use_warm &&
                 settings_.warm_refine_iterations > 0 && has_deadline_) {
        // Live (a time budget and the local refinement): the frame's time
        // goes to the refinement, and the frame ends when it does. The
        // whole-image steps after it gained nothing where measured
        // (bench_streaming --iterations 150 --refine 100, camera moving or
        // still, duals reset or warped: every outer step rejected, E would
        // rise) and, started near the deadline, overran it. Their energies
        // are not measured.
      } else if (finest_level && use_warm && !levelFits()) {
        // A warm start under a time budget without the refinement: what is
        // left of the budget would not hold a whole-image step, which is left
        // out (its energies are then not measured).
        report.budget_exhausted = true;
      } else {
        runLevel(level, s, finest_level, report);
      }
      if (!finest_level) coarse_result_ = s.n0;
    }

    // Output: the accepted (unit) normals and the duals for the next frame,
    // swapped out (the state's old buffers become the next solve's scratch).
    // The state's buffers are sized first, so that the iteration state keeps
    // sized buffers: a first solve into an empty state allocates here, not
    // the next (warm) frame. (Not when cancelled: the next solve sizes
    // them.)
    out.dual_data.resize(L);
    if (!cancelled_) {
      out.normals.resize(W, H, 3);
      out.dual_h.resize(W, H, 3);
      out.dual_v.resize(W, H, 3);
      for (PlanarImage& q : out.dual_data) q.resize(W, H, 3);
    }
    std::swap(out.normals, s.n0);
    std::swap(out.dual_h, s.p_h);
    std::swap(out.dual_v, s.p_v);
    for (int l = 0; l < L; ++l) std::swap(out.dual_data[l], s.q[l]);
    if (report.energies.empty()) {
      report.initial_energy = report.final_energy =
          std::numeric_limits<double>::quiet_NaN();
    } else {
      report.final_energy = report.energies.back();
    }
    report.cancelled = cancelled_;
    report.seconds = secondsSince(start);
  }

  /// Solver::bytesHeld().
  std::size_t bytesHeld() const {
    std::size_t bytes = state_.bytesHeld() + candidate_.bytesHeld() +
                        coarse_result_.bytesHeld() + edge_scratch_.bytesHeld() +
                        active_.bytesHeld() + active_buffers_.bytesHeld() +
                        internal::bytesHeld(edge_scratch_map_) +
                        internal::bytesHeld(fill_pending_) +
                        internal::bytesHeld(unknown_) +
                        internal::bytesHeld(n_saved_);
    for (const PreparedLevel& level : levels_) bytes += level.bytesHeld();
    return bytes;
  }

  /// Solver::requestCancel(): set by the caller (any thread), read by the
  /// solve, never cleared by it.
  std::atomic<bool> cancel_request_{false};
  static_assert(std::atomic<bool>::is_always_lock_free,
                "requestCancel() must be a lock-free store (signal handlers)");

 private:
  /// True once this solve has seen the cancel request (latched for the rest
  /// of the solve, so that a request withdrawn meanwhile does not undo what
  /// it stopped).
  bool cancelled() {
    if (!cancelled_ && cancel_request_.load(std::memory_order_relaxed)) {
      cancelled_ = true;
    }
    return cancelled_;
  }

  /// The report of a solve cancelled before its levels started (no
  /// iterations, no energies, the state untouched).
  void finishCancelledBeforeStart(SolveReport& report,
                                  Clock::time_point start) const {
    report.cancelled = true;
    report.initial_energy = report.final_energy =
        std::numeric_limits<double>::quiet_NaN();
    report.prepare_seconds = report.seconds = secondsSince(start);
  }

  /// Gives back the memory of the buffers that every level of a solve
  /// shares, and of those of the warm start, when they were sized for a much
  /// larger image than this one (W x H): more than 4 times what it
  /// needs (PlanarImage::resize()'s rule; the same size never reallocates).
  /// The finest level's own buffers follow the rule as they are prepared.
  void fitBuffers(int W, int H) {
    const std::size_t N = static_cast<std::size_t>(W) * H;
    state_.fit(W, H, threads_);
    internal::releaseIfOversized(candidate_, 3 * N);
    internal::releaseIfOversized(coarse_result_, 3 * N);
    for (std::vector<float>* v :
         {&edge_scratch_.mag_h, &edge_scratch_.mag_v, &edge_scratch_.plane,
          &edge_scratch_.blurred, &edge_scratch_.blur}) {
      internal::releaseIfOversized(*v, N);
    }
    internal::releaseIfOversized(unknown_, N);
    internal::releaseIfOversized(edge_scratch_map_, N);
    internal::releaseIfOversized(fill_pending_, N);
    internal::releaseIfOversized(n_saved_, 3 * N);
    // The refinement's buffers hold room for up to every pixel of the image
    // they were sized for (ActiveSet: its mask, one entry per pixel).
    if (N < active_.mask.capacity() / 4) active_ = internal::ActiveSet();
    if (N < active_buffers_.node_of.capacity() / 4) {
      active_buffers_ = internal::ActiveBuffers();
    }
  }

  /// Releases the pyramid levels past `used` that a much larger image left:
  /// more than 4 times the pixels this image's level of that depth has. (A
  /// stream of one size keeps its cold start's levels for the next one.)
  void releaseUnusedLevels(int used) {
    int w = levels_[0].width, h = levels_[0].height;
    for (int li = 1; li < static_cast<int>(levels_.size()); ++li) {
      w = (w + 1) / 2;
      h = (h + 1) / 2;
      if (li < used) continue;
      const long pixels =
          static_cast<long>(levels_[li].width) * levels_[li].height;
      if (pixels / 4 > static_cast<long>(w) * h) levels_[li] = PreparedLevel();
    }
  }

  IterationState state_;
  PlanarImage candidate_;
  std::vector<unsigned char> edge_scratch_map_;  ///< markMapEdges(), fill
  std::vector<int> fill_pending_;                ///< fillUnknownPixels()
  std::vector<unsigned char> unknown_;      ///< pixels the warm start lacked
  internal::ActiveSet active_;              ///< pixels of the local refinement
  internal::ActiveBuffers active_buffers_;  ///< their variables, gathered
  double level_seconds_ = 0.0;  ///< least cost of the finest level, measured
  std::vector<float>
      n_saved_;  ///< reference refinement: iterate while normalized
  /// Finest first; grown (releaseUnusedLevels() frees what a larger image
  /// left).
  std::vector<PreparedLevel> levels_;
  PlanarImage coarse_result_;
  internal::EdgeWeightScratch edge_scratch_;
  Clock::time_point deadline_;
  Clock::time_point solve_start_;

 public:
  /// Solver::setBudgetStart().
  Clock::time_point budget_start_;
  bool has_budget_start_ = false;

 private:
  bool has_deadline_ = false;
  bool cancelled_ = false;  ///< cancelled(): this solve saw the request
  int threads_ = 1;
  int remaining_inner_ = 0;
  /// The local refinement's thread count per step (kept across frames).
  internal::RefineThreadChooser refine_threads_;

  /// Step sizes for L data terms; throws ParameterError when explicit steps
  /// break tau * sigma * (8 + L) < 1.
  /// `balance` scales the automatic steps (SolverSettings::step_balance).
  InnerParams stepSizes(int num_inputs, double balance) const {
    InnerParams params;
    const double K_norm2 = 8.0 + num_inputs;
    if (settings_.tau > 0.0) {
      if (settings_.tau * settings_.sigma * K_norm2 >= 1.0) {
        std::ostringstream msg;
        msg << "settings tau = " << settings_.tau
            << ", sigma = " << settings_.sigma
            << ": expected tau * sigma * (8 + L) < 1, got "
            << settings_.tau * settings_.sigma * K_norm2;
        throw ParameterError(msg.str());
      }
      params.tau = static_cast<float>(settings_.tau);
      params.sigma = params.sigma_data = static_cast<float>(settings_.sigma);
      return params;  // explicit steps are not balanced
    }
    if (settings_.preconditioning) {
      // Diagonal preconditioning (Pock & Chambolle 2011, alpha = 1): tau =
      // 1 / (column sums of |K|) = 1 / (4 + L), sigma = 1 / (row sums) = 1/2
      // for the differences and 1 for the data terms.
      params.tau = static_cast<float>(1.0 / (4.0 + num_inputs));
      params.sigma = 0.5f;
      params.sigma_data = 1.0f;
    } else {
      params.tau = params.sigma = params.sigma_data =
          static_cast<float>(0.99 / std::sqrt(K_norm2));
    }
    // The normals' and the duals' share of the step (tau * sigma kept).
    params.tau = static_cast<float>(params.tau * balance);
    params.sigma = static_cast<float>(params.sigma / balance);
    params.sigma_data = static_cast<float>(params.sigma_data / balance);
    return params;
  }

  /// Step sizes and model constants of the inner iterations at one level.
  InnerParams innerParams(const PreparedLevel& level, double balance) const {
    InnerParams params = stepSizes(level.num_inputs, balance);
    params.huber_eps = static_cast<float>(settings_.huber_eps);
    params.penalty = settings_.penalty;
    params.soft_visibility = settings_.visibility == VisibilityMode::kSoft;
    params.num_threads = threads_;
    params.block_depth = kBlockDepth;
    params.cancel = &cancel_request_;
    return params;
  }

  /// False when a time budget is set and what is left of it is less than
  /// kBudgetMargin times the least the finest level took last time (unknown
  /// before one ran: true).
  bool levelFits() const {
    if (!has_deadline_) return true;
    const double left =
        std::chrono::duration<double>(deadline_ - Clock::now()).count();
    return left >= kBudgetMargin * level_seconds_;
  }

  /// Local refinement of a warm start (SolverSettings::warm_refine_*):
  /// majorize-minimize on the active pixels, every other pixel fixed, with
  /// short outer steps (kRefineStepIterations). A step is kept when the
  /// active pixels' terms of E do not rise, so E does not; a rejected one
  /// goes on from its iterate on the same tangent planes.
  void refineActive(const PreparedLevel& level, IterationState& s,
                    SolveReport& report) {
    const InnerParams params = innerParams(level, kRefineStepBalance);
    const bool reference = settings_.backend == SolverBackend::kReference;
    const std::vector<int>& pixels = active_.pixels;
    const long count = static_cast<long>(pixels.size());
    report.refined_pixels = static_cast<int>(count);
    internal::ActiveBuffers& b = active_buffers_;
    // Reference: on the images, n = nbar = n0 (everywhere). Fast: gathered.
    double best = 0.0;
    if (reference) {
      s.n = s.n0;
      s.nbar = s.n0;
      best = internal::energyActive(level, settings_.huber_eps,
                                    settings_.penalty, s.n0, active_, threads_);
      if (n_saved_.size() < 3 * pixels.size()) {
        n_saved_.resize(3 * pixels.size());
      }
    } else {
      b.gather(level, s, active_, threads_);
      best = b.energy(settings_.huber_eps, settings_.penalty, threads_);
    }
    int remaining = settings_.warm_refine_iterations;
    double step_seconds = 0.0;  // what the last outer step took
    // A cancel request ends it before a step, or inside one (the step is
    // then dropped: n0 holds the last accepted one).
    while (remaining > 0 && !cancelled()) {
      const Clock::time_point step_start = Clock::now();
      const int k = std::min(kRefineStepIterations, remaining);
      // One thread or all: whichever the last steps found cheaper (the same
      // result either way).
      const int step_threads = reference || !settings_.adaptive_refine_threads
                                   ? threads_
                                   : refine_threads_.choose();
      // What the step will take: the last step's time, or more if its thread
      // count was measured to cost more.
      const double expected_seconds =
          reference ? step_seconds
                    : std::max(step_seconds,
                               refine_threads_.cost(step_threads) * k * count);
      if (has_deadline_ &&
          step_start + std::chrono::duration_cast<Clock::duration>(
                           std::chrono::duration<double>(kBudgetMargin *
                                                         expected_seconds)) >
              deadline_) {
        report.budget_exhausted = true;
        break;
      }
      // Inner iterations, then the candidate n / |n| at the active pixels and
      // its local terms of E.
      double e = 0.0;
      InnerParams step_params = params;
      step_params.num_threads = step_threads;
      const bool ran =
          reference ? internal::runInnerActive(level, params, s, active_, k)
                    : internal::runInnerActiveFast(level, step_params, b, k);
      if (!ran) {
        cancelled_ = true;
        break;
      }
      remaining -= k;
      report.refine_iterations += k;
      if (step_threads < threads_) {
        report.refine_single_thread_iterations += k;
      }
      if (reference) {
        for (long j = 0; j < count; ++j) {
          const int i = pixels[j];
          float* n[3] = {s.n.plane(0) + i, s.n.plane(1) + i, s.n.plane(2) + i};
          const float inv =
              1.0f / std::sqrt(*n[0] * *n[0] + *n[1] * *n[1] + *n[2] * *n[2]);
          for (int c = 0; c < 3; ++c) {
            n_saved_[3 * j + c] = *n[c];  // the iterate, if rejected
            *n[c] *= inv;
          }
        }
        e = internal::energyActive(level, settings_.huber_eps,
                                   settings_.penalty, s.n, active_, threads_);
      } else {
        b.normalizeCandidate();
        e = b.energy(settings_.huber_eps, settings_.penalty, step_threads);
      }
      const bool accepted = e <= best;
      const double decrease = (best - e) / std::max(best, 1e-30);
      if (accepted) {
        best = e;
        if (reference) {
          std::swap(s.n0, s.n);  // s.n (the old n0) equals n0 off the set
          for (long j = 0; j < count; ++j) {
            for (int c = 0; c < 3; ++c) {
              s.n.plane(c)[pixels[j]] = s.nbar.plane(c)[pixels[j]] =
                  s.n0.plane(c)[pixels[j]];
            }
          }
        } else {
          b.acceptCandidate();
        }
      } else if (reference) {
        for (long j = 0; j < count; ++j) {
          for (int c = 0; c < 3; ++c) {
            s.n.plane(c)[pixels[j]] = n_saved_[3 * j + c];
          }
        }
      }
      // Converged: a small decrease, once at least half of the iterations
      // ran (the first steps after the fill can be slow to start: a short
      // step with little decrease is no sign of convergence there).
      if (accepted && decrease < settings_.relative_tolerance &&
          2 * report.refine_iterations >= settings_.warm_refine_iterations) {
        break;
      }
      step_seconds = secondsSince(step_start);
      if (!reference && count > 0) {
        refine_threads_.record(step_threads,
                               step_seconds / (static_cast<double>(k) * count));
      }
    }
    if (!reference) b.scatter(s, threads_);
  }

  /// The solve ends by `budget_ms` after `from` (0 = no deadline).
  void setDeadline(Clock::time_point from, double budget_ms) {
    has_deadline_ = budget_ms > 0.0;
    deadline_ =
        from + std::chrono::duration_cast<Clock::duration>(
                   std::chrono::duration<double, std::milli>(budget_ms));
  }

  /// Majorize-minimize at one level: inner iterations on the tangent plane at
  /// n0, then n0 <- n / |n| when that lowers E (never raises it).
  void runLevel(const PreparedLevel& level, IterationState& s, bool finest,
                SolveReport& report) {
    const InnerParams params = innerParams(
        level, finest ? settings_.step_balance : kCoarseStepBalance);

    auto energy_of = [&](const PlanarImage& n) {
      return settings_.backend == SolverBackend::kReference
                 ? internal::energy(level, settings_.huber_eps,
                                    settings_.penalty, n, threads_)
                 : internal::energyFast(level, settings_.huber_eps,
                                        settings_.penalty, n, threads_);
    };
    const Clock::time_point level_start = Clock::now();
    double best = energy_of(s.n0);
    const double energy_seconds = secondsSince(level_start);
    // What closing an outer step costs (normalize + energy), for the budget.
    double finish_seconds = 1.5 * secondsSince(level_start);
    if (finest) {
      report.initial_energy = best;
      report.energies.push_back(best);
      report.energy_seconds.push_back(secondsSince(solve_start_));
    }
    s.n = s.n0;
    s.nbar = s.n0;
    // Each level may use the whole iteration cap; coarse levels are cheap.
    // Coarse levels only prepare a start for the next finer one: a few outer
    // steps each (kCoarseOuterSteps) and a looser tolerance.
    int remaining =
        finest ? remaining_inner_
               : std::min(settings_.max_total_inner_iterations,
                          kCoarseOuterSteps * settings_.inner_iterations);
    const double tolerance =
        finest ? settings_.relative_tolerance
               : std::max(settings_.relative_tolerance, kCoarseTolerance);
    // Without a budget, whole outer steps; with one, chunks sized so that the
    // next chunk and the closing step still fit (2 iterations to measure
    // first).
    double seconds_per_iteration = 0.0;
    const int max_chunk = has_deadline_ ? 2 : settings_.inner_iterations;
    for (int outer = 0; outer < settings_.max_outer_iterations && remaining > 0;
         ++outer) {
      int done = 0;
      const int target = std::min(settings_.inner_iterations, remaining);
      bool out_of_time = false;
      while (done < target) {
        int k = std::min(max_chunk, target - done);
        if (has_deadline_ && seconds_per_iteration > 0.0) {
          const double left =
              std::chrono::duration<double>(deadline_ - Clock::now()).count() -
              finish_seconds;
          k = std::max(
              1, std::min(target - done,
                          static_cast<int>(left / seconds_per_iteration)));
          k = std::min(k, 4 * threads_ * kBlockDepth);
        }
        const Clock::time_point chunk_start = Clock::now();
        // A cancel request stops the iterations inside the chunk (its
        // iterate is then dropped: n0 is the last accepted step).
        const bool ran = settings_.backend == SolverBackend::kReference
                             ? internal::runInnerReference(level, params, s, k)
                             : internal::runInnerFast(level, params, s, k);
        if (!ran) {
          cancelled_ = true;
          break;
        }
        seconds_per_iteration = secondsSince(chunk_start) / k;
        done += k;
        if (has_deadline_ &&
            Clock::now() + std::chrono::duration_cast<Clock::duration>(
                               std::chrono::duration<double>(
                                   seconds_per_iteration + finish_seconds)) >=
                deadline_) {
          out_of_time = true;
          break;
        }
      }
      if (cancelled()) {
        // Only whole chunks count; the outer step is not closed.
        (finest ? report.inner_iterations : report.coarse_inner_iterations) +=
            done;
        break;
      }
      remaining -= done;
      if (finest) {
        report.inner_iterations += done;
        report.outer_iterations += 1;
      } else {
        report.coarse_inner_iterations += done;
      }
      // Re-linearize: the normalized iterate replaces n0 when E does not rise.
      const Clock::time_point finish_start = Clock::now();
      normalizeInto(s.n, candidate_, threads_);
      const double e = energy_of(candidate_);
      finish_seconds = secondsSince(finish_start);
      if (finest) {
        // The least a finest level costs: its first energy, a first chunk
        // of 2 iterations and one closing step.
        level_seconds_ =
            energy_seconds + 2.0 * seconds_per_iteration + finish_seconds;
      }
      bool converged = false;
      if (e <= best) {
        const double decrease = (best - e) / std::max(best, 1e-30);
        best = e;
        std::swap(s.n0, candidate_);
        s.n = s.n0;
        s.nbar = s.n0;
        if (finest) {
          report.energies.push_back(e);
          report.energy_seconds.push_back(secondsSince(solve_start_));
        }
        converged = decrease < tolerance;
      } else if (finest) {
        report.rejected_outer_steps += 1;
      }
      if (out_of_time) {
        report.budget_exhausted = true;
        break;
      }
      if (converged) {
        if (finest) report.converged = true;
        break;
      }
    }
    if (finest) remaining_inner_ = remaining;
  }
};

Solver::Solver(const SolverSettings& settings)
    : impl_(std::make_unique<SolverImpl>(settings)) {}
Solver::~Solver() = default;
Solver::Solver(Solver&&) noexcept = default;
Solver& Solver::operator=(Solver&&) noexcept = default;

void Solver::setSettings(const SolverSettings& settings) {
  settings.validate();
  impl_->settings_ = settings;
}

const SolverSettings& Solver::settings() const { return impl_->settings_; }

SolveReport Solver::solve(const FusionProblem& problem, SolverState& state,
                          bool warm_start) {
  SolveReport report;
  impl_->solve(problem, state, warm_start, report);
  return report;
}

void Solver::requestCancel() noexcept {
  impl_->cancel_request_.store(true, std::memory_order_relaxed);
}

void Solver::clearCancel() noexcept {
  impl_->cancel_request_.store(false, std::memory_order_relaxed);
}

bool Solver::cancelRequested() const noexcept {
  return impl_->cancel_request_.load(std::memory_order_relaxed);
}

std::size_t Solver::bytesHeld() const { return impl_->bytesHeld(); }

void Solver::setBudgetStart(std::chrono::steady_clock::time_point frame_start) {
  impl_->budget_start_ = frame_start;
  impl_->has_budget_start_ = true;
}

void Solver::solve(const FusionProblem& problem, SolverState& state,
                   bool warm_start, SolveReport& report) {
  impl_->solve(problem, state, warm_start, report);
}

NormalMap Solver::solve(const FusionProblem& problem, SolveReport* report) {
  SolverState state;
  SolveReport r;
  impl_->solve(problem, state, false, r);
  if (report != nullptr) *report = r;
  return std::move(state.normals);
}

double computeEnergy(const FusionProblem& problem,
                     const SolverSettings& settings, const NormalMap& normals) {
  settings.validate();
  const PreparedLevel level = internal::prepareFinest(problem, settings);
  if (normals.channels() != 3 || normals.width() != level.width ||
      normals.height() != level.height) {
    throw InputError(
        "computeEnergy: expected normals of the image's size with "
        "3 channels, got " +
        sizeText(normals));
  }
  return internal::energy(level, settings.huber_eps, settings.penalty, normals,
                          resolveThreadCount(settings.num_threads));
}

}  // namespace normal_fusion
