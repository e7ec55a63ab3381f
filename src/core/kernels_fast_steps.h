// The fast backend's per-pixel steps that its kernels share (the whole
// image: kernels_fast.cpp; a local refinement: kernels_fast_active.cpp; the
// energies: kernels_fast_energy.cpp): branch-free, for vectorised loops.
#pragma once

#include <algorithm>
#include <cmath>

#include "normal_fusion/detail/solver_internal.h"

namespace normal_fusion {
namespace internal {
namespace fast {

constexpr float kTiny = 1e-30f;
/// Active pixels per thread below which a local refinement runs on one.
constexpr int kMinActivePerThread = 4096;

/// Scale that maps a vector of length sqrt(len2) into the ball of `radius`:
/// clamp_c(v) = v * min(1, c / |v|), and 0 when c = 0.
inline float clampScale(float len2, float radius) {
  const float len = std::sqrt(len2);
  return radius / std::max(std::max(len, radius), kTiny);
}

/// Huber dual step in one division: clamp_w(a / (1 + sigma eps / w)) =
/// a w / max(w + sigma eps, |a|) (0 where w = 0), the same value as the
/// shrink-then-clamp of the reference.
inline float huberDualScale(float len2, float w, float sigma_eps) {
  return w / std::max(std::max(w + sigma_eps, std::sqrt(len2)), kTiny);
}

/// One Huber dual step on (px, py, pz): a = p + sigma g, then
/// p <- a w / max(w + sigma eps, |a|) (huberDualScale()). The smoothness
/// duals take g = grad nbar and the edge weight, the data duals (with their
/// Huber threshold) g = nbar - f, w = c and sigma eps = sigma delta.
inline void huberDualStep(float& px, float& py, float& pz, float gx, float gy,
                          float gz, float sigma, float w, float sigma_eps) {
  const float ax = px + sigma * gx;
  const float ay = py + sigma * gy;
  const float az = pz + sigma * gz;
  const float sc = huberDualScale(ax * ax + ay * ay + az * az, w, sigma_eps);
  px = ax * sc;
  py = ay * sc;
  pz = az * sc;
}

/// The relaxed step (Condat 2013): x_old + rho (x_hat - x_old).
inline float relaxed(float x_old, float x_hat, float rho) {
  return x_old + rho * (x_hat - x_old);
}

/// huberDualStep() relaxed: p <- p + rho (p_hat - p), p_hat its plain step.
inline void huberDualStepRelaxed(float& px, float& py, float& pz, float gx,
                                 float gy, float gz, float sigma, float w,
                                 float sigma_eps, float rho) {
  float hx = px, hy = py, hz = pz;
  huberDualStep(hx, hy, hz, gx, gy, gz, sigma, w, sigma_eps);
  px = relaxed(px, hx, rho);
  py = relaxed(py, hy, rho);
  pz = relaxed(pz, hz, rho);
}

/// v <- Proj_C(v): onto the tangent plane n0 . n = 1 (n0 = a), then, when
/// kSoft, within the plane onto n . r <= 0 (the line n . r = 0 when
/// violated). Branch-free, for vectorised loops.
template <bool kSoft>
inline void projectFeasible(float& vx, float& vy, float& vz, float ax, float ay,
                            float az, float rx, float ry, float rz) {
  const float plane_off = ax * vx + ay * vy + az * vz - 1.0f;
  vx -= plane_off * ax;
  vy -= plane_off * ay;
  vz -= plane_off * az;
  if (kSoft) {
    const float rv = rx * vx + ry * vy + rz * vz;
    const float rn0 = rx * ax + ry * ay + rz * az;
    const float tx = rx - rn0 * ax, ty = ry - rn0 * ay, tz = rz - rn0 * az;
    const float t2 = tx * tx + ty * ty + tz * tz;
    // t2 ~ 0 only where n0 = -r/|r|; there r . v = -|r| < 0 and k = 0.
    const float k = std::max(rv, 0.0f) / std::max(t2, 1e-20f);
    vx -= k * tx;
    vy -= k * ty;
    vz -= k * tz;
  }
}

// Row kernels of the data terms' dual steps and of d -= q
// (kernels_fast_shared.cpp; NF_MULTIVERSION clones). The dual steps take the
// relaxation rho: q <- q + rho (q_hat - q), q_hat the step below (rho = 1:
// q_hat itself, bit for bit).

/// q <- clamp_c(q + sigma (nbar - f)) (unsquared) for one row.
void dataDualRowL2(int n, float sigma, const float* __restrict c,
                   const float* __restrict nx, const float* __restrict ny,
                   const float* __restrict nz, const float* __restrict fx,
                   const float* __restrict fy, const float* __restrict fz,
                   float* __restrict qx, float* __restrict qy,
                   float* __restrict qz, float rho);
/// q <- clamp_c((q + sigma (nbar - f)) / (1 + sigma delta / c)) (unsquared,
/// Huber threshold delta) for one row.
void dataDualRowHuber(int n, float sigma, const float* __restrict c,
                      const float* __restrict delta, const float* __restrict nx,
                      const float* __restrict ny, const float* __restrict nz,
                      const float* __restrict fx, const float* __restrict fy,
                      const float* __restrict fz, float* __restrict qx,
                      float* __restrict qy, float* __restrict qz, float rho);
/// q <- (q + sigma (nbar - f)) / (1 + sigma / c) (squared) for one row.
void dataDualRowSquared(int n, float sigma, const float* __restrict c,
                        const float* __restrict nx, const float* __restrict ny,
                        const float* __restrict nz, const float* __restrict fx,
                        const float* __restrict fy, const float* __restrict fz,
                        float* __restrict qx, float* __restrict qy,
                        float* __restrict qz, float rho);
/// d -= q for one row and one channel.
void subtractRow(int W, const float* __restrict q, float* __restrict d);

}  // namespace fast
}  // namespace internal
}  // namespace normal_fusion
