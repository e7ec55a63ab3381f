// Fast backend: the same Chambolle-Pock iteration as kernels_reference.cpp,
// fused into two passes over the rows per iteration (all duals, then the
// primal), branch-free inner loops that the compiler vectorises, and OpenMP
// threads over rows inside one parallel region for all iterations.
#include <omp.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <thread>
#include <vector>

#include "normal_fusion/detail/multiversion.h"
#include "normal_fusion/detail/solver_internal.h"

namespace normal_fusion {
namespace internal {
namespace {

constexpr float kTiny = 1e-30f;
/// Active pixels per thread below which a local refinement runs on one.
constexpr int kMinActivePerThread = 4096;

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

// Row kernels: NF_MULTIVERSION (AVX-512, AVX2 and baseline x86-64 clones).

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

/// p <- clamp_w((p + sigma g) / (1 + sigma eps / w)) for one row of one
/// direction, with g = next - here given as two row pointers.
NF_MULTIVERSION
void huberDualRow(int n, float sigma, float sigma_eps,
                  const float* __restrict w, const float* __restrict here_x,
                  const float* __restrict here_y,
                  const float* __restrict here_z,
                  const float* __restrict next_x,
                  const float* __restrict next_y,
                  const float* __restrict next_z, float* __restrict px,
                  float* __restrict py, float* __restrict pz) {
  for (int x = 0; x < n; ++x) {
    // p <- prox(p + sigma grad nbar), grad nbar = next - here.
    huberDualStep(px[x], py[x], pz[x], next_x[x] - here_x[x],
                  next_y[x] - here_y[x], next_z[x] - here_z[x], sigma, w[x],
                  sigma_eps);
  }
}

/// q <- clamp_c(q + sigma (nbar - f)) (unsquared) for one row.
NF_MULTIVERSION
void dataDualRowL2(int n, float sigma, const float* __restrict c,
                   const float* __restrict nx, const float* __restrict ny,
                   const float* __restrict nz, const float* __restrict fx,
                   const float* __restrict fy, const float* __restrict fz,
                   float* __restrict qx, float* __restrict qy,
                   float* __restrict qz) {
  for (int x = 0; x < n; ++x) {
    const float ax = qx[x] + sigma * (nx[x] - fx[x]);
    const float ay = qy[x] + sigma * (ny[x] - fy[x]);
    const float az = qz[x] + sigma * (nz[x] - fz[x]);
    const float sc = clampScale(ax * ax + ay * ay + az * az, c[x]);
    qx[x] = ax * sc;
    qy[x] = ay * sc;
    qz[x] = az * sc;
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
                      float* __restrict qy, float* __restrict qz) {
  for (int x = 0; x < n; ++x) {
    // q <- prox(q + sigma (nbar - f)): the shrink by c / (c + sigma delta)
    // and the clamp to c in one division.
    huberDualStep(qx[x], qy[x], qz[x], nx[x] - fx[x], ny[x] - fy[x],
                  nz[x] - fz[x], sigma, c[x], sigma * delta[x]);
  }
}

/// q <- (q + sigma (nbar - f)) / (1 + sigma / c) (squared) for one row.
NF_MULTIVERSION
void dataDualRowSquared(int n, float sigma, const float* __restrict c,
                        const float* __restrict nx, const float* __restrict ny,
                        const float* __restrict nz, const float* __restrict fx,
                        const float* __restrict fy, const float* __restrict fz,
                        float* __restrict qx, float* __restrict qy,
                        float* __restrict qz) {
  for (int x = 0; x < n; ++x) {
    const float sc = c[x] / (c[x] + sigma);
    qx[x] = (qx[x] + sigma * (nx[x] - fx[x])) * sc;
    qy[x] = (qy[x] + sigma * (ny[x] - fy[x])) * sc;
    qz[x] = (qz[x] + sigma * (nz[x] - fz[x])) * sc;
  }
}

/// Dual pass over one row: p_h, p_v and every q_l.
void dualRow(const PreparedLevel& level, const InnerParams& prm,
             IterationState& s, int y) {
  const int W = level.width;
  const std::size_t off = static_cast<std::size_t>(y) * W;
  const ConstPlanes3 nb = rowOf(static_cast<const PlanarImage&>(s.nbar), off);
  const Planes3 ph = rowOf(s.p_h, off);
  const Planes3 pv = rowOf(s.p_v, off);
  const float sigma = prm.sigma;
  const float sigma_eps = prm.sigma * prm.huber_eps;
  const float sigma_data = prm.sigma_data;
  // p_h: grad_h nbar = nbar(x+1) - nbar(x), 0 on the last column (so the
  // last column sees next = here).
  huberDualRow(W - 1, sigma, sigma_eps, level.edge_weight.plane(0) + off, nb.x,
               nb.y, nb.z, nb.x + 1, nb.y + 1, nb.z + 1, ph.x, ph.y, ph.z);
  huberDualRow(1, sigma, sigma_eps, level.edge_weight.plane(0) + off + W - 1,
               nb.x + W - 1, nb.y + W - 1, nb.z + W - 1, nb.x + W - 1,
               nb.y + W - 1, nb.z + W - 1, ph.x + W - 1, ph.y + W - 1,
               ph.z + W - 1);
  // p_v: grad_v nbar = nbar(y+1) - nbar(y), 0 on the last row.
  const ConstPlanes3 nb_next = rowOf(static_cast<const PlanarImage&>(s.nbar),
                                     y + 1 < level.height ? off + W : off);
  huberDualRow(W, sigma, sigma_eps, level.edge_weight.plane(1) + off, nb.x,
               nb.y, nb.z, nb_next.x, nb_next.y, nb_next.z, pv.x, pv.y, pv.z);
  // q_l, one data term at a time.
  for (int l = 0; l < level.num_inputs; ++l) {
    const ConstPlanes3 f = rowOf(level.data[l], off);
    const float* c_w = level.data_weight[l].plane(0) + off;
    const Planes3 q = rowOf(s.q[l], off);
    if (prm.penalty == DataPenalty::kL2 && level.data_huber) {
      dataDualRowHuber(W, sigma_data, c_w, level.data_eps[l].plane(0) + off,
                       nb.x, nb.y, nb.z, f.x, f.y, f.z, q.x, q.y, q.z);
    } else if (prm.penalty == DataPenalty::kL2) {
      dataDualRowL2(W, sigma_data, c_w, nb.x, nb.y, nb.z, f.x, f.y, f.z, q.x,
                    q.y, q.z);
    } else {
      dataDualRowSquared(W, sigma_data, c_w, nb.x, nb.y, nb.z, f.x, f.y, f.z,
                         q.x, q.y, q.z);
    }
  }
}

/// d = div p for one row and one channel: (p_h(x) - p_h(x-1)) +
/// (p_v(y) - p_v(y-1)), Dirichlet ends (p_h(-1) = 0, p_h(W-1) read as 0,
/// p_v(-1) = 0, p_v(H-1) read as 0: `here_v_on` / `up` are 0 or 1).
NF_MULTIVERSION
void divergenceRow(int W, const float* __restrict ph,
                   const float* __restrict pv, const float* __restrict pv_up,
                   float here_v_on, float up_on, float* __restrict d) {
  d[0] = ph[0] + here_v_on * pv[0] - up_on * pv_up[0];
  for (int x = 1; x < W - 1; ++x) {
    d[x] = (ph[x] - ph[x - 1]) + here_v_on * pv[x] - up_on * pv_up[x];
  }
  if (W > 1)
    d[W - 1] = -ph[W - 2] + here_v_on * pv[W - 1] - up_on * pv_up[W - 1];
}

/// d -= q for one row and one channel.
NF_MULTIVERSION
void subtractRow(int W, const float* __restrict q, float* __restrict d) {
  for (int x = 0; x < W; ++x) d[x] -= q[x];
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

/// n <- Proj_C(n + tau d), nbar <- 2 n - n_old for one row; C the tangent
/// plane at n0, intersected with n . r <= 0 when kSoft.
template <bool kSoft>
NF_MULTIVERSION void primalUpdateRow(
    int W, float tau, const float* __restrict dx, const float* __restrict dy,
    const float* __restrict dz, const float* __restrict ax_,
    const float* __restrict ay_, const float* __restrict az_, float r0x,
    float r0y, float r0z, float drx, float dry, float drz, float* __restrict nx,
    float* __restrict ny, float* __restrict nz, float* __restrict bx,
    float* __restrict by, float* __restrict bz) {
  for (int x = 0; x < W; ++x) {
    const float ox = nx[x], oy = ny[x], oz = nz[x];
    float vx = ox + tau * dx[x];
    float vy = oy + tau * dy[x];
    float vz = oz + tau * dz[x];
    // Ray r = K^-1 (x, y, 1), affine along the row.
    const float xf = static_cast<float>(x);
    projectFeasible<kSoft>(vx, vy, vz, ax_[x], ay_[x], az_[x], r0x + drx * xf,
                           r0y + dry * xf, r0z + drz * xf);
    nx[x] = vx;
    ny[x] = vy;
    nz[x] = vz;
    bx[x] = 2.0f * vx - ox;
    by[x] = 2.0f * vy - oy;
    bz[x] = 2.0f * vz - oz;
  }
}

/// Primal pass over one row: n <- Proj_C(n + tau (div p - sum q)),
/// nbar <- 2 n - n_old. `scratch` holds 3 rows of W floats.
void primalRow(const PreparedLevel& level, const InnerParams& prm,
               IterationState& s, int y, float* scratch) {
  const int W = level.width;
  const std::size_t off = static_cast<std::size_t>(y) * W;
  const float up_on = y > 0 ? 1.0f : 0.0f;
  const float here_v_on = y + 1 < level.height ? 1.0f : 0.0f;
  const std::size_t off_up = y > 0 ? off - W : off;
  float* d[3] = {scratch, scratch + W, scratch + 2 * W};
  for (int c = 0; c < 3; ++c) {
    // d = div p - sum_l q_l.
    divergenceRow(W, s.p_h.plane(c) + off, s.p_v.plane(c) + off,
                  s.p_v.plane(c) + off_up, here_v_on, up_on, d[c]);
    for (int l = 0; l < level.num_inputs; ++l) {
      subtractRow(W, s.q[l].plane(c) + off, d[c]);
    }
  }
  // Ray r = K^-1 (x, y, 1): affine in x along the row.
  const auto& Ki = level.K_inv;
  const float r0x = static_cast<float>(Ki[1] * y + Ki[2]);
  const float r0y = static_cast<float>(Ki[4] * y + Ki[5]);
  const float r0z = static_cast<float>(Ki[7] * y + Ki[8]);
  const ConstPlanes3 n0 = rowOf(static_cast<const PlanarImage&>(s.n0), off);
  const Planes3 n = rowOf(s.n, off);
  const Planes3 nb = rowOf(s.nbar, off);
  auto update =
      prm.soft_visibility ? primalUpdateRow<true> : primalUpdateRow<false>;
  update(W, prm.tau, d[0], d[1], d[2], n0.x, n0.y, n0.z, r0x, r0y, r0z,
         static_cast<float>(Ki[0]), static_cast<float>(Ki[3]),
         static_cast<float>(Ki[6]), n.x, n.y, n.z, nb.x, nb.y, nb.z);
}

}  // namespace

bool runInnerFast(const PreparedLevel& level, const InnerParams& params,
                  IterationState& state, int iterations) {
  // Temporal blocking with a pipeline of threads. One iteration is a sweep
  // over the rows doing dual(y) then primal(y) in place: dual(y) reads nbar
  // rows y and y+1 (not yet touched by primal in this sweep) and primal(y)
  // reads p_v(y-1) (already updated). Iteration k+1 may therefore process row
  // y as soon as iteration k has finished row y+1. Each thread runs a
  // wavefront of `depth` consecutive iterations over a band of depth + 1 rows
  // that stays in its cache, and thread t+1 runs the next `depth` iterations
  // one row behind thread t. Memory traffic per iteration drops by about the
  // depth, and the result is the same as sweep after sweep.
  //
  // A stop request (params.cancel) is read before each row step and in
  // every wait: the thread that sees it first latches `stopped`, and every
  // thread leaves its sweeps where they are (no thread then waits for one
  // that left).
  if (iterations <= 0) return true;
  const int W = level.width;
  const int H = level.height;
  const int threads = std::max(1, std::min(params.num_threads, iterations));
  const int depth = std::max(1, params.block_depth);
  state.row_scratch.resize(static_cast<std::size_t>(threads) * 3 * W);
  // progress[t] counts rows finished by thread t's last iteration, summed over
  // rounds (round r adds H), so a waiting thread knows which round it sees.
  std::vector<std::atomic<long>>& progress = state.progress;
  if (static_cast<int>(progress.size()) < threads) {
    std::vector<std::atomic<long>> fresh(threads);
    progress.swap(fresh);
  }
  for (int t = 0; t < threads; ++t)
    progress[t].store(0, std::memory_order_relaxed);
  const int per_round = threads * depth;
  const int rounds = (iterations + per_round - 1) / per_round;
  std::atomic<bool> stopped{false};
  auto stop = [&stopped, cancel = params.cancel] {
    if (stopped.load(std::memory_order_relaxed)) return true;
    if (!stopRequested(cancel)) return false;
    // Latched: a request withdrawn now does not leave a thread waiting for
    // one that has left.
    stopped.store(true, std::memory_order_relaxed);
    return true;
  };

#pragma omp parallel num_threads(threads)
  {
    const int t = omp_get_thread_num();
    float* scratch =
        state.row_scratch.data() + static_cast<std::size_t>(t) * 3 * W;
    int remaining = iterations;
    // False once the thread stopped on the request: it skips the rest.
    bool running = true;
    for (int round = 0; round < rounds && running; ++round) {
      // Iterations of this round, split as evenly as possible over threads.
      const int in_round = std::min(per_round, remaining);
      remaining -= in_round;
      const int mine = in_round / threads + (t < in_round % threads ? 1 : 0);
      // Whose rows this thread's first iteration depends on: the previous
      // thread in this round, or the last thread of the previous round.
      const int pred = t > 0 ? t - 1 : threads - 1;
      const long pred_base = t > 0 ? static_cast<long>(round) * H
                                   : static_cast<long>(round - 1) * H;
      const bool must_wait = !(t == 0 && round == 0);
      if (mine == 0) {
        // Nothing to do: pass the predecessor's progress on.
        if (must_wait) {
          while (running && progress[pred].load(std::memory_order_acquire) <
                                pred_base + H) {
            running = !stop();
            std::this_thread::yield();
          }
        }
        if (!running) break;
        progress[t].store(static_cast<long>(round + 1) * H,
                          std::memory_order_release);
        continue;
      }
      for (int step = 0; step < H + mine - 1 && running; ++step) {
        running = !stop();
        // The first iteration processes row `step`: wait until the
        // predecessor's last iteration has finished row step + 1.
        if (running && must_wait && step < H) {
          const long needed = pred_base + std::min(step + 2, H);
          int spins = 0;
          while (running &&
                 progress[pred].load(std::memory_order_acquire) < needed) {
            if (++spins > 64) {
              running = !stop();
              std::this_thread::yield();
            }
          }
        }
        if (!running) break;
        for (int i = 0; i < mine; ++i) {
          const int y = step - i;
          if (y < 0 || y >= H) continue;
          dualRow(level, params, state, y);
          primalRow(level, params, state, y, scratch);
        }
        const int finished = step - (mine - 1);
        if (finished >= 0) {
          progress[t].store(static_cast<long>(round) * H + finished + 1,
                            std::memory_order_release);
        }
      }
    }
  }
  return !stopped.load(std::memory_order_relaxed);
}

namespace {

/// p <- clamp_w((p + sigma (nbar_b - nbar_a)) / (1 + sigma eps / w)) on each
/// link (a, b) of a local refinement: huberDualRow() with indexed nodes.
NF_MULTIVERSION
void linkDualsIndexed(int num_links, float sigma, float sigma_eps,
                      const int* __restrict a, const int* __restrict b,
                      const float* __restrict w, const float* __restrict nx,
                      const float* __restrict ny, const float* __restrict nz,
                      float* __restrict px, float* __restrict py,
                      float* __restrict pz) {
  for (int m = 0; m < num_links; ++m) {
    huberDualStep(px[m], py[m], pz[m], nx[b[m]] - nx[a[m]], ny[b[m]] - ny[a[m]],
                  nz[b[m]] - nz[a[m]], sigma, w[m], sigma_eps);
  }
}

/// linkDualsIndexed() for links whose first nodes are consecutive (their
/// components given from the first link's node on: ax[m] = nx[a[m]]).
NF_MULTIVERSION
void linkDualsFirstContiguous(
    int num_links, float sigma, float sigma_eps, const int* __restrict b,
    const float* __restrict w, const float* __restrict ax_,
    const float* __restrict ay_, const float* __restrict az_,
    const float* __restrict nx, const float* __restrict ny,
    const float* __restrict nz, float* __restrict px, float* __restrict py,
    float* __restrict pz) {
  for (int m = 0; m < num_links; ++m) {
    huberDualStep(px[m], py[m], pz[m], nx[b[m]] - ax_[m], ny[b[m]] - ay_[m],
                  nz[b[m]] - az_[m], sigma, w[m], sigma_eps);
  }
}

/// d = div p at each active pixel: p_right - p_left + p_below - p_above, the
/// right and lower links given contiguously (link k and link P + k of
/// active pixel k), the left and upper ones by index (the dummy link, p = 0,
/// where a link is missing).
NF_MULTIVERSION
void divergenceRightBelowContiguous(int count, const float* __restrict right,
                                    const float* __restrict below,
                                    const int* __restrict left,
                                    const int* __restrict above,
                                    const float* __restrict p,
                                    float* __restrict d) {
  for (int k = 0; k < count; ++k) {
    d[k] = (right[k] - p[left[k]]) + (below[k] - p[above[k]]);
  }
}

/// n <- Proj_C(n + tau d), nbar <- 2 n - n_old at each active pixel (rays
/// given per pixel).
template <bool kSoft>
NF_MULTIVERSION void primalUpdateIndexed(
    int count, float tau, const float* __restrict dx,
    const float* __restrict dy, const float* __restrict dz,
    const float* __restrict ax_, const float* __restrict ay_,
    const float* __restrict az_, const float* __restrict rx,
    const float* __restrict ry, const float* __restrict rz,
    float* __restrict nx, float* __restrict ny, float* __restrict nz,
    float* __restrict bx, float* __restrict by, float* __restrict bz) {
  for (int k = 0; k < count; ++k) {
    const float ox = nx[k], oy = ny[k], oz = nz[k];
    float vx = ox + tau * dx[k];
    float vy = oy + tau * dy[k];
    float vz = oz + tau * dz[k];
    projectFeasible<kSoft>(vx, vy, vz, ax_[k], ay_[k], az_[k], rx[k], ry[k],
                           rz[k]);
    nx[k] = vx;
    ny[k] = vy;
    nz[k] = vz;
    bx[k] = 2.0f * vx - ox;
    by[k] = 2.0f * vy - oy;
    bz[k] = 2.0f * vz - oz;
  }
}

}  // namespace

bool runInnerActiveFast(const PreparedLevel& level, const InnerParams& prm,
                        ActiveBuffers& b, int iterations) {
  const int P = b.num_active, L = b.num_inputs;
  const float sigma_eps = prm.sigma * prm.huber_eps;
  const float sigma_data = prm.sigma_data;
  auto& nb = b.nbar;
  // Small sets are not worth a second thread.
  const int threads = P >= kMinActivePerThread ? prm.num_threads : 1;
  auto update = prm.soft_visibility ? primalUpdateIndexed<true>
                                    : primalUpdateIndexed<false>;
  // The stop request, read before the first iteration, then by thread 0
  // before each iteration's last barrier and acted on by every thread after
  // it (the same decision for all: none is left at a barrier). Written again
  // only after the next iteration's first barrier, when every thread has
  // read it.
  if (iterations <= 0) return true;
  bool stop = stopRequested(prm.cancel);
  if (stop) return false;
  int done = iterations;
#pragma omp parallel num_threads(threads)
  {
    // Each thread: a fixed share of the links and of the pixels.
    const int t = omp_get_thread_num(), T = omp_get_num_threads();
    const int m0 = static_cast<int>(static_cast<long>(b.num_links) * t / T);
    const int m1 =
        static_cast<int>(static_cast<long>(b.num_links) * (t + 1) / T);
    const int k0 = static_cast<int>(static_cast<long>(P) * t / T);
    const int k1 = static_cast<int>(static_cast<long>(P) * (t + 1) / T);
    const int np = k1 - k0;
    for (int it = 0; it < iterations; ++it) {
      // Dual ascent on the smoothness terms of each link: p <- prox(p +
      // sigma (nbar_b - nbar_a)).
      // Links [0, P) (right) and [P, 2 P) (below) start at node m and m - P:
      // read contiguously; the ghosts' links by index.
      for (int range = 0; range < 3; ++range) {
        const int begin = std::max(m0, range * P);
        const int end = std::min(m1, range < 2 ? (range + 1) * P : b.num_links);
        if (begin >= end) continue;
        if (range < 2) {
          const int first_node = begin - range * P;
          linkDualsFirstContiguous(
              end - begin, prm.sigma, sigma_eps, b.link_b.data() + begin,
              b.link_w.data() + begin, nb[0].data() + first_node,
              nb[1].data() + first_node, nb[2].data() + first_node,
              nb[0].data(), nb[1].data(), nb[2].data(), b.p[0].data() + begin,
              b.p[1].data() + begin, b.p[2].data() + begin);
        } else {
          linkDualsIndexed(end - begin, prm.sigma, sigma_eps,
                           b.link_a.data() + begin, b.link_b.data() + begin,
                           b.link_w.data() + begin, nb[0].data(), nb[1].data(),
                           nb[2].data(), b.p[0].data() + begin,
                           b.p[1].data() + begin, b.p[2].data() + begin);
        }
      }
#pragma omp barrier
      // Dual ascent on each data term at the active pixels (nodes [0, P)):
      // q_l <- prox(q_l + sigma (nbar - f_l)).
      for (int l = 0; l < L; ++l) {
        const float* f[3];
        float* q[3];
        for (int ch = 0; ch < 3; ++ch) {
          f[ch] = b.f.data() + (3 * l + ch) * P + k0;
          q[ch] = b.q.data() + (3 * l + ch) * P + k0;
        }
        const float* c_w = b.c.data() + l * P + k0;
        const float* n[3] = {nb[0].data() + k0, nb[1].data() + k0,
                             nb[2].data() + k0};
        if (prm.penalty == DataPenalty::kL2 && level.data_huber) {
          dataDualRowHuber(np, sigma_data, c_w, b.delta.data() + l * P + k0,
                           n[0], n[1], n[2], f[0], f[1], f[2], q[0], q[1],
                           q[2]);
        } else if (prm.penalty == DataPenalty::kL2) {
          dataDualRowL2(np, sigma_data, c_w, n[0], n[1], n[2], f[0], f[1], f[2],
                        q[0], q[1], q[2]);
        } else {
          dataDualRowSquared(np, sigma_data, c_w, n[0], n[1], n[2], f[0], f[1],
                             f[2], q[0], q[1], q[2]);
        }
      }
      // d = div p - sum_l q_l.
      for (int ch = 0; ch < 3; ++ch) {
        divergenceRightBelowContiguous(
            np, b.p[ch].data() + k0, b.p[ch].data() + P + k0,
            b.left_link.data() + k0, b.above_link.data() + k0, b.p[ch].data(),
            b.d[ch].data() + k0);
        for (int l = 0; l < L; ++l) {
          subtractRow(np, b.q.data() + (3 * l + ch) * P + k0,
                      b.d[ch].data() + k0);
        }
      }
      // Primal descent: n <- Proj_C(n + tau d), nbar <- 2 n - n_old.
      update(np, prm.tau, b.d[0].data() + k0, b.d[1].data() + k0,
             b.d[2].data() + k0, b.n0[0].data() + k0, b.n0[1].data() + k0,
             b.n0[2].data() + k0, b.ray[0].data() + k0, b.ray[1].data() + k0,
             b.ray[2].data() + k0, b.n[0].data() + k0, b.n[1].data() + k0,
             b.n[2].data() + k0, nb[0].data() + k0, nb[1].data() + k0,
             nb[2].data() + k0);
      if (t == 0) stop = stopRequested(prm.cancel);
#pragma omp barrier
      if (stop && it + 1 < iterations) {
        if (t == 0) done = it + 1;
        break;
      }
    }
  }
  return done == iterations;
}

namespace {

/// Sum over links [m0, m1) of w huber_eps(|n_b - n_a|).
NF_MULTIVERSION
float linkEnergyBlock(int m0, int m1, float eps, const int* __restrict a,
                      const int* __restrict b, const float* __restrict w,
                      const float* __restrict nx, const float* __restrict ny,
                      const float* __restrict nz) {
  const float inv_2eps = eps > 0.0f ? 0.5f / eps : 0.0f;
  float sum = 0.0f;
  for (int m = m0; m < m1; ++m) {
    const float gx = nx[b[m]] - nx[a[m]];
    const float gy = ny[b[m]] - ny[a[m]];
    const float gz = nz[b[m]] - nz[a[m]];
    const float z = std::sqrt(gx * gx + gy * gy + gz * gz);
    sum += w[m] * (z < eps ? z * z * inv_2eps : z - 0.5f * eps);
  }
  return sum;
}

/// Sum over pixels [k0, k1) of c phi(n - f) (unsquared with Huber threshold
/// delta, or squared).
NF_MULTIVERSION
float dataEnergyBlock(int k0, int k1, bool squared, const float* __restrict c,
                      const float* __restrict delta, const float* __restrict nx,
                      const float* __restrict ny, const float* __restrict nz,
                      const float* __restrict fx, const float* __restrict fy,
                      const float* __restrict fz) {
  float sum = 0.0f;
  for (int k = k0; k < k1; ++k) {
    const float dx = nx[k] - fx[k], dy = ny[k] - fy[k], dz = nz[k] - fz[k];
    const float d2 = dx * dx + dy * dy + dz * dz;
    const float z = std::sqrt(d2);
    const float th = delta[k];
    const float huber =
        z < th ? d2 / (2.0f * std::max(th, kTiny)) : z - 0.5f * th;
    sum += c[k] * (squared ? 0.5f * d2 : huber);
  }
  return sum;
}

}  // namespace

double ActiveBuffers::energy(double huber_eps, DataPenalty penalty,
                             int threads) const {
  const int L = num_inputs, P = num_active;
  const auto& nn = node_n;
  // Blocks: the links' smoothness terms w huber(|n_b - n_a|), then each
  // input's data terms c_l phi(n - f_l) at the active pixels (c = 0 where an
  // input is missing).
  const int link_blocks = (num_links + kEnergyBlock - 1) / kEnergyBlock;
  const int data_blocks = (P + kEnergyBlock - 1) / kEnergyBlock;
  const int blocks = link_blocks + L * data_blocks;
  if (block_sums.size() < static_cast<std::size_t>(blocks)) {
    block_sums.resize(blocks);
  }
  const float eps = static_cast<float>(huber_eps);
  const bool squared = penalty == DataPenalty::kSquaredL2;
  const int used = P >= kMinActivePerThread ? threads : 1;
#pragma omp parallel for num_threads(used) schedule(static)
  for (int b = 0; b < blocks; ++b) {
    if (b < link_blocks) {
      const int m0 = b * kEnergyBlock;
      block_sums[b] =
          linkEnergyBlock(m0, std::min(num_links, m0 + kEnergyBlock), eps,
                          link_a.data(), link_b.data(), link_w.data(),
                          nn[0].data(), nn[1].data(), nn[2].data());
    } else {
      const int l = (b - link_blocks) / data_blocks;
      const int k0 = ((b - link_blocks) % data_blocks) * kEnergyBlock;
      block_sums[b] = dataEnergyBlock(
          k0, std::min(P, k0 + kEnergyBlock), squared, c.data() + l * P,
          delta.data() + l * P, nn[0].data(), nn[1].data(), nn[2].data(),
          f.data() + (3 * l) * P, f.data() + (3 * l + 1) * P,
          f.data() + (3 * l + 2) * P);
    }
  }
  double total = 0.0;
  for (int b = 0; b < blocks; ++b) total += block_sums[b];
  return total;
}

namespace {

/// Energy terms of one row, summed in float over the row (vectorised); the
/// rows are then summed in double.
NF_MULTIVERSION
float energyRow(int W, const float* __restrict nx, const float* __restrict ny,
                const float* __restrict nz, const float* __restrict bx,
                const float* __restrict by, const float* __restrict bz,
                float below_on, const float* __restrict w_h,
                const float* __restrict w_v, float eps, float inv_2eps) {
  float sum = 0.0f;
  // Smoothness: w_h huber(n(x+1) - n(x)) + w_v huber(n(y+1) - n(y)).
  for (int x = 0; x < W; ++x) {
    const int xr = x + 1 < W ? x + 1 : x;
    const float gx = nx[xr] - nx[x], gy = ny[xr] - ny[x], gz = nz[xr] - nz[x];
    const float zh = std::sqrt(gx * gx + gy * gy + gz * gz);
    const float vx = bx[x] - nx[x], vy = by[x] - ny[x], vz = bz[x] - nz[x];
    const float zv = below_on * std::sqrt(vx * vx + vy * vy + vz * vz);
    const float hh = zh < eps ? zh * zh * inv_2eps : zh - 0.5f * eps;
    const float hv = zv < eps ? zv * zv * inv_2eps : zv - 0.5f * eps;
    sum += w_h[x] * hh + w_v[x] * hv;
  }
  return sum;
}

NF_MULTIVERSION
float dataEnergyRow(int W, bool squared, const float* __restrict nx,
                    const float* __restrict ny, const float* __restrict nz,
                    const float* __restrict fx, const float* __restrict fy,
                    const float* __restrict fz, const float* __restrict c) {
  float sum = 0.0f;
  for (int x = 0; x < W; ++x) {
    const float dx = nx[x] - fx[x], dy = ny[x] - fy[x], dz = nz[x] - fz[x];
    const float d2 = dx * dx + dy * dy + dz * dz;
    sum += c[x] * (squared ? 0.5f * d2 : std::sqrt(d2));
  }
  return sum;
}

/// sum c huber_delta(|n - f|) over one row (delta = 0: c |n - f|).
NF_MULTIVERSION
float dataHuberEnergyRow(int W, const float* __restrict nx,
                         const float* __restrict ny, const float* __restrict nz,
                         const float* __restrict fx, const float* __restrict fy,
                         const float* __restrict fz, const float* __restrict c,
                         const float* __restrict delta) {
  float sum = 0.0f;
  for (int x = 0; x < W; ++x) {
    const float dx = nx[x] - fx[x], dy = ny[x] - fy[x], dz = nz[x] - fz[x];
    const float z = std::sqrt(dx * dx + dy * dy + dz * dz);
    const float d = delta[x];
    sum += c[x] * (z < d ? z * z / (2.0f * d) : z - 0.5f * d);
  }
  return sum;
}

}  // namespace

double energyFast(const PreparedLevel& level, double huber_eps,
                  DataPenalty penalty, const PlanarImage& normals,
                  int num_threads) {
  const int W = level.width, H = level.height;
  const float eps = static_cast<float>(huber_eps);
  const float inv_2eps = eps > 0.0f ? 0.5f / eps : 0.0f;
  const bool squared = penalty == DataPenalty::kSquaredL2;
  double total = 0.0;
#pragma omp parallel for num_threads(num_threads) reduction(+ : total) schedule(static)
  for (int y = 0; y < H; ++y) {
    const std::size_t off = static_cast<std::size_t>(y) * W;
    const std::size_t off_below = y + 1 < H ? off + W : off;
    double row =
        energyRow(W, normals.plane(0) + off, normals.plane(1) + off,
                  normals.plane(2) + off, normals.plane(0) + off_below,
                  normals.plane(1) + off_below, normals.plane(2) + off_below,
                  y + 1 < H ? 1.0f : 0.0f, level.edge_weight.plane(0) + off,
                  level.edge_weight.plane(1) + off, eps, inv_2eps);
    for (int l = 0; l < level.num_inputs; ++l) {
      if (!squared && level.data_huber) {
        row += dataHuberEnergyRow(
            W, normals.plane(0) + off, normals.plane(1) + off,
            normals.plane(2) + off, level.data[l].plane(0) + off,
            level.data[l].plane(1) + off, level.data[l].plane(2) + off,
            level.data_weight[l].plane(0) + off,
            level.data_eps[l].plane(0) + off);
        continue;
      }
      row += dataEnergyRow(
          W, squared, normals.plane(0) + off, normals.plane(1) + off,
          normals.plane(2) + off, level.data[l].plane(0) + off,
          level.data[l].plane(1) + off, level.data[l].plane(2) + off,
          level.data_weight[l].plane(0) + off);
    }
    total += row;
  }
  return total;
}

}  // namespace internal
}  // namespace normal_fusion
