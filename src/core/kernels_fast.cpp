// Fast backend: the same Chambolle-Pock iteration as kernels_reference.cpp,
// fused into two passes over the rows per iteration (all duals, then the
// primal), branch-free inner loops that the compiler vectorises, and OpenMP
// threads over rows inside one parallel region for all iterations.
#include <omp.h>

#include <algorithm>
#include <cmath>

#include "normal_fusion/detail/solver_internal.h"

namespace normal_fusion {
namespace internal {
namespace {

constexpr float kTiny = 1e-30f;

/// Scale that maps a vector of length sqrt(len2) into the ball of `radius`:
/// clamp_c(v) = v * min(1, c / |v|), and 0 when c = 0.
inline float clampScale(float len2, float radius) {
  const float len = std::sqrt(len2);
  return radius / std::max(std::max(len, radius), kTiny);
}

struct Planes3 {
  float* x;
  float* y;
  float* z;
};
struct ConstPlanes3 {
  const float* x;
  const float* y;
  const float* z;
};

inline Planes3 rowOf(PlanarImage& img, std::size_t offset) {
  return {img.plane(0) + offset, img.plane(1) + offset, img.plane(2) + offset};
}
inline ConstPlanes3 rowOf(const PlanarImage& img, std::size_t offset) {
  return {img.plane(0) + offset, img.plane(1) + offset, img.plane(2) + offset};
}

/// Dual pass over one row: p_h, p_v and every q_l.
void dualRow(const PreparedLevel& level, const InnerParams& prm,
             IterationState& s, int y) {
  const int W = level.width;
  const std::size_t off = static_cast<std::size_t>(y) * W;
  const bool has_below = y + 1 < level.height;
  const ConstPlanes3 nb = rowOf(static_cast<const PlanarImage&>(s.nbar), off);
  const ConstPlanes3 nb_below = rowOf(static_cast<const PlanarImage&>(s.nbar),
                                      has_below ? off + W : off);
  const Planes3 ph = rowOf(s.p_h, off);
  const Planes3 pv = rowOf(s.p_v, off);
  const float* w_h = level.edge_weight.plane(0) + off;
  const float* w_v = level.edge_weight.plane(1) + off;
  const float sigma = prm.sigma;
  const float sigma_eps = prm.sigma * prm.huber_eps;
  // grad_v is 0 on the last row; multiply by 0 rather than branch per pixel.
  const float below = has_below ? 1.0f : 0.0f;

  // p_h <- clamp_{w_h}((p_h + sigma grad_h nbar) / (1 + sigma eps / w_h)),
  // likewise p_v; grad_h is 0 on the last column.
  for (int x = 0; x < W; ++x) {
    const int xr = std::min(x + 1, W - 1);
    const float gx = nb.x[xr] - nb.x[x];
    const float gy = nb.y[xr] - nb.y[x];
    const float gz = nb.z[xr] - nb.z[x];
    const float wh = w_h[x];
    const float shrink_h = wh / (wh + sigma_eps + kTiny);
    const float hx = (ph.x[x] + sigma * gx) * shrink_h;
    const float hy = (ph.y[x] + sigma * gy) * shrink_h;
    const float hz = (ph.z[x] + sigma * gz) * shrink_h;
    const float sh = clampScale(hx * hx + hy * hy + hz * hz, wh);
    ph.x[x] = hx * sh;
    ph.y[x] = hy * sh;
    ph.z[x] = hz * sh;

    const float vx = below * (nb_below.x[x] - nb.x[x]);
    const float vy = below * (nb_below.y[x] - nb.y[x]);
    const float vz = below * (nb_below.z[x] - nb.z[x]);
    const float wv = w_v[x];
    const float shrink_v = wv / (wv + sigma_eps + kTiny);
    const float ux = (pv.x[x] + sigma * vx) * shrink_v;
    const float uy = (pv.y[x] + sigma * vy) * shrink_v;
    const float uz = (pv.z[x] + sigma * vz) * shrink_v;
    const float sv = clampScale(ux * ux + uy * uy + uz * uz, wv);
    pv.x[x] = ux * sv;
    pv.y[x] = uy * sv;
    pv.z[x] = uz * sv;
  }

  for (int l = 0; l < level.num_inputs; ++l) {
    const ConstPlanes3 f = rowOf(level.data[l], off);
    const float* c_w = level.data_weight[l].plane(0) + off;
    const Planes3 q = rowOf(s.q[l], off);
    if (prm.penalty == DataPenalty::kL2) {
      // q_l <- clamp_{c_l}(q_l + sigma (nbar - f_l)).
      for (int x = 0; x < W; ++x) {
        const float ax = q.x[x] + sigma * (nb.x[x] - f.x[x]);
        const float ay = q.y[x] + sigma * (nb.y[x] - f.y[x]);
        const float az = q.z[x] + sigma * (nb.z[x] - f.z[x]);
        const float sc = clampScale(ax * ax + ay * ay + az * az, c_w[x]);
        q.x[x] = ax * sc;
        q.y[x] = ay * sc;
        q.z[x] = az * sc;
      }
    } else {
      // q_l <- (q_l + sigma (nbar - f_l)) / (1 + sigma / c_l).
      for (int x = 0; x < W; ++x) {
        const float sc = c_w[x] / (c_w[x] + sigma);
        q.x[x] = (q.x[x] + sigma * (nb.x[x] - f.x[x])) * sc;
        q.y[x] = (q.y[x] + sigma * (nb.y[x] - f.y[x])) * sc;
        q.z[x] = (q.z[x] + sigma * (nb.z[x] - f.z[x])) * sc;
      }
    }
  }
}

/// Primal pass over one row: n <- Proj_C(n + tau (div p - sum q)),
/// nbar <- 2 n - n_old.
void primalRow(const PreparedLevel& level, const InnerParams& prm,
               IterationState& s, int y) {
  const int W = level.width;
  const std::size_t off = static_cast<std::size_t>(y) * W;
  const bool has_above = y > 0;
  const bool has_below = y + 1 < level.height;
  const ConstPlanes3 ph = rowOf(static_cast<const PlanarImage&>(s.p_h), off);
  const ConstPlanes3 pv = rowOf(static_cast<const PlanarImage&>(s.p_v), off);
  const ConstPlanes3 pv_up = rowOf(static_cast<const PlanarImage&>(s.p_v),
                                   has_above ? off - W : off);
  const ConstPlanes3 n0 = rowOf(static_cast<const PlanarImage&>(s.n0), off);
  const Planes3 n = rowOf(s.n, off);
  const Planes3 nb = rowOf(s.nbar, off);
  const float up = has_above ? 1.0f : 0.0f;
  const float here_v = has_below ? 1.0f : 0.0f;
  const float tau = prm.tau;
  const int L = level.num_inputs;
  const float* q_planes[8][3];
  const int L_cached = std::min(L, 8);
  for (int l = 0; l < L_cached; ++l) {
    for (int c = 0; c < 3; ++c) q_planes[l][c] = s.q[l].plane(c) + off;
  }
  // Ray r = K^-1 (x, y, 1): affine in x along the row.
  const auto& Ki = level.K_inv;
  const float r0x = static_cast<float>(Ki[1] * y + Ki[2]);
  const float r0y = static_cast<float>(Ki[4] * y + Ki[5]);
  const float r0z = static_cast<float>(Ki[7] * y + Ki[8]);
  const float drx = static_cast<float>(Ki[0]);
  const float dry = static_cast<float>(Ki[3]);
  const float drz = static_cast<float>(Ki[6]);
  const bool soft = prm.soft_visibility;

  for (int x = 0; x < W; ++x) {
    // div p = (p_h(x) - p_h(x-1)) + (p_v(y) - p_v(y-1)), Dirichlet ends.
    const float hr = x + 1 < W ? 1.0f : 0.0f;
    const int xl = std::max(x - 1, 0);
    const float hl = x > 0 ? 1.0f : 0.0f;
    float dx = hr * ph.x[x] - hl * ph.x[xl] + here_v * pv.x[x] - up * pv_up.x[x];
    float dy = hr * ph.y[x] - hl * ph.y[xl] + here_v * pv.y[x] - up * pv_up.y[x];
    float dz = hr * ph.z[x] - hl * ph.z[xl] + here_v * pv.z[x] - up * pv_up.z[x];
    // - sum_l q_l.
    for (int l = 0; l < L_cached; ++l) {
      dx -= q_planes[l][0][x];
      dy -= q_planes[l][1][x];
      dz -= q_planes[l][2][x];
    }
    for (int l = 8; l < L; ++l) {
      dx -= s.q[l].plane(0)[off + x];
      dy -= s.q[l].plane(1)[off + x];
      dz -= s.q[l].plane(2)[off + x];
    }
    const float ox = n.x[x], oy = n.y[x], oz = n.z[x];
    float vx = ox + tau * dx;
    float vy = oy + tau * dy;
    float vz = oz + tau * dz;
    // Onto the tangent plane n0 . n = 1.
    const float ax = n0.x[x], ay = n0.y[x], az = n0.z[x];
    const float plane_off = ax * vx + ay * vy + az * vz - 1.0f;
    vx -= plane_off * ax;
    vy -= plane_off * ay;
    vz -= plane_off * az;
    if (soft) {
      // Within the plane onto n . r <= 0 (the line n . r = 0 when violated).
      const float rx = r0x + drx * x, ry = r0y + dry * x, rz = r0z + drz * x;
      const float rv = rx * vx + ry * vy + rz * vz;
      const float rn0 = rx * ax + ry * ay + rz * az;
      const float tx = rx - rn0 * ax, ty = ry - rn0 * ay, tz = rz - rn0 * az;
      const float t2 = tx * tx + ty * ty + tz * tz;
      const float k = t2 > 1e-20f ? std::max(rv, 0.0f) / t2 : 0.0f;
      vx -= k * tx;
      vy -= k * ty;
      vz -= k * tz;
    }
    n.x[x] = vx;
    n.y[x] = vy;
    n.z[x] = vz;
    nb.x[x] = 2.0f * vx - ox;
    nb.y[x] = 2.0f * vy - oy;
    nb.z[x] = 2.0f * vz - oz;
  }
}

}  // namespace

void runInnerFast(const PreparedLevel& level, const InnerParams& params,
                  IterationState& state, int iterations) {
  const int H = level.height;
  const int threads = std::max(1, std::min(params.num_threads, H));
#pragma omp parallel num_threads(threads)
  {
    for (int it = 0; it < iterations; ++it) {
#pragma omp for schedule(static)
      for (int y = 0; y < H; ++y) dualRow(level, params, state, y);
#pragma omp for schedule(static)
      for (int y = 0; y < H; ++y) primalRow(level, params, state, y);
    }
  }
}

}  // namespace internal
}  // namespace normal_fusion
