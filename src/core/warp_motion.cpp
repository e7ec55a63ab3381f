#include "normal_fusion/warp_motion.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <sstream>
#include <string>

#include "normal_fusion/detail/previous_pixel.h"
#include "normal_fusion/errors.h"

namespace normal_fusion {
namespace {

constexpr const char* kWho = "warpStateByMotion";
constexpr std::uint64_t kNoWinner = std::numeric_limits<std::uint64_t>::max();
/// 1 + kMotionWarpSameSurfaceRatio, in the float arithmetic of the test.
const float kSameSurfaceFactor =
    static_cast<float>(1.0 + kMotionWarpSameSurfaceRatio);

/// Where the previous pixels land: X_cur = z A (x, y, 1) + t with A = R K^-1,
/// then (u, v) = the projection of K X_cur.
class Projection {
 public:
  Projection(const CameraIntrinsics& K, const Pose& T_cur_prev)
      : A_(multiply(T_cur_prev.R, K.inverse())), K_(K.K), t_(T_cur_prev.t) {}

  /// The splat of previous pixel (x, y) at depth z_prev: false when it has no
  /// depth, lands behind the camera or reaches no pixel of the W x H image.
  /// (u, v) are rounded to float, as the fast warp stores them.
  bool at(int x, int y, float z_prev, int W, int H, float* u, float* v,
          float* z_cur) const {
    if (!(z_prev > 0.0f) || !(z_prev < std::numeric_limits<float>::max())) {
      return false;
    }
    const double z = z_prev;
    Vec3 X;
    for (int r = 0; r < 3; ++r) {
      X[r] = z * (A_[3 * r] * x + A_[3 * r + 1] * y + A_[3 * r + 2]) + t_[r];
    }
    const Vec3 p = multiply(K_, X);
    if (!(X[2] > 1e-6) || !(p[2] > 1e-12)) return false;
    const double u_cur = p[0] / p[2], v_cur = p[1] / p[2];
    // floor(u) in [-1, W - 1]: at least one of its 2x2 pixels is inside.
    if (!(u_cur >= -1.0 && u_cur < W && v_cur >= -1.0 && v_cur < H)) {
      return false;
    }
    *u = static_cast<float>(u_cur);
    *v = static_cast<float>(v_cur);
    *z_cur = static_cast<float>(X[2]);
    return *u >= -1.0f && *u < W && *v >= -1.0f && *v<H&& * z_cur> 0.0f;
  }

 private:
  Mat3 A_;
  Mat3 K_;
  Vec3 t_;
};

/// The current pixels a splat at coordinate `u` reaches along one axis of
/// `size` pixels: those closer than one pixel (floor(u), and floor(u) + 1
/// unless u is on a pixel centre), clipped to the image; lo > hi for none.
void splatRange(double u, int size, int* lo, int* hi) {
  const double u0 = std::floor(u);
  const int x0 = static_cast<int>(u0);
  *lo = std::max(x0, 0);
  *hi = std::min(u > u0 ? x0 + 1 : x0, size - 1);
}

/// Calls f(j, x, y) for each pixel (x, y) (index j) of the W x H image in
/// rows y_begin .. y_end - 1 that a splat at (u, v) reaches.
template <typename F>
void forEachSplatTarget(double u, double v, int W, int H, int y_begin,
                        int y_end, F&& f) {
  int x_lo, x_hi, y_lo, y_hi;
  splatRange(u, W, &x_lo, &x_hi);
  splatRange(v, H, &y_lo, &y_hi);
  y_lo = std::max(y_lo, y_begin);
  y_hi = std::min(y_hi, y_end - 1);
  for (int y = y_lo; y <= y_hi; ++y) {
    for (int x = x_lo; x <= x_hi; ++x) {
      f(static_cast<std::size_t>(y) * W + x, x, y);
    }
  }
}

/// 0 when pixel (x, y) is the one nearest to the splat at (u, v) (within half
/// a pixel in x and y), 1 for the rest of its 2x2: only pixels that no splat
/// is nearest to take one of the second layer (cracks), so that a surface
/// does not grow over its neighbour by the wider footprint.
std::size_t splatLayer(double u, double v, int x, int y) {
  return std::abs(u - x) <= 0.5 && std::abs(v - y) <= 0.5 ? 0 : 1;
}

std::uint32_t floatBits(float value) {
  std::uint32_t bits;
  std::memcpy(&bits, &value, sizeof bits);
  return bits;
}

float bitsFloat(std::uint32_t bits) {
  float value;
  std::memcpy(&value, &bits, sizeof value);
  return value;
}

/// The splat's squared distance to pixel (x, y) and the previous pixel's
/// index, ordered so that the smaller key wins (nearer; then the lower index).
std::uint64_t winnerKey(double u, double v, int x, int y, std::size_t source) {
  const float d2 = static_cast<float>((u - x) * (u - x) + (v - y) * (v - y));
  return (static_cast<std::uint64_t>(floatBits(d2)) << 32) |
         static_cast<std::uint64_t>(source);
}

bool validSource(const NormalMap& normals, std::size_t i) {
  return isValidNormal(normals.plane(0)[i], normals.plane(1)[i],
                       normals.plane(2)[i]);
}

void checkMotionWarpArguments(const SolverState& state,
                              const ScalarMap& depth_prev_m,
                              const CameraIntrinsics& K, const Pose& T) {
  K.validate();
  internal::checkRotation(T.R, kWho);
  for (double value : T.t) {
    if (!std::isfinite(value)) {
      throw InputError(std::string(kWho) +
                       ": t_cur_prev has a non-finite entry");
    }
  }
  if (state.normals.channels() != 3 || state.normals.width() == 0 ||
      state.normals.height() == 0) {
    throw InputError(std::string(kWho) + ": the state holds no normals");
  }
  if (depth_prev_m.channels() != 1 || !depth_prev_m.sameSize(state.normals)) {
    std::ostringstream text;
    text << kWho << ": the previous depth is " << depth_prev_m.width() << "x"
         << depth_prev_m.height() << " with " << depth_prev_m.channels()
         << " plane(s); expected one plane of " << state.normals.width() << "x"
         << state.normals.height() << " (aligned with the previous image)";
    throw InputError(text.str());
  }
  if (state.normals.pixelCount() >= 0xffffffffu) {
    throw InputError(std::string(kWho) + ": the image has too many pixels");
  }
}

/// The 3-plane groups a warp moves: the normals, then the duals p_h, p_v
/// and each q_l (when present).
PlanarImage& planeGroup(SolverState& state, int g) {
  return g == 0   ? state.normals
         : g == 1 ? state.dual_h
         : g == 2 ? state.dual_v
                  : state.dual_data[g - 3];
}

/// Writes pixel `target` of `warped` from pixel `source` of `state` (rotated
/// by R; normals renormalized) or, for source < 0 or a degenerate normal, as
/// unknown: NaN normals, zero duals. `groups` counts the normals' group and
/// the dual groups to write; reset_duals zeroes the duals instead.
void writePixel(SolverState& state, SolverState& warped, int groups,
                std::size_t target, std::ptrdiff_t source, const float* R,
                bool reset_duals) {
  const std::size_t N = state.normals.pixelCount();
  float n[3] = {0.0f, 0.0f, 0.0f};
  bool known = source >= 0;
  if (known) {
    const float* from = state.normals.data() + source;
    for (int r = 0; r < 3; ++r) {
      n[r] = R[3 * r] * from[0] + R[3 * r + 1] * from[N] +
             R[3 * r + 2] * from[2 * N];
    }
    const float len = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    known = len > 1e-6f;
    for (float& value : n) value = known ? value / len : 0.0f;
  }
  float* to = warped.normals.data() + target;
  for (int c = 0; c < 3; ++c) {
    to[c * N] = known ? n[c] : std::numeric_limits<float>::quiet_NaN();
  }
  for (int g = 1; g < groups; ++g) {
    float* dst = planeGroup(warped, g).data() + target;
    if (!known || reset_duals) {
      for (int c = 0; c < 3; ++c) dst[c * N] = 0.0f;
      continue;
    }
    const float* src = planeGroup(state, g).data() + source;
    for (int r = 0; r < 3; ++r) {
      dst[r * N] =
          R[3 * r] * src[0] + R[3 * r + 1] * src[N] + R[3 * r + 2] * src[2 * N];
    }
  }
}

/// Row y of `warped` from the previous pixels `source[j]` (kNoWinner: none)
/// of `state`: normals rotated by R and renormalized (NaN where none or
/// degenerate), the duals rotated (zero where none) unless
/// DualWarp::kReset; plane by plane, so that the loops stream.
void writeRow(const SolverState& state, SolverState& warped,
              std::uint64_t* source, int y, const float* R, DualWarp dual_warp,
              bool has_duals) {
  const int W = state.normals.width();
  const std::size_t N = state.normals.pixelCount();
  const std::size_t row = static_cast<std::size_t>(y) * W;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const float* n = state.normals.data();
  float* out = warped.normals.data();
  for (int x = 0; x < W; ++x) {
    const std::size_t j = row + x;
    float m[3] = {nan, nan, nan};
    if (source[j] != kNoWinner) {
      const std::size_t k = static_cast<std::size_t>(source[j]);
      for (int r = 0; r < 3; ++r) {
        m[r] = R[3 * r] * n[k] + R[3 * r + 1] * n[N + k] +
               R[3 * r + 2] * n[2 * N + k];
      }
      const float len = std::sqrt(m[0] * m[0] + m[1] * m[1] + m[2] * m[2]);
      const bool known = len > 1e-6f;
      for (float& value : m) value = known ? value / len : nan;
      // A degenerate normal predicts nothing: no duals either.
      if (!known) source[j] = kNoWinner;
    }
    for (int c = 0; c < 3; ++c) out[c * N + j] = m[c];
  }
  // DualWarp::kReset: warpStateByMotion() zeroes the duals, whole planes.
  if (!has_duals || dual_warp == DualWarp::kReset) return;
  const int groups = 2 + static_cast<int>(state.dual_data.size());
  for (int g = 0; g < groups; ++g) {
    const PlanarImage& src_image = g == 0   ? state.dual_h
                                   : g == 1 ? state.dual_v
                                            : state.dual_data[g - 2];
    PlanarImage& dst_image = g == 0   ? warped.dual_h
                             : g == 1 ? warped.dual_v
                                      : warped.dual_data[g - 2];
    float* dst = dst_image.data();
    const float* src = src_image.data();
    for (int x = 0; x < W; ++x) {
      const std::size_t j = row + x;
      float p[3] = {0.0f, 0.0f, 0.0f};
      if (source[j] != kNoWinner) {
        const std::size_t k = static_cast<std::size_t>(source[j]);
        for (int r = 0; r < 3; ++r) {
          p[r] = R[3 * r] * src[k] + R[3 * r + 1] * src[N + k] +
                 R[3 * r + 2] * src[2 * N + k];
        }
      }
      for (int c = 0; c < 3; ++c) dst[c * N + j] = p[c];
    }
  }
}

void rotationAsFloat(const Mat3& R, float out[9]) {
  for (int k = 0; k < 9; ++k) out[k] = static_cast<float>(R[k]);
}

/// The splats of one band of current rows y_begin .. y_end - 1: their
/// z-buffers, their winners and the band's rows of `warped`. Every band
/// reads all splats (skipping the previous rows that land elsewhere) and
/// writes only its own pixels, so that bands run in parallel without
/// atomics and the result does not depend on how the image is banded.
void warpBand(const SolverState& state, MotionWarpScratch& scratch, int y_begin,
              int y_end, const float* R, DualWarp dual_warp, bool has_duals) {
  const int W = state.normals.width(), H = state.normals.height();
  const std::size_t N = state.normals.pixelCount();
  std::uint32_t* nearest = scratch.nearest_depth_bits.data();
  std::uint64_t* winner = scratch.winner.data();
  const float* splat_u = scratch.splat_u.data();
  const float* splat_v = scratch.splat_v.data();
  const float* splat_z = scratch.splat_z.data();
  const float far = std::numeric_limits<float>::infinity();
  const std::size_t first = static_cast<std::size_t>(y_begin) * W;
  const std::size_t last = static_cast<std::size_t>(y_end) * W;
  for (int layer = 0; layer < 2; ++layer) {
    std::fill(nearest + layer * N + first, nearest + layer * N + last,
              floatBits(far));
    std::fill(winner + layer * N + first, winner + layer * N + last, kNoWinner);
  }
  // Calls visit(k, u, v, z, j, x, y) for the splats reaching the band.
  const auto for_each_splat = [&](auto&& visit) {
    for (int sy = 0; sy < H; ++sy) {
      // A splat reaches the rows closer than one pixel to its v.
      if (!(scratch.row_v_max[sy] > y_begin - 1.0f &&
            scratch.row_v_min[sy] < static_cast<float>(y_end))) {
        continue;
      }
      const std::size_t row = static_cast<std::size_t>(sy) * W;
      for (std::size_t k = row; k < row + W; ++k) {
        const float u = splat_u[k], v = splat_v[k], z = splat_z[k];
        if (!(z < far) || !(v > y_begin - 1.0f && v < y_end)) continue;
        forEachSplatTarget(
            u, v, W, H, y_begin, y_end,
            [&](std::size_t j, int x, int y) { visit(k, u, v, z, j, x, y); });
      }
    }
  };
  // The z-buffers: the nearest splat's depth at each pixel, per layer.
  for_each_splat(
      [&](std::size_t, float u, float v, float z, std::size_t j, int x, int y) {
        std::uint32_t& at = nearest[splatLayer(u, v, x, y) * N + j];
        at = std::min(at, floatBits(z));
      });
  // Among the splats of the visible surface, the nearest to the centre.
  for_each_splat([&](std::size_t k, float u, float v, float z, std::size_t j,
                     int x, int y) {
    const std::size_t at = splatLayer(u, v, x, y) * N + j;
    if (z <= bitsFloat(nearest[at]) * kSameSurfaceFactor) {
      winner[at] = std::min(winner[at], winnerKey(u, v, x, y, k));
    }
  });
  // The winners' previous pixels (kNoWinner: none), in the first layer.
  for (std::size_t j = first; j < last; ++j) {
    const std::uint64_t key =
        winner[j] != kNoWinner ? winner[j] : winner[N + j];
    winner[j] = key == kNoWinner ? kNoWinner : (key & 0xffffffffu);
  }
  for (int y = y_begin; y < y_end; ++y) {
    writeRow(state, scratch.state, winner, y, R, dual_warp, has_duals);
  }
}

}  // namespace

void warpStateByMotion(SolverState& state, const ScalarMap& depth_prev_m,
                       const CameraIntrinsics& K, const Pose& T_cur_prev) {
  MotionWarpScratch scratch;
  warpStateByMotion(state, depth_prev_m, K, T_cur_prev, scratch, 1,
                    DualWarp::kRotate);
}

void warpStateByMotion(SolverState& state, const ScalarMap& depth_prev_m,
                       const CameraIntrinsics& K, const Pose& T_cur_prev,
                       MotionWarpScratch& scratch, int num_threads,
                       DualWarp dual_warp) {
  checkMotionWarpArguments(state, depth_prev_m, K, T_cur_prev);
  const int W = state.normals.width(), H = state.normals.height();
  const int L = static_cast<int>(state.dual_data.size());
  const bool has_duals = state.compatible(W, H, L);
  const int threads = resolveThreadCount(num_threads);
  scratch.resize(W, H, has_duals ? L : -1);
  const float far = std::numeric_limits<float>::infinity();
  const Projection projection(K, T_cur_prev);
  const float* depth = depth_prev_m.plane(0);
  float Rf[9];
  rotationAsFloat(T_cur_prev.R, Rf);
  const DualWarp duals = has_duals ? dual_warp : DualWarp::kReset;
  // Bands of current rows, a few per thread (their costs differ).
  const int bands = std::min(H, 4 * threads);
#pragma omp parallel num_threads(threads)
  {
    // Where each previous pixel lands (z = +inf: nowhere), and each
    // previous row's range of v.
#pragma omp for schedule(static)
    for (int sy = 0; sy < H; ++sy) {
      float v_min = far, v_max = -far;
      for (int sx = 0; sx < W; ++sx) {
        const std::size_t k = static_cast<std::size_t>(sy) * W + sx;
        float u, v, z;
        if (!validSource(state.normals, k) ||
            !projection.at(sx, sy, depth[k], W, H, &u, &v, &z)) {
          scratch.splat_z[k] = far;
          continue;
        }
        scratch.splat_u[k] = u;
        scratch.splat_v[k] = v;
        scratch.splat_z[k] = z;
        v_min = std::min(v_min, v);
        v_max = std::max(v_max, v);
      }
      scratch.row_v_min[sy] = v_min;
      scratch.row_v_max[sy] = v_max;
    }
#pragma omp for schedule(dynamic, 1)
    for (int b = 0; b < bands; ++b) {
      warpBand(state, scratch, H * b / bands, H * (b + 1) / bands, Rf, duals,
               has_duals);
    }
    if (has_duals && duals == DualWarp::kReset) {
      // All duals zero: whole planes at once (large blocks, which the C
      // library writes faster than rows), in as many parts as threads.
      const std::size_t N = state.normals.pixelCount();
      const int parts = 3 * (2 + L) * threads;
#pragma omp for schedule(static)
      for (int part = 0; part < parts; ++part) {
        const int plane = part / threads, share = part % threads;
        float* to =
            planeGroup(scratch.state, 1 + plane / 3).data() + (plane % 3) * N;
        const std::size_t begin = N * share / threads;
        const std::size_t end = N * (share + 1) / threads;
        std::memset(to + begin, 0, (end - begin) * sizeof(float));
      }
    }
  }
  internal::swapInWarped(state, scratch.state, has_duals);
}

namespace internal {

void warpStateByMotionReference(SolverState& state,
                                const ScalarMap& depth_prev_m,
                                const CameraIntrinsics& K,
                                const Pose& T_cur_prev) {
  checkMotionWarpArguments(state, depth_prev_m, K, T_cur_prev);
  const int W = state.normals.width(), H = state.normals.height();
  const int L = static_cast<int>(state.dual_data.size());
  const bool has_duals = state.compatible(W, H, L);
  SolverState warped;
  if (has_duals) {
    warped.resize(W, H, L);
  } else {
    warped.normals.resize(W, H, 3);
  }
  const Projection projection(K, T_cur_prev);
  float Rf[9];
  rotationAsFloat(T_cur_prev.R, Rf);
  // Does previous pixel (sx, sy) splat onto current pixel (x, y) as its
  // nearest pixel (layer 0: within half a pixel in x and y) or as the rest
  // of its footprint (layer 1: closer than one pixel)? Its position and
  // depth when it does.
  auto reaches = [&](int sx, int sy, int x, int y, int layer, float* u,
                     float* v, float* z) {
    const std::size_t s = static_cast<std::size_t>(sy) * W + sx;
    if (!validSource(state.normals, s) ||
        !projection.at(sx, sy, depth_prev_m.at(0, sy, sx), W, H, u, v, z)) {
      return false;
    }
    const double du = std::abs(static_cast<double>(*u) - x);
    const double dv = std::abs(static_cast<double>(*v) - y);
    const bool nearest = du <= 0.5 && dv <= 0.5;
    return layer == 0 ? nearest : (!nearest && du < 1.0 && dv < 1.0);
  };
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      std::uint64_t best = kNoWinner;
      for (int layer = 0; layer < 2 && best == kNoWinner; ++layer) {
        float z_min = std::numeric_limits<float>::infinity();
        float u, v, z;
        for (int sy = 0; sy < H; ++sy) {
          for (int sx = 0; sx < W; ++sx) {
            if (reaches(sx, sy, x, y, layer, &u, &v, &z)) {
              z_min = std::min(z_min, z);
            }
          }
        }
        for (int sy = 0; sy < H; ++sy) {
          for (int sx = 0; sx < W; ++sx) {
            if (reaches(sx, sy, x, y, layer, &u, &v, &z) &&
                z <= z_min * kSameSurfaceFactor) {
              const std::size_t s = static_cast<std::size_t>(sy) * W + sx;
              best = std::min(best, winnerKey(u, v, x, y, s));
            }
          }
        }
      }
      const std::ptrdiff_t source =
          best == kNoWinner ? -1
                            : static_cast<std::ptrdiff_t>(best & 0xffffffffu);
      writePixel(state, warped, has_duals ? 3 + L : 1,
                 static_cast<std::size_t>(y) * W + x, source, Rf, false);
    }
  }
  internal::swapInWarped(state, warped, has_duals);
}

}  // namespace internal
}  // namespace normal_fusion
