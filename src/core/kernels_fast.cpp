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

#include "kernels_fast_steps.h"
#include "normal_fusion/detail/multiversion.h"
#include "normal_fusion/detail/solver_internal.h"

namespace normal_fusion {
namespace internal {

using namespace fast;

namespace {

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

/// p <- clamp_w((p + sigma g) / (1 + sigma eps / w)) for one row of one
/// direction, with g = next - here given as two row pointers; relaxed,
/// p <- p + rho (p_hat - p), when rho != 1.
NF_MULTIVERSION
void huberDualRow(int n, float sigma, float sigma_eps, float rho,
                  const float* __restrict w, const float* __restrict here_x,
                  const float* __restrict here_y,
                  const float* __restrict here_z,
                  const float* __restrict next_x,
                  const float* __restrict next_y,
                  const float* __restrict next_z, float* __restrict px,
                  float* __restrict py, float* __restrict pz) {
  if (rho == 1.0f) {
    for (int x = 0; x < n; ++x) {
      // p <- prox(p + sigma grad nbar), grad nbar = next - here.
      huberDualStep(px[x], py[x], pz[x], next_x[x] - here_x[x],
                    next_y[x] - here_y[x], next_z[x] - here_z[x], sigma, w[x],
                    sigma_eps);
    }
    return;
  }
  for (int x = 0; x < n; ++x) {
    // p <- p + rho (prox(p + sigma grad nbar) - p).
    huberDualStepRelaxed(px[x], py[x], pz[x], next_x[x] - here_x[x],
                         next_y[x] - here_y[x], next_z[x] - here_z[x], sigma,
                         w[x], sigma_eps, rho);
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
  const float rho = prm.relaxation;
  // p_h: grad_h nbar = nbar(x+1) - nbar(x), 0 on the last column (so the
  // last column sees next = here).
  huberDualRow(W - 1, sigma, sigma_eps, rho, level.edge_weight.plane(0) + off,
               nb.x, nb.y, nb.z, nb.x + 1, nb.y + 1, nb.z + 1, ph.x, ph.y,
               ph.z);
  huberDualRow(1, sigma, sigma_eps, rho,
               level.edge_weight.plane(0) + off + W - 1, nb.x + W - 1,
               nb.y + W - 1, nb.z + W - 1, nb.x + W - 1, nb.y + W - 1,
               nb.z + W - 1, ph.x + W - 1, ph.y + W - 1, ph.z + W - 1);
  // p_v: grad_v nbar = nbar(y+1) - nbar(y), 0 on the last row.
  const ConstPlanes3 nb_next = rowOf(static_cast<const PlanarImage&>(s.nbar),
                                     y + 1 < level.height ? off + W : off);
  huberDualRow(W, sigma, sigma_eps, rho, level.edge_weight.plane(1) + off, nb.x,
               nb.y, nb.z, nb_next.x, nb_next.y, nb_next.z, pv.x, pv.y, pv.z);
  // q_l, one data term at a time.
  for (int l = 0; l < level.num_inputs; ++l) {
    const ConstPlanes3 f = rowOf(level.data[l], off);
    const float* c_w = level.data_weight[l].plane(0) + off;
    const Planes3 q = rowOf(s.q[l], off);
    if (prm.penalty == DataPenalty::kL2 && level.data_huber) {
      dataDualRowHuber(W, sigma_data, c_w, level.data_eps[l].plane(0) + off,
                       nb.x, nb.y, nb.z, f.x, f.y, f.z, q.x, q.y, q.z, rho);
    } else if (prm.penalty == DataPenalty::kL2) {
      dataDualRowL2(W, sigma_data, c_w, nb.x, nb.y, nb.z, f.x, f.y, f.z, q.x,
                    q.y, q.z, rho);
    } else {
      dataDualRowSquared(W, sigma_data, c_w, nb.x, nb.y, nb.z, f.x, f.y, f.z,
                         q.x, q.y, q.z, rho);
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

/// n_hat = Proj_C(n + tau d), nbar <- 2 n_hat - n_old for one row; C the
/// tangent plane at n0, intersected with n . r <= 0 when kSoft; n <- n_hat,
/// or n_old + rho (n_hat - n_old) when kRelaxed.
template <bool kSoft, bool kRelaxed>
NF_MULTIVERSION void primalUpdateRow(
    int W, float tau, float rho, const float* __restrict dx,
    const float* __restrict dy, const float* __restrict dz,
    const float* __restrict ax_, const float* __restrict ay_,
    const float* __restrict az_, float r0x, float r0y, float r0z, float drx,
    float dry, float drz, float* __restrict nx, float* __restrict ny,
    float* __restrict nz, float* __restrict bx, float* __restrict by,
    float* __restrict bz) {
  for (int x = 0; x < W; ++x) {
    const float ox = nx[x], oy = ny[x], oz = nz[x];
    float vx = ox + tau * dx[x];
    float vy = oy + tau * dy[x];
    float vz = oz + tau * dz[x];
    // Ray r = K^-1 (x, y, 1), affine along the row.
    const float xf = static_cast<float>(x);
    projectFeasible<kSoft>(vx, vy, vz, ax_[x], ay_[x], az_[x], r0x + drx * xf,
                           r0y + dry * xf, r0z + drz * xf);
    nx[x] = kRelaxed ? relaxed(ox, vx, rho) : vx;
    ny[x] = kRelaxed ? relaxed(oy, vy, rho) : vy;
    nz[x] = kRelaxed ? relaxed(oz, vz, rho) : vz;
    bx[x] = 2.0f * vx - ox;
    by[x] = 2.0f * vy - oy;
    bz[x] = 2.0f * vz - oz;
  }
}

/// Primal pass over one row: n_hat = Proj_C(n + tau (div p - sum q)),
/// nbar <- 2 n_hat - n_old, n <- n_old + rho (n_hat - n_old). `scratch` holds 3
/// rows of W floats.
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
  const bool relax = prm.relaxation != 1.0f;
  auto update =
      prm.soft_visibility
          ? (relax ? primalUpdateRow<true, true> : primalUpdateRow<true, false>)
          : (relax ? primalUpdateRow<false, true>
                   : primalUpdateRow<false, false>);
  update(W, prm.tau, prm.relaxation, d[0], d[1], d[2], n0.x, n0.y, n0.z, r0x,
         r0y, r0z, static_cast<float>(Ki[0]), static_cast<float>(Ki[3]),
         static_cast<float>(Ki[6]), n.x, n.y, n.z, nb.x, nb.y, nb.z);
}

/// The pipeline's shared state: each thread's progress through the rows,
/// and the stop request latched by the first thread that sees it.
struct Pipeline {
  int threads = 1;
  int depth = 1;
  int rounds = 0;
  std::vector<std::atomic<long>>* progress = nullptr;
  std::atomic<bool> stopped{false};
  const std::atomic<bool>* cancel = nullptr;

  bool stop() {
    if (stopped.load(std::memory_order_relaxed)) return true;
    if (!stopRequested(cancel)) return false;
    // Latched: a request withdrawn now does not leave a thread waiting for
    // one that has left.
    stopped.store(true, std::memory_order_relaxed);
    return true;
  }
};

/// Thread t's part of the pipeline: in each round, `mine` consecutive
/// iterations as a wavefront one row behind its predecessor.
void runPipelineThread(const PreparedLevel& level, const InnerParams& params,
                       IterationState& state, int iterations, int t,
                       Pipeline& pipe) {
  const int W = level.width;
  const int H = level.height;
  const int threads = pipe.threads;
  std::vector<std::atomic<long>>& progress = *pipe.progress;
  float* scratch =
      state.row_scratch.data() + static_cast<std::size_t>(t) * 3 * W;
  const int per_round = threads * pipe.depth;
  int remaining = iterations;
  // False once the thread stopped on the request: it skips the rest.
  bool running = true;
  for (int round = 0; round < pipe.rounds && running; ++round) {
    // Iterations of this round, split as evenly as possible over threads.
    const int in_round = std::min(per_round, remaining);
    remaining -= in_round;
    const int mine = in_round / threads + (t < in_round % threads ? 1 : 0);
    // Whose rows this thread's first iteration depends on: the previous
    // thread in this round, or the last thread of the previous round.
    const int pred = t > 0 ? t - 1 : threads - 1;
    const long pred_base =
        t > 0 ? static_cast<long>(round) * H : static_cast<long>(round - 1) * H;
    const bool must_wait = !(t == 0 && round == 0);
    if (mine == 0) {
      // Nothing to do: pass the predecessor's progress on.
      if (must_wait) {
        while (running &&
               progress[pred].load(std::memory_order_acquire) < pred_base + H) {
          running = !pipe.stop();
          std::this_thread::yield();
        }
      }
      if (!running) break;
      progress[t].store(static_cast<long>(round + 1) * H,
                        std::memory_order_release);
      continue;
    }
    for (int step = 0; step < H + mine - 1 && running; ++step) {
      running = !pipe.stop();
      // The first iteration processes row `step`: wait until the
      // predecessor's last iteration has finished row step + 1.
      if (running && must_wait && step < H) {
        const long needed = pred_base + std::min(step + 2, H);
        int spins = 0;
        while (running &&
               progress[pred].load(std::memory_order_acquire) < needed) {
          if (++spins > 64) {
            running = !pipe.stop();
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
  Pipeline pipe;
  pipe.threads = std::max(1, std::min(params.num_threads, iterations));
  pipe.depth = std::max(1, params.block_depth);
  pipe.cancel = params.cancel;
  const int threads = pipe.threads;
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
  pipe.progress = &progress;
  const int per_round = threads * pipe.depth;
  pipe.rounds = (iterations + per_round - 1) / per_round;
#pragma omp parallel num_threads(threads)
  runPipelineThread(level, params, state, iterations, omp_get_thread_num(),
                    pipe);
  return !pipe.stopped.load(std::memory_order_relaxed);
}

}  // namespace internal
}  // namespace normal_fusion
