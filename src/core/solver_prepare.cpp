// Input preparation of the finest level: each input converted to the
// optical frame with its weights, the pixels with an observation, the links
// inside holes weakened, and each input's local statistics (Huber
// thresholds, density correction, window means of the warm-start checks).
#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <vector>

#include "normal_fusion/detail/multiversion.h"
#include "normal_fusion/detail/noise_estimate.h"
#include "normal_fusion/detail/solver_internal.h"

namespace normal_fusion {
namespace internal {

namespace {

/// The largest finite float (comparisons against it reject infinities and
/// NaN alike).
constexpr float kFloatMax = std::numeric_limits<float>::max();

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

namespace {

/// c <- c w / mean(c | c > 0), w = lambda times the input's weight: the
/// confidence's mean over the observed pixels becomes 1, so that it ranks
/// the input's observations and leaves the level of its data term to w.
void normalizeConfidence(PlanarImage& data_weight, float global_weight,
                         int threads) {
  float* c = data_weight.plane(0);
  const long pixels = static_cast<long>(data_weight.pixelCount());
  double sum = 0.0;
  long observed = 0;
#pragma omp parallel for num_threads(threads) schedule(static) reduction(+ : sum, observed)
  for (long i = 0; i < pixels; ++i) {
    sum += c[i];
    observed += c[i] > 0.0f ? 1 : 0;
  }
  if (observed == 0 || !(sum > 0.0)) return;
  const float factor = static_cast<float>(static_cast<double>(global_weight) *
                                          static_cast<double>(observed) / sum);
#pragma omp parallel for num_threads(threads) schedule(static)
  for (long i = 0; i < pixels; ++i) c[i] *= factor;
}

/// Input l of the problem into the level's f_l and c_l (the level's size and
/// K set): converted to the optical frame row by row, then in hard
/// visibility mode the observations facing away from the camera dropped.
void convertInput(const NormalInput& input, const SolverSettings& settings,
                  PreparedLevel& level, int l, int threads) {
  const int W = level.width, H = level.height;
  const bool hard = settings.visibility == VisibilityMode::kHard;
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
                                   conf_in != nullptr ? conf_in + row : nullptr,
                                   level.data[l].plane(0) + row,
                                   level.data[l].plane(1) + row,
                                   level.data[l].plane(2) + row,
                                   level.data_weight[l].plane(0) + row);
    if (hard) {
      // Facing away from the camera (r . f > 0): ignored.
      float* f[3] = {level.data[l].plane(0) + row, level.data[l].plane(1) + row,
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
  if (conf_in != nullptr && settings.confidence_relative) {
    normalizeConfidence(level.data_weight[l], global_weight, threads);
  }
}

/// Pixels with at least one usable observation (c_l > 0 for some l).
long countValidPixels(const PreparedLevel& level, int threads) {
  const int W = level.width, H = level.height, L = level.num_inputs;
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
  return valid;
}

/// applyLocalStatistics() with the input's noise gain g across scales
/// (estimateNoise()): delta = data_eps + g data_eps_local s, so that the
/// threshold reads the noise a wide window sees where the local one misses
/// what neighbours share, and c *= g^-noise_weight_power, since such an
/// input's neighbouring pixels repeat one error rather than average it.
void applyNoiseGain(const SolverSettings& settings, float gain,
                    const PlanarImage& data, PlanarImage& data_eps,
                    PlanarImage& data_weight, PlanarImage* mean_spread,
                    int threads) {
  SolverSettings scaled = settings;
  scaled.data_eps_local *= gain;
  applyLocalStatistics(scaled, data, data_eps, data_weight, mean_spread,
                       threads);
  if (settings.noise_weight_power > 0.0 && gain > 1.0f) {
    // c <- c g^-p (fixed before the solve, like the density correction).
    const float factor = static_cast<float>(
        std::pow(static_cast<double>(gain), -settings.noise_weight_power));
    float* c = data_weight.plane(0);
    const std::size_t pixels = data_weight.pixelCount();
    for (std::size_t i = 0; i < pixels; ++i) c[i] *= factor;
  }
}

}  // namespace

bool prepareFinestInto(const FusionProblem& problem,
                       const SolverSettings& settings, PreparedLevel& level,
                       EdgeWeightScratch& scratch, int threads,
                       const std::atomic<bool>* cancel,
                       NoiseGainMemory* noise_gains, bool reuse_noise_gains) {
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
  for (int l = 0; l < level.num_inputs; ++l) {
    if (stopRequested(cancel)) return false;
    convertInput(problem.inputs[l], settings, level, l, threads);
  }
  const long valid = countValidPixels(level, threads);
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
  const bool estimates = settings.noise_radius > settings.local_radius;
  // The kept gains stand for this frame's when they are the same inputs'
  // (a warm frame) and recent enough.
  const bool reuse =
      estimates && noise_gains != nullptr && reuse_noise_gains &&
      noise_gains->gains.size() == static_cast<std::size_t>(level.num_inputs) &&
      noise_gains->uses < NoiseGainMemory::kFrames;
  if (noise_gains != nullptr) {
    if (reuse) {
      ++noise_gains->uses;
    } else {
      noise_gains->clear();
    }
  }
  for (int l = 0; l < level.num_inputs; ++l) {
    if (stopRequested(cancel)) return false;
    level.data_eps[l].resize(W, H, 1);
    if (means) level.data_mean[l].resize(W, H, 4);
    if (estimates) {
      const float gain =
          reuse ? noise_gains->gains[l]
                : estimateNoise(level.data[l], settings.local_radius,
                                settings.noise_radius, threads,
                                settings.noise_plane_residual)
                      .gain;
      if (noise_gains != nullptr && !reuse) noise_gains->gains.push_back(gain);
      applyNoiseGain(settings, gain, level.data[l], level.data_eps[l],
                     level.data_weight[l],
                     means ? &level.data_mean[l] : nullptr, threads);
    } else {
      applyLocalStatistics(settings, level.data[l], level.data_eps[l],
                           level.data_weight[l],
                           means ? &level.data_mean[l] : nullptr, threads);
    }
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
  float* delta = data_eps.plane(0);
  float* c = data_weight.plane(0);
  if (!huber && !density && mean_spread == nullptr) return;
#pragma omp parallel num_threads(threads)
  {
    // Per thread: window sums of f and of the valid count, down the columns
    // (col_*) and then along the row (win_*); grown once, then reused.
    // (Rows of a much wider image give their memory back.)
    thread_local std::vector<float> scratch;
    const int rows_values = WindowSumRows::kRows;
    const std::size_t scratch_values =
        (rows_values + 3) * static_cast<std::size_t>(W);
    releaseIfOversized(scratch, scratch_values);
    if (scratch.size() < scratch_values) scratch.resize(scratch_values);
    WindowSumRows rows(scratch.data(), W);
    const float* const* win = rows.win;
    float* ratio = scratch.data() + rows_values * W;
    float* unused_delta = scratch.data() + (rows_values + 1) * W;
    float* spread = scratch.data() + (rows_values + 2) * W;
#pragma omp for schedule(static)
    for (int y = 0; y < H; ++y) {
      // Resultant of the valid f in the window (f = 0 where missing) and
      // their count.
      windowResultantRow(data, r, y, rows);
      const int window_rows = std::min(H - 1, y + r) - std::max(0, y - r) + 1;
      const std::size_t off = static_cast<std::size_t>(y) * W;
      // delta (written when the data terms use it) and the ratios.
      float* delta_row = huber ? delta + off : unused_delta;
      localStatisticsRow(W, r, window_rows, eps_global, eps_local, win[0],
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
}  // namespace normal_fusion
