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
  bool at(int x, int y, float z_prev, int W, int H, double* u, double* v,
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
    *u = p[0] / p[2];
    *v = p[1] / p[2];
    *z_cur = static_cast<float>(X[2]);
    // floor(u) in [-1, W - 1]: at least one of its 2x2 pixels is inside.
    return *u >= -1.0 && *u < W && *v >= -1.0 && *v<H&& * z_cur> 0.0f;
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

/// Calls f(j, x, y) for each pixel (x, y) (index j) of the W x H image that
/// a splat at (u, v) reaches.
template <typename F>
void forEachSplatTarget(double u, double v, int W, int H, F&& f) {
  int x_lo, x_hi, y_lo, y_hi;
  splatRange(u, W, &x_lo, &x_hi);
  splatRange(v, H, &y_lo, &y_hi);
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

template <typename T>
void atomicMin(T* target, T value) {
  T current = __atomic_load_n(target, __ATOMIC_RELAXED);
  while (value < current &&
         !__atomic_compare_exchange_n(target, &current, value, true,
                                      __ATOMIC_RELAXED, __ATOMIC_RELAXED)) {
  }
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

/// Swaps the warped buffers in; a state without usable duals keeps none.
void swapIn(SolverState& state, SolverState& warped, bool has_duals) {
  std::swap(state.normals, warped.normals);
  if (has_duals) {
    std::swap(state.dual_h, warped.dual_h);
    std::swap(state.dual_v, warped.dual_v);
    std::swap(state.dual_data, warped.dual_data);
  } else {
    state.dual_h = PlanarImage();
    state.dual_v = PlanarImage();
    state.dual_data.clear();
  }
}

void rotationAsFloat(const Mat3& R, float out[9]) {
  for (int k = 0; k < 9; ++k) out[k] = static_cast<float>(R[k]);
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
  const std::size_t N = state.normals.pixelCount();
  const int L = static_cast<int>(state.dual_data.size());
  const bool has_duals = state.compatible(W, H, L);
  const int groups = has_duals ? 3 + L : 1;
  const int threads = resolveThreadCount(num_threads);
  scratch.resize(W, H, has_duals ? L : -1);
  SolverState& warped = scratch.state;
  // Per layer (0: the pixel nearest to the splat, 1: its 2x2) and pixel.
  std::uint32_t* nearest = scratch.nearest_depth_bits.data();
  std::uint64_t* winner = scratch.winner.data();
  const std::uint32_t far_bits =
      floatBits(std::numeric_limits<float>::infinity());
  const Projection projection(K, T_cur_prev);
  const float* depth = depth_prev_m.plane(0);
  float Rf[9];
  rotationAsFloat(T_cur_prev.R, Rf);
  const bool reset_duals = dual_warp == DualWarp::kReset;
  // Calls visit(k, u, v, z, target, x, y) for each pixel (x, y) that
  // previous pixel k's splat at (u, v), depth z, reaches.
  const auto splats_of_row = [&](int sy, auto&& visit) {
    for (int sx = 0; sx < W; ++sx) {
      const std::size_t k = static_cast<std::size_t>(sy) * W + sx;
      double u, v;
      float z;
      if (!validSource(state.normals, k) ||
          !projection.at(sx, sy, depth[k], W, H, &u, &v, &z)) {
        continue;
      }
      forEachSplatTarget(u, v, W, H, [&](std::size_t j, int x, int y) {
        visit(k, u, v, z, j, x, y);
      });
    }
  };
#pragma omp parallel num_threads(threads)
  {
#pragma omp for schedule(static)
    for (std::ptrdiff_t j = 0; j < static_cast<std::ptrdiff_t>(2 * N); ++j) {
      nearest[j] = far_bits;
      winner[j] = kNoWinner;
    }
    // The z-buffers: the nearest splat's depth at each pixel, per layer.
#pragma omp for schedule(static)
    for (int sy = 0; sy < H; ++sy) {
      splats_of_row(sy, [&](std::size_t, double u, double v, float z,
                            std::size_t j, int x, int y) {
        atomicMin(nearest + splatLayer(u, v, x, y) * N + j, floatBits(z));
      });
    }
    // Among the splats of the visible surface, the nearest to the centre.
#pragma omp for schedule(static)
    for (int sy = 0; sy < H; ++sy) {
      splats_of_row(sy, [&](std::size_t k, double u, double v, float z,
                            std::size_t j, int x, int y) {
        const std::size_t at = splatLayer(u, v, x, y) * N + j;
        if (z <= bitsFloat(nearest[at]) * kSameSurfaceFactor) {
          atomicMin(winner + at, winnerKey(u, v, x, y, k));
        }
      });
    }
#pragma omp for schedule(static)
    for (std::ptrdiff_t j = 0; j < static_cast<std::ptrdiff_t>(N); ++j) {
      const std::uint64_t key =
          winner[j] != kNoWinner ? winner[j] : winner[N + j];
      const std::ptrdiff_t source =
          key == kNoWinner ? -1
                           : static_cast<std::ptrdiff_t>(key & 0xffffffffu);
      writePixel(state, warped, groups, static_cast<std::size_t>(j), source, Rf,
                 reset_duals);
    }
  }
  swapIn(state, warped, has_duals);
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
  auto reaches = [&](int sx, int sy, int x, int y, int layer, double* u,
                     double* v, float* z) {
    const std::size_t s = static_cast<std::size_t>(sy) * W + sx;
    if (!validSource(state.normals, s) ||
        !projection.at(sx, sy, depth_prev_m.at(0, sy, sx), W, H, u, v, z)) {
      return false;
    }
    const double du = std::abs(*u - x), dv = std::abs(*v - y);
    const bool nearest = du <= 0.5 && dv <= 0.5;
    return layer == 0 ? nearest : (!nearest && du < 1.0 && dv < 1.0);
  };
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      std::uint64_t best = kNoWinner;
      for (int layer = 0; layer < 2 && best == kNoWinner; ++layer) {
        float z_min = std::numeric_limits<float>::infinity();
        double u, v;
        float z;
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
  swapIn(state, warped, has_duals);
}

}  // namespace internal
}  // namespace normal_fusion
