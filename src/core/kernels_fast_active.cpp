// Fast backend, local refinement: the Chambolle-Pock iteration of
// runInnerActive() on the variables gathered into contiguous arrays
// (ActiveBuffers), the links' and the pixels' steps each one vectorised loop,
// on up to num_threads threads with fixed shares.
#include <omp.h>

#include <algorithm>

#include "kernels_fast_steps.h"
#include "normal_fusion/detail/multiversion.h"
#include "normal_fusion/detail/solver_internal.h"

namespace normal_fusion {
namespace internal {

using namespace fast;

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

/// One thread's fixed share of a local refinement: links [m0, m1) and
/// active pixels [k0, k1).
struct Share {
  int m0, m1, k0, k1;
};

/// Dual ascent on the smoothness terms of the share's links: p <- prox(p +
/// sigma (nbar_b - nbar_a)). Links [0, P) (right) and [P, 2 P) (below) start
/// at node m and m - P: read contiguously; the ghosts' links by index.
void linkDualsOfShare(const InnerParams& prm, ActiveBuffers& b,
                      const Share& sh) {
  const int P = b.num_active;
  const float sigma_eps = prm.sigma * prm.huber_eps;
  auto& nb = b.nbar;
  for (int range = 0; range < 3; ++range) {
    const int begin = std::max(sh.m0, range * P);
    const int end = std::min(sh.m1, range < 2 ? (range + 1) * P : b.num_links);
    if (begin >= end) continue;
    if (range < 2) {
      const int first_node = begin - range * P;
      linkDualsFirstContiguous(
          end - begin, prm.sigma, sigma_eps, b.link_b.data() + begin,
          b.link_w.data() + begin, nb[0].data() + first_node,
          nb[1].data() + first_node, nb[2].data() + first_node, nb[0].data(),
          nb[1].data(), nb[2].data(), b.p[0].data() + begin,
          b.p[1].data() + begin, b.p[2].data() + begin);
    } else {
      linkDualsIndexed(end - begin, prm.sigma, sigma_eps,
                       b.link_a.data() + begin, b.link_b.data() + begin,
                       b.link_w.data() + begin, nb[0].data(), nb[1].data(),
                       nb[2].data(), b.p[0].data() + begin,
                       b.p[1].data() + begin, b.p[2].data() + begin);
    }
  }
}

/// Dual ascent on each data term at the share's active pixels:
/// q_l <- prox(q_l + sigma (nbar - f_l)).
void dataDualsOfShare(const PreparedLevel& level, const InnerParams& prm,
                      ActiveBuffers& b, const Share& sh) {
  const int P = b.num_active, k0 = sh.k0, np = sh.k1 - sh.k0;
  const float sigma_data = prm.sigma_data;
  auto& nb = b.nbar;
  for (int l = 0; l < b.num_inputs; ++l) {
    const float* f[3];
    float* q[3];
    for (int ch = 0; ch < 3; ++ch) {
      f[ch] = b.f.data() + (3 * l + ch) * P + k0;
      q[ch] = b.q.data() + (3 * l + ch) * P + k0;
    }
    const float* c_w = b.c.data() + l * P + k0;
    const float* n[3] = {nb[0].data() + k0, nb[1].data() + k0,
                         nb[2].data() + k0};
    // The local refinement runs the plain step (relaxation 1).
    if (prm.penalty == DataPenalty::kL2 && level.data_huber) {
      dataDualRowHuber(np, sigma_data, c_w, b.delta.data() + l * P + k0, n[0],
                       n[1], n[2], f[0], f[1], f[2], q[0], q[1], q[2], 1.0f);
    } else if (prm.penalty == DataPenalty::kL2) {
      dataDualRowL2(np, sigma_data, c_w, n[0], n[1], n[2], f[0], f[1], f[2],
                    q[0], q[1], q[2], 1.0f);
    } else {
      dataDualRowSquared(np, sigma_data, c_w, n[0], n[1], n[2], f[0], f[1],
                         f[2], q[0], q[1], q[2], 1.0f);
    }
  }
}

/// d = div p - sum_l q_l, then the primal descent n <- Proj_C(n + tau d),
/// nbar <- 2 n - n_old at the share's active pixels.
void primalOfShare(const InnerParams& prm, ActiveBuffers& b, const Share& sh) {
  const int P = b.num_active, k0 = sh.k0, np = sh.k1 - sh.k0;
  auto& nb = b.nbar;
  for (int ch = 0; ch < 3; ++ch) {
    divergenceRightBelowContiguous(
        np, b.p[ch].data() + k0, b.p[ch].data() + P + k0,
        b.left_link.data() + k0, b.above_link.data() + k0, b.p[ch].data(),
        b.d[ch].data() + k0);
    for (int l = 0; l < b.num_inputs; ++l) {
      subtractRow(np, b.q.data() + (3 * l + ch) * P + k0, b.d[ch].data() + k0);
    }
  }
  auto update = prm.soft_visibility ? primalUpdateIndexed<true>
                                    : primalUpdateIndexed<false>;
  update(np, prm.tau, b.d[0].data() + k0, b.d[1].data() + k0,
         b.d[2].data() + k0, b.n0[0].data() + k0, b.n0[1].data() + k0,
         b.n0[2].data() + k0, b.ray[0].data() + k0, b.ray[1].data() + k0,
         b.ray[2].data() + k0, b.n[0].data() + k0, b.n[1].data() + k0,
         b.n[2].data() + k0, nb[0].data() + k0, nb[1].data() + k0,
         nb[2].data() + k0);
}

}  // namespace

bool runInnerActiveFast(const PreparedLevel& level, const InnerParams& prm,
                        ActiveBuffers& b, int iterations) {
  const int P = b.num_active;
  // Small sets are not worth a second thread.
  const int threads = P >= kMinActivePerThread ? prm.num_threads : 1;
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
    const Share share{
        static_cast<int>(static_cast<long>(b.num_links) * t / T),
        static_cast<int>(static_cast<long>(b.num_links) * (t + 1) / T),
        static_cast<int>(static_cast<long>(P) * t / T),
        static_cast<int>(static_cast<long>(P) * (t + 1) / T)};
    for (int it = 0; it < iterations; ++it) {
      linkDualsOfShare(prm, b, share);
#pragma omp barrier
      dataDualsOfShare(level, prm, b, share);
      primalOfShare(prm, b, share);
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

}  // namespace internal
}  // namespace normal_fusion
