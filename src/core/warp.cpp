#include "normal_fusion/warp.h"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include "normal_fusion/errors.h"

namespace normal_fusion {
namespace {

/// Bilinear sample of all planes of `src` at (u, v); false when outside.
bool sampleRotated(const PlanarImage& src, double u, double v,
                   const std::array<double, 9>& R, float out[3]) {
  const int W = src.width(), H = src.height();
  if (!(u >= 0.0 && v >= 0.0 && u <= W - 1.0 && v <= H - 1.0)) return false;
  const int x0 = static_cast<int>(u), y0 = static_cast<int>(v);
  const int x1 = std::min(x0 + 1, W - 1), y1 = std::min(y0 + 1, H - 1);
  const float tx = static_cast<float>(u - x0), ty = static_cast<float>(v - y0);
  float s[3];
  for (int c = 0; c < 3; ++c) {
    s[c] = (1 - ty) * ((1 - tx) * src.at(c, y0, x0) + tx * src.at(c, y0, x1)) +
           ty * ((1 - tx) * src.at(c, y1, x0) + tx * src.at(c, y1, x1));
  }
  // Vectors in the previous camera frame to the current one: R s.
  for (int r = 0; r < 3; ++r) {
    out[r] = static_cast<float>(R[3 * r] * s[0] + R[3 * r + 1] * s[1] +
                                R[3 * r + 2] * s[2]);
  }
  return true;
}

/// cos kMaxBlendDegrees.
const float kMinBlendCos =
    static_cast<float>(std::cos(kMaxBlendDegrees * 3.14159265358979 / 180.0));

/// True when the source pixels around (u, v) (inside the image) that carry
/// weight in the bilinear blend hold normals within kMaxBlendDegrees of each
/// other.
bool blendable(const PlanarImage& normals, double u, double v) {
  const int W = normals.width(), H = normals.height();
  const int x0 = static_cast<int>(u), y0 = static_cast<int>(v);
  const double tx = u - x0, ty = v - y0;
  // Weights below 1e-3 (a sample on a pixel centre, up to rounding) do not
  // count.
  const int x_lo = tx > 0.999 ? std::min(x0 + 1, W - 1) : x0;
  const int x_hi = tx > 1e-3 ? std::min(x0 + 1, W - 1) : x0;
  const int y_lo = ty > 0.999 ? std::min(y0 + 1, H - 1) : y0;
  const int y_hi = ty > 1e-3 ? std::min(y0 + 1, H - 1) : y0;
  const int xs[4] = {x_lo, x_hi, x_lo, x_hi};
  const int ys[4] = {y_lo, y_lo, y_hi, y_hi};
  for (int a = 0; a < 4; ++a) {
    for (int b = a + 1; b < 4; ++b) {
      float dot = 0.0f;
      for (int c = 0; c < 3; ++c) {
        dot += normals.at(c, ys[a], xs[a]) * normals.at(c, ys[b], xs[b]);
      }
      if (!(dot >= kMinBlendCos)) return false;  // NaN too
    }
  }
  return true;
}

/// Throws InputError unless R is a rotation (R R^T = I) and the state holds
/// normals.
void checkWarpArguments(const SolverState& state,
                        const std::array<double, 9>& R) {
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) {
      double d = 0.0;
      for (int k = 0; k < 3; ++k) d += R[3 * i + k] * R[3 * j + k];
      if (!std::isfinite(d) || std::abs(d - (i == j ? 1.0 : 0.0)) > 1e-4) {
        throw InputError("warpStateByRotation: R is not a rotation matrix");
      }
    }
  }
  if (state.normals.channels() != 3 || state.normals.width() == 0 ||
      state.normals.height() == 0) {
    throw InputError("warpStateByRotation: the state holds no normals");
  }
}

/// Where a current pixel comes from in the previous image: u_prev ~ K R^T
/// K^-1 u_cur, the homography of a camera that rotated by R.
class PreviousPixel {
 public:
  PreviousPixel(const CameraIntrinsics& K, const std::array<double, 9>& R) {
    const std::array<double, 9> K_inv = K.inverse();
    // A = K R^T K^-1.
    double RtKinv[9];
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) {
        RtKinv[3 * i + j] =
            R[i] * K_inv[j] + R[3 + i] * K_inv[3 + j] + R[6 + i] * K_inv[6 + j];
      }
    }
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) {
        A_[3 * i + j] = K.K[3 * i] * RtKinv[j] +
                        K.K[3 * i + 1] * RtKinv[3 + j] +
                        K.K[3 * i + 2] * RtKinv[6 + j];
      }
    }
  }

  /// The previous pixel (u, v) of pixel (x, y); false when it lies outside
  /// the previous W x H image (or behind the camera). Positions within 1e-6
  /// of the border count as on it (rounding of an identity warp).
  bool at(int x, int y, int W, int H, double* u, double* v) const {
    const double w = A_[6] * x + A_[7] * y + A_[8];
    if (!(w > 1e-9)) return false;
    const double inv_w = 1.0 / w;
    *u = clampNear((A_[0] * x + A_[1] * y + A_[2]) * inv_w, W - 1.0);
    *v = clampNear((A_[3] * x + A_[4] * y + A_[5]) * inv_w, H - 1.0);
    return *u >= 0.0 && *v >= 0.0 && *u <= W - 1.0 && *v <= H - 1.0;
  }

  /// A = K R^T K^-1, row-major.
  const double* matrix() const { return A_; }

  static double clampNear(double t, double high) {
    constexpr double kSlack = 1e-6;
    if (t < 0.0 && t > -kSlack) return 0.0;
    if (t > high && t < high + kSlack) return high;
    return t;
  }

 private:
  double A_[9];
};

/// Bilinear blend of 3 planes at the corners i00, i00 + dx | i00 + dy,
/// i00 + dy + dx (weights tx, ty), rotated by R: out = R blend.
inline void bilinearRotate(const float* const src[3], int i00, int dx, int dy,
                           float tx, float ty, const float* R, float out[3]) {
  float s[3];
  for (int c = 0; c < 3; ++c) {
    const float* p = src[c];
    s[c] = (1 - ty) * ((1 - tx) * p[i00] + tx * p[i00 + dx]) +
           ty * ((1 - tx) * p[i00 + dy] + tx * p[i00 + dy + dx]);
  }
  for (int r = 0; r < 3; ++r) {
    out[r] = R[3 * r] * s[0] + R[3 * r + 1] * s[1] + R[3 * r + 2] * s[2];
  }
}

/// Where a chunk of pixels of one row comes from, and their warped normals:
/// the arithmetic of PreviousPixel::at() and blendable() per pixel, then
/// bilinearRotate(), without early exits (GCC 12 does not vectorise its
/// gathers, so it runs scalar). Writes n_cur (NaN where no prediction) and,
/// per pixel, the source's first corner (-1: none), its steps to the right
/// and down, and the blend weights.
void warpNormalsChunk(const double* A, int W, int H, int y, int x_begin,
                      int count, const float* __restrict n0,
                      const float* __restrict n1, const float* __restrict n2,
                      const float* R, float cos_blend, float* __restrict out0,
                      float* __restrict out1, float* __restrict out2,
                      int* __restrict corner, int* __restrict step_x,
                      int* __restrict step_y, float* __restrict t_x,
                      float* __restrict t_y) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (int j = 0; j < count; ++j) {
    const int x = x_begin + j;
    // PreviousPixel::at().
    const double w = A[6] * x + A[7] * y + A[8];
    const double inv_w = 1.0 / w;
    const double u =
        PreviousPixel::clampNear((A[0] * x + A[1] * y + A[2]) * inv_w, W - 1.0);
    const double v =
        PreviousPixel::clampNear((A[3] * x + A[4] * y + A[5]) * inv_w, H - 1.0);
    const bool inside =
        (w > 1e-9) & (u >= 0.0) & (v >= 0.0) & (u <= W - 1.0) & (v <= H - 1.0);
    // Safe indices everywhere (the outside ones are not used).
    const double us = inside ? u : 0.0, vs = inside ? v : 0.0;
    const int x0 = static_cast<int>(us), y0 = static_cast<int>(vs);
    const int dx = x0 + 1 < W ? 1 : 0, dy = y0 + 1 < H ? W : 0;
    const float tx = static_cast<float>(us - x0);
    const float ty = static_cast<float>(vs - y0);
    const int i00 = y0 * W + x0;
    // blendable(): the corners that carry weight, all pairs within
    // kMaxBlendDegrees (NaN fails).
    const int lo_x = tx > 0.999f ? dx : 0, hi_x = tx > 1e-3f ? dx : 0;
    const int lo_y = ty > 0.999f ? dy : 0, hi_y = ty > 1e-3f ? dy : 0;
    const int at[4] = {i00 + lo_y + lo_x, i00 + lo_y + hi_x, i00 + hi_y + lo_x,
                       i00 + hi_y + hi_x};
    // The four corners that carry weight (some may coincide).
    const float ax = n0[at[0]], ay = n1[at[0]], az = n2[at[0]];
    const float bx = n0[at[1]], by = n1[at[1]], bz = n2[at[1]];
    const float cx = n0[at[2]], cy = n1[at[2]], cz = n2[at[2]];
    const float ex = n0[at[3]], ey = n1[at[3]], ez = n2[at[3]];
    const bool blend = (ax * bx + ay * by + az * bz >= cos_blend) &
                       (ax * cx + ay * cy + az * cz >= cos_blend) &
                       (ax * ex + ay * ey + az * ez >= cos_blend) &
                       (bx * cx + by * cy + bz * cz >= cos_blend) &
                       (bx * ex + by * ey + bz * ez >= cos_blend) &
                       (cx * ex + cy * ey + cz * ez >= cos_blend);
    // The blend, rotated into the current frame.
    const float* const src[3] = {n0, n1, n2};
    float n[3];
    bilinearRotate(src, i00, dx, dy, tx, ty, R, n);
    const float len = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    const bool ok = inside & blend & (len > 1e-6f);
    const float safe_len = ok ? len : 1.0f;
    out0[j] = ok ? n[0] / safe_len : nan;
    out1[j] = ok ? n[1] / safe_len : nan;
    out2[j] = ok ? n[2] / safe_len : nan;
    corner[j] = ok ? i00 : -1;
    step_x[j] = dx;
    step_y[j] = dy;
    t_x[j] = tx;
    t_y[j] = ty;
  }
}

}  // namespace

void warpStateByRotation(SolverState& state, const CameraIntrinsics& K,
                         const std::array<double, 9>& R_cur_prev) {
  SolverState scratch;
  warpStateByRotation(state, K, R_cur_prev, scratch, 1, DualWarp::kRotate);
}

void warpStateByRotation(SolverState& state, const CameraIntrinsics& K,
                         const std::array<double, 9>& R_cur_prev,
                         SolverState& scratch, int num_threads,
                         DualWarp dual_warp) {
  const auto& R = R_cur_prev;
  checkWarpArguments(state, R);
  const PreviousPixel previous(K, R);
  const int W = state.normals.width(), H = state.normals.height();
  const std::size_t N = state.normals.pixelCount();
  const int L = static_cast<int>(state.dual_data.size());
  const bool has_duals = state.compatible(W, H, L);
  const int threads =
      num_threads > 0 ? num_threads : std::max(1, omp_get_num_procs());
  // The warped state is written into the scratch buffers (sized once), then
  // swapped in.
  scratch.normals.resize(W, H, 3);
  if (has_duals) {
    scratch.dual_h.resize(W, H, 3);
    scratch.dual_v.resize(W, H, 3);
    scratch.dual_data.resize(L);
    for (PlanarImage& q : scratch.dual_data) q.resize(W, H, 3);
  }
  // The duals' 3-plane groups (p_h, p_v, each q_l), source and destination.
  const int dual_groups = has_duals ? 2 + L : 0;
  auto dual_group = [](SolverState& st, int g) -> PlanarImage& {
    return g == 0 ? st.dual_h : g == 1 ? st.dual_v : st.dual_data[g - 2];
  };
  float Rf[9];
  for (int k = 0; k < 9; ++k) Rf[k] = static_cast<float>(R[k]);
  const float cos_blend = kMinBlendCos;
  const float* n_prev[3] = {state.normals.plane(0), state.normals.plane(1),
                            state.normals.plane(2)};
  float* n_cur[3] = {scratch.normals.plane(0), scratch.normals.plane(1),
                     scratch.normals.plane(2)};
  // Rows in chunks of kChunk pixels: the chunk's source positions and the
  // warped normals first, then each dual group over the chunk.
  constexpr int kChunk = 64;
#pragma omp parallel for num_threads(threads) schedule(static)
  for (int y = 0; y < H; ++y) {
    for (int x_begin = 0; x_begin < W; x_begin += kChunk) {
      const int count = std::min(kChunk, W - x_begin);
      int corner[kChunk];  // i00 of the source, -1: no prediction
      int step_x[kChunk];  // i01 - i00 (0 or 1)
      int step_y[kChunk];  // i10 - i00 (0 or W)
      float t_x[kChunk], t_y[kChunk];
      const std::size_t row = static_cast<std::size_t>(y) * W + x_begin;
      warpNormalsChunk(previous.matrix(), W, H, y, x_begin, count, n_prev[0],
                       n_prev[1], n_prev[2], Rf, cos_blend, n_cur[0] + row,
                       n_cur[1] + row, n_cur[2] + row, corner, step_x, step_y,
                       t_x, t_y);
      // The duals at the same positions, rotated (zero where no prediction),
      // or all zero (DualWarp::kReset).
      for (int g = 0; g < dual_groups; ++g) {
        const PlanarImage& src = dual_group(state, g);
        PlanarImage& dst = dual_group(scratch, g);
        const float* from[3] = {src.data(), src.data() + N, src.data() + 2 * N};
        float* to[3] = {dst.data(), dst.data() + N, dst.data() + 2 * N};
        if (dual_warp == DualWarp::kReset) {
          for (int c = 0; c < 3; ++c) {
            std::fill(to[c] + row, to[c] + row + count, 0.0f);
          }
          continue;
        }
        for (int j = 0; j < count; ++j) {
          float p[3] = {0.0f, 0.0f, 0.0f};
          if (corner[j] >= 0) {
            bilinearRotate(from, corner[j], step_x[j], step_y[j], t_x[j],
                           t_y[j], Rf, p);
          }
          for (int c = 0; c < 3; ++c) to[c][row + j] = p[c];
        }
      }
    }
  }
  std::swap(state.normals, scratch.normals);
  if (has_duals) {
    std::swap(state.dual_h, scratch.dual_h);
    std::swap(state.dual_v, scratch.dual_v);
    std::swap(state.dual_data, scratch.dual_data);
  } else {
    // No usable duals: none (as a state without them).
    state.dual_h = PlanarImage();
    state.dual_v = PlanarImage();
    state.dual_data.clear();
  }
}

namespace internal {

void warpStateByRotationReference(SolverState& state, const CameraIntrinsics& K,
                                  const std::array<double, 9>& R_cur_prev) {
  const auto& R = R_cur_prev;
  checkWarpArguments(state, R);
  const int W = state.normals.width(), H = state.normals.height();
  const int L = static_cast<int>(state.dual_data.size());
  SolverState warped;
  warped.normals.resize(W, H, 3);
  const bool has_duals = state.compatible(W, H, L);
  if (has_duals) {
    warped.dual_h.resize(W, H, 3);
    warped.dual_v.resize(W, H, 3);
    warped.dual_data.assign(L, PlanarImage(W, H, 3));
  }
  const PreviousPixel previous(K, R);
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      float n[3];
      double u = 0.0, v = 0.0;
      bool inside = previous.at(x, y, W, H, &u, &v);
      if (inside) {
        // An edge of the map between the source pixels: a blend would be a
        // normal of neither side; the current inputs decide there.
        inside = sampleRotated(state.normals, u, v, R, n) &&
                 blendable(state.normals, u, v);
        if (inside && has_duals) {
          float p[3];
          sampleRotated(state.dual_h, u, v, R, p);
          for (int c = 0; c < 3; ++c) warped.dual_h.at(c, y, x) = p[c];
          sampleRotated(state.dual_v, u, v, R, p);
          for (int c = 0; c < 3; ++c) warped.dual_v.at(c, y, x) = p[c];
          for (int l = 0; l < L; ++l) {
            sampleRotated(state.dual_data[l], u, v, R, p);
            for (int c = 0; c < 3; ++c) warped.dual_data[l].at(c, y, x) = p[c];
          }
        }
      }
      const float len =
          inside ? std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]) : 0.0f;
      if (!(len > 1e-6f)) {
        // Uncovered: no prediction (NaN); the solver's warm start fills it.
        for (float& value : n) value = std::numeric_limits<float>::quiet_NaN();
        inside = false;
      } else {
        for (float& value : n) value /= len;
      }
      for (int c = 0; c < 3; ++c) warped.normals.at(c, y, x) = n[c];
      if (!inside && has_duals) {
        for (int c = 0; c < 3; ++c) {
          warped.dual_h.at(c, y, x) = 0.0f;
          warped.dual_v.at(c, y, x) = 0.0f;
          for (int l = 0; l < L; ++l) warped.dual_data[l].at(c, y, x) = 0.0f;
        }
      }
    }
  }
  state = std::move(warped);
}

}  // namespace internal
}  // namespace normal_fusion
