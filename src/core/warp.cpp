#include "normal_fusion/warp.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <vector>

#include "normal_fusion/detail/multiversion.h"
#include "normal_fusion/detail/previous_pixel.h"
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
  internal::checkRotation(R, "warpStateByRotation");
  if (state.normals.channels() != 3 || state.normals.width() == 0 ||
      state.normals.height() == 0) {
    throw InputError("warpStateByRotation: the state holds no normals");
  }
}

/// Bilinear blend of one component from its four corners (weights tx, ty).
inline float blendCorners(float p00, float p01, float p10, float p11, float tx,
                          float ty) {
  return (1 - ty) * ((1 - tx) * p00 + tx * p01) +
         ty * ((1 - tx) * p10 + tx * p11);
}

/// out = R s (R row-major, float).
inline void rotate(const float* R, const float s[3], float out[3]) {
  for (int r = 0; r < 3; ++r) {
    out[r] = R[3 * r] * s[0] + R[3 * r + 1] * s[1] + R[3 * r + 2] * s[2];
  }
}

/// Pixels per chunk of warpNormalsChunk().
constexpr int kChunk = 64;

/// Where a chunk of at most kChunk pixels of one row comes from, and their
/// warped normals: internal::PreviousPixel::at() and blendable() per pixel,
/// then the corners' bilinear blend, rotated, in three passes without branches
/// that GCC vectorises (positions; the blend's four corners gathered; blend
/// test, blend, rotation and normalization). The corners that carry weight in
/// blendable() are among the four gathered ones, so they are selected from
/// them rather than loaded again. Writes n_cur (NaN where no prediction)
/// and, per pixel, the source's first corner (-1: none), its steps to the
/// right and down, and the blend weights.
// Over 80 lines: its vectorised passes share the chunk's stack arrays.
NF_MULTIVERSION
void warpNormalsChunk(const double* A, int W, int H, int y, int x_begin,
                      int count, const float* __restrict n0,
                      const float* __restrict n1, const float* __restrict n2,
                      const float* R, float cos_blend, float* __restrict out0,
                      float* __restrict out1, float* __restrict out2,
                      int* __restrict corner, int* __restrict step_x,
                      int* __restrict step_y, float* __restrict t_x,
                      float* __restrict t_y) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  double in_flag[kChunk];  // 1: inside the previous image
  // internal::PreviousPixel::at(), in double; the positions outside replaced by
  // (0, 0) (safe indices; their prediction is dropped below).
  double u_safe[kChunk], v_safe[kChunk];
  for (int j = 0; j < count; ++j) {
    const double x = x_begin + j;
    const double w = A[6] * x + A[7] * y + A[8];
    const double inv_w = 1.0 / w;
    const double u = internal::PreviousPixel::clampNear(
        (A[0] * x + A[1] * y + A[2]) * inv_w, W - 1.0);
    const double v = internal::PreviousPixel::clampNear(
        (A[3] * x + A[4] * y + A[5]) * inv_w, H - 1.0);
    const bool in = (w > 1e-9) && (u >= 0.0) && (v >= 0.0) && (u <= W - 1.0) &&
                    (v <= H - 1.0);
    u_safe[j] = in ? u : 0.0;
    v_safe[j] = in ? v : 0.0;
    in_flag[j] = in ? 1.0 : 0.0;
  }
  // The corners of the blend and its weights.
  for (int j = 0; j < count; ++j) {
    const int x0 = static_cast<int>(u_safe[j]),
              y0 = static_cast<int>(v_safe[j]);
    corner[j] = y0 * W + x0;
    step_x[j] = x0 + 1 < W ? 1 : 0;
    step_y[j] = y0 + 1 < H ? W : 0;
    t_x[j] = static_cast<float>(u_safe[j] - x0);
    t_y[j] = static_cast<float>(v_safe[j] - y0);
  }
  // The normals at the four corners of the blend (p00, p01, p10, p11),
  // gathered.
  float p00[3][kChunk], p01[3][kChunk], p10[3][kChunk], p11[3][kChunk];
  const float* const src[3] = {n0, n1, n2};
  for (int ch = 0; ch < 3; ++ch) {
    const float* __restrict p = src[ch];
    for (int j = 0; j < count; ++j) {
      const int i00 = corner[j];
      p00[ch][j] = p[i00];
      p01[ch][j] = p[i00 + step_x[j]];
      p10[ch][j] = p[i00 + step_y[j]];
      p11[ch][j] = p[i00 + step_y[j] + step_x[j]];
    }
  }
  for (int j = 0; j < count; ++j) {
    // blendable()'s corners (weights below 1e-3 do not count): the low and
    // high column and row that carry weight, picked among the four.
    const bool lo_x = t_x[j] > 0.999f, hi_x = t_x[j] > 1e-3f;
    const bool lo_y = t_y[j] > 0.999f, hi_y = t_y[j] > 1e-3f;
    float a[3], b[3], c[3], e[3];
    for (int ch = 0; ch < 3; ++ch) {
      const float q00 = p00[ch][j], q01 = p01[ch][j];
      const float q10 = p10[ch][j], q11 = p11[ch][j];
      a[ch] = lo_y ? (lo_x ? q11 : q10) : (lo_x ? q01 : q00);
      b[ch] = lo_y ? (hi_x ? q11 : q10) : (hi_x ? q01 : q00);
      c[ch] = hi_y ? (lo_x ? q11 : q10) : (lo_x ? q01 : q00);
      e[ch] = hi_y ? (hi_x ? q11 : q10) : (hi_x ? q01 : q00);
    }
    // blendable(): all pairs of weight-carrying corners within
    // kMaxBlendDegrees (NaN fails).
    auto dot = [](const float(&p)[3], const float(&q)[3]) {
      return p[0] * q[0] + p[1] * q[1] + p[2] * q[2];
    };
    const bool ab = dot(a, b) >= cos_blend, ac = dot(a, c) >= cos_blend;
    const bool ae = dot(a, e) >= cos_blend, bc = dot(b, c) >= cos_blend;
    const bool be = dot(b, e) >= cos_blend, ce = dot(c, e) >= cos_blend;
    const bool blend = ab & ac & ae & bc & be & ce;
    // The bilinear blend, rotated into the current frame.
    float s[3];
    for (int ch = 0; ch < 3; ++ch) {
      s[ch] = blendCorners(p00[ch][j], p01[ch][j], p10[ch][j], p11[ch][j],
                           t_x[j], t_y[j]);
    }
    float n[3];
    rotate(R, s, n);
    const float len = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    const bool ok = (in_flag[j] != 0.0) & blend & (len > 1e-6f);
    const float safe_len = ok ? len : 1.0f;
    out0[j] = ok ? n[0] / safe_len : nan;
    out1[j] = ok ? n[1] / safe_len : nan;
    out2[j] = ok ? n[2] / safe_len : nan;
    corner[j] = ok ? corner[j] : -1;
  }
}

/// One dual group (3 planes) over a chunk at the positions that
/// warpNormalsChunk() found: the corners' bilinear blend, rotated, and zero
/// where there is no prediction (corner -1, read at a safe index), without
/// branches, so that GCC vectorises it.
NF_MULTIVERSION
void warpDualChunk(int count, const float* __restrict from0,
                   const float* __restrict from1, const float* __restrict from2,
                   const int* __restrict corner, const int* __restrict step_x,
                   const int* __restrict step_y, const float* __restrict t_x,
                   const float* __restrict t_y, const float* R,
                   float* __restrict to0, float* __restrict to1,
                   float* __restrict to2) {
  const float* const src[3] = {from0, from1, from2};
  for (int j = 0; j < count; ++j) {
    const bool ok = corner[j] >= 0;
    const int i00 = ok ? corner[j] : 0;
    const int dx = step_x[j], dy = step_y[j];
    float s[3];
    for (int c = 0; c < 3; ++c) {
      const float* p = src[c];
      s[c] = blendCorners(p[i00], p[i00 + dx], p[i00 + dy], p[i00 + dy + dx],
                          t_x[j], t_y[j]);
    }
    float n[3];
    rotate(R, s, n);
    const float mask = ok ? 1.0f : 0.0f;
    to0[j] = mask * n[0];
    to1[j] = mask * n[1];
    to2[j] = mask * n[2];
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
  const internal::PreviousPixel previous(K, R);
  const int W = state.normals.width(), H = state.normals.height();
  const std::size_t N = state.normals.pixelCount();
  const int L = static_cast<int>(state.dual_data.size());
  const bool has_duals = state.compatible(W, H, L);
  const int threads = resolveThreadCount(num_threads);
  // The warped state is written into the scratch buffers (sized once), then
  // swapped in.
  if (has_duals) {
    scratch.resize(W, H, L);
  } else {
    scratch.normals.resize(W, H, 3);
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
  const int rotated_groups = dual_warp == DualWarp::kReset ? 0 : dual_groups;
  // Rows in chunks of kChunk pixels: the chunk's source positions and the
  // warped normals first, then each dual group over the chunk.
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
      // The duals at the same positions, rotated (zero where no prediction);
      // DualWarp::kReset zeroes them below.
      for (int g = 0; g < rotated_groups; ++g) {
        const PlanarImage& src = dual_group(state, g);
        PlanarImage& dst = dual_group(scratch, g);
        float* to = dst.data() + row;
        warpDualChunk(count, src.data(), src.data() + N, src.data() + 2 * N,
                      corner, step_x, step_y, t_x, t_y, Rf, to, to + N,
                      to + 2 * N);
      }
    }
  }
  if (dual_warp == DualWarp::kReset && dual_groups > 0) {
    // All duals zero: whole planes at once (large blocks, which the C
    // library writes faster than the chunks' short runs), in as many parts
    // as threads.
    const int parts = 3 * dual_groups * threads;
#pragma omp parallel for num_threads(threads) schedule(static)
    for (int part = 0; part < parts; ++part) {
      const int plane = part / threads, share = part % threads;
      float* to = dual_group(scratch, plane / 3).data() + (plane % 3) * N;
      const std::size_t begin = N * share / threads;
      const std::size_t end = N * (share + 1) / threads;
      std::memset(to + begin, 0, (end - begin) * sizeof(float));
    }
  }
  internal::swapInWarped(state, scratch, has_duals);
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
  const internal::PreviousPixel previous(K, R);
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

void swapInWarped(SolverState& state, SolverState& warped, bool has_duals) {
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

}  // namespace internal

}  // namespace normal_fusion
