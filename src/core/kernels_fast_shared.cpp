// The data terms' dual steps and the subtraction of the data duals, row by
// row: the steps that the whole-image and the local-refinement kernels of
// the fast backend share (NF_MULTIVERSION clones).
#include "kernels_fast_steps.h"
#include "normal_fusion/detail/multiversion.h"

namespace normal_fusion {
namespace internal {
namespace fast {

/// q <- clamp_c(q + sigma (nbar - f)) (unsquared) for one row.
NF_MULTIVERSION
void dataDualRowL2(int n, float sigma, const float* __restrict c,
                   const float* __restrict nx, const float* __restrict ny,
                   const float* __restrict nz, const float* __restrict fx,
                   const float* __restrict fy, const float* __restrict fz,
                   float* __restrict qx, float* __restrict qy,
                   float* __restrict qz, float rho) {
  if (rho == 1.0f) {
    for (int x = 0; x < n; ++x) {
      const float ax = qx[x] + sigma * (nx[x] - fx[x]);
      const float ay = qy[x] + sigma * (ny[x] - fy[x]);
      const float az = qz[x] + sigma * (nz[x] - fz[x]);
      const float sc = clampScale(ax * ax + ay * ay + az * az, c[x]);
      qx[x] = ax * sc;
      qy[x] = ay * sc;
      qz[x] = az * sc;
    }
    return;
  }
  for (int x = 0; x < n; ++x) {
    // q <- q + rho (clamp_c(q + sigma (nbar - f)) - q).
    const float ax = qx[x] + sigma * (nx[x] - fx[x]);
    const float ay = qy[x] + sigma * (ny[x] - fy[x]);
    const float az = qz[x] + sigma * (nz[x] - fz[x]);
    const float sc = clampScale(ax * ax + ay * ay + az * az, c[x]);
    qx[x] = relaxed(qx[x], ax * sc, rho);
    qy[x] = relaxed(qy[x], ay * sc, rho);
    qz[x] = relaxed(qz[x], az * sc, rho);
  }
}

/// q <- clamp_c((q + sigma (nbar - f)) / (1 + sigma delta / c)) (unsquared,
/// Huber threshold delta) for one row.
NF_MULTIVERSION
void dataDualRowHuber(int n, float sigma, const float* __restrict c,
                      const float* __restrict delta, const float* __restrict nx,
                      const float* __restrict ny, const float* __restrict nz,
                      const float* __restrict fx, const float* __restrict fy,
                      const float* __restrict fz, float* __restrict qx,
                      float* __restrict qy, float* __restrict qz, float rho) {
  if (rho == 1.0f) {
    for (int x = 0; x < n; ++x) {
      // q <- prox(q + sigma (nbar - f)): the shrink by c / (c + sigma delta)
      // and the clamp to c in one division.
      huberDualStep(qx[x], qy[x], qz[x], nx[x] - fx[x], ny[x] - fy[x],
                    nz[x] - fz[x], sigma, c[x], sigma * delta[x]);
    }
    return;
  }
  for (int x = 0; x < n; ++x) {
    // q <- q + rho (prox(q + sigma (nbar - f)) - q).
    huberDualStepRelaxed(qx[x], qy[x], qz[x], nx[x] - fx[x], ny[x] - fy[x],
                         nz[x] - fz[x], sigma, c[x], sigma * delta[x], rho);
  }
}

/// q <- (q + sigma (nbar - f)) / (1 + sigma / c) (squared) for one row.
NF_MULTIVERSION
void dataDualRowSquared(int n, float sigma, const float* __restrict c,
                        const float* __restrict nx, const float* __restrict ny,
                        const float* __restrict nz, const float* __restrict fx,
                        const float* __restrict fy, const float* __restrict fz,
                        float* __restrict qx, float* __restrict qy,
                        float* __restrict qz, float rho) {
  if (rho == 1.0f) {
    for (int x = 0; x < n; ++x) {
      const float sc = c[x] / (c[x] + sigma);
      qx[x] = (qx[x] + sigma * (nx[x] - fx[x])) * sc;
      qy[x] = (qy[x] + sigma * (ny[x] - fy[x])) * sc;
      qz[x] = (qz[x] + sigma * (nz[x] - fz[x])) * sc;
    }
    return;
  }
  for (int x = 0; x < n; ++x) {
    // q <- q + rho ((q + sigma (nbar - f)) / (1 + sigma / c) - q).
    const float sc = c[x] / (c[x] + sigma);
    qx[x] = relaxed(qx[x], (qx[x] + sigma * (nx[x] - fx[x])) * sc, rho);
    qy[x] = relaxed(qy[x], (qy[x] + sigma * (ny[x] - fy[x])) * sc, rho);
    qz[x] = relaxed(qz[x], (qz[x] + sigma * (nz[x] - fz[x])) * sc, rho);
  }
}

/// d -= q for one row and one channel.
NF_MULTIVERSION
void subtractRow(int W, const float* __restrict q, float* __restrict d) {
  for (int x = 0; x < W; ++x) d[x] -= q[x];
}

}  // namespace fast
}  // namespace internal
}  // namespace normal_fusion
