#include "normal_fusion/warp.h"

#include <cmath>
#include <limits>

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

}  // namespace

void warpStateByRotation(SolverState& state, const CameraIntrinsics& K,
                         const std::array<double, 9>& R_cur_prev) {
  const std::array<double, 9> K_inv = K.inverse();
  const auto& R = R_cur_prev;
  // R must be a rotation: R R^T = I, det R = 1.
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) {
      double d = 0.0;
      for (int k = 0; k < 3; ++k) d += R[3 * i + k] * R[3 * j + k];
      if (!std::isfinite(d) || std::abs(d - (i == j ? 1.0 : 0.0)) > 1e-4) {
        throw InputError("warpStateByRotation: R is not a rotation matrix");
      }
    }
  }
  const int W = state.normals.width(), H = state.normals.height();
  if (state.normals.channels() != 3 || W == 0 || H == 0) {
    throw InputError("warpStateByRotation: the state holds no normals");
  }
  const int L = static_cast<int>(state.dual_data.size());
  SolverState warped;
  warped.normals.resize(W, H, 3);
  const bool has_duals = state.compatible(W, H, L);
  if (has_duals) {
    warped.dual_h.resize(W, H, 3);
    warped.dual_v.resize(W, H, 3);
    warped.dual_data.assign(L, PlanarImage(W, H, 3));
  }
  // Previous pixel of a current pixel: u_prev ~ K R^T K^-1 u_cur.
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const double r_cur[3] = {K_inv[0] * x + K_inv[1] * y + K_inv[2],
                               K_inv[3] * x + K_inv[4] * y + K_inv[5],
                               K_inv[6] * x + K_inv[7] * y + K_inv[8]};
      double r_prev[3];
      for (int i = 0; i < 3; ++i) {
        r_prev[i] = R[i] * r_cur[0] + R[3 + i] * r_cur[1] + R[6 + i] * r_cur[2];
      }
      const auto& Km = K.K;
      const double w =
          Km[6] * r_prev[0] + Km[7] * r_prev[1] + Km[8] * r_prev[2];
      float n[3];
      bool inside = w > 1e-9;
      if (inside) {
        const double u =
            (Km[0] * r_prev[0] + Km[1] * r_prev[1] + Km[2] * r_prev[2]) / w;
        const double v =
            (Km[3] * r_prev[0] + Km[4] * r_prev[1] + Km[5] * r_prev[2]) / w;
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

}  // namespace normal_fusion
