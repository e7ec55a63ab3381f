// Local refinement of a warm start: the active set (the pixels to refine
// and their surroundings), the reference path of the Chambolle-Pock iteration
// restricted to it (the reference backend's per-pixel steps through index
// lists; every other pixel held fixed) and its terms of E. The work is in
// proportion to the active pixels, not the image.
#include <algorithm>
#include <cmath>

#include "normal_fusion/detail/solver_internal.h"

namespace normal_fusion {
namespace internal {

void ActiveSet::preallocate(int W, int H) {
  if (W == width && H == height) return;
  const std::size_t N = static_cast<std::size_t>(W) * H;
  width = W;
  height = H;
  // Buffers of a much larger image give their memory back.
  releaseIfOversized(mask, N);
  releaseIfOversized(scratch, N);
  mask.assign(N, 0);
  scratch.assign(N, 0);
  // Every entry written once (then cleared): the pages exist from now on.
  for (auto* list : {&pixels, &links_h, &links_v, &links_up, &links_down}) {
    releaseIfOversized(*list, N);
    list->assign(N, 0);
    list->clear();
  }
}

std::size_t ActiveSet::bytesHeld() const {
  std::size_t bytes = internal::bytesHeld(mask) + internal::bytesHeld(scratch);
  for (const auto* list :
       {&pixels, &links_h, &links_v, &links_up, &links_down}) {
    bytes += internal::bytesHeld(*list);
  }
  return bytes;
}

void ActiveSet::build(const std::vector<unsigned char>& seed, int W, int H,
                      int radius) {
  preallocate(W, H);
  pixels.clear();
  links_h.clear();
  links_v.clear();
  links_down.clear();
  // Dilation by a (2 radius + 1)^2 square, separably: along the rows into
  // `scratch`, then down the columns into `mask`.
  for (int y = 0; y < H; ++y) {
    const unsigned char* in = seed.data() + static_cast<std::size_t>(y) * W;
    unsigned char* out = scratch.data() + static_cast<std::size_t>(y) * W;
    int last_seed = -2 * radius - 1;  // latest seed at or left of x (none)
    for (int x = 0; x < W; ++x) out[x] = 0;
    for (int x = 0; x < W + radius; ++x) {
      if (x < W && in[x] != 0) last_seed = x;
      const int centre = x - radius;
      if (centre >= 0 && centre < W) {
        out[centre] = x - last_seed <= 2 * radius ? 1 : 0;
      }
    }
  }
  for (int y = 0; y < H; ++y) {
    const int y0 = std::max(0, y - radius), y1 = std::min(H - 1, y + radius);
    unsigned char* out = mask.data() + static_cast<std::size_t>(y) * W;
    for (int x = 0; x < W; ++x) out[x] = 0;
    for (int v = y0; v <= y1; ++v) {
      const unsigned char* in =
          scratch.data() + static_cast<std::size_t>(v) * W;
      for (int x = 0; x < W; ++x) out[x] |= in[x];
    }
  }
  // The active pixels, and each link once: to the right and below an active
  // pixel, and to the left and above one when that neighbour is inactive.
  // Horizontal links come in ascending order; vertical ones in two ascending
  // lists (above, below), merged.
  links_up.clear();
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const int i = y * W + x;
      if (mask[i] == 0) continue;
      pixels.push_back(i);
      if (x > 0 && mask[i - 1] == 0) links_h.push_back(i - 1);
      if (x + 1 < W) links_h.push_back(i);
      if (y > 0 && mask[i - W] == 0) links_up.push_back(i - W);
      if (y + 1 < H) links_down.push_back(i);
    }
  }
  links_v.resize(links_up.size() + links_down.size());
  std::merge(links_up.begin(), links_up.end(), links_down.begin(),
             links_down.end(), links_v.begin());
}

namespace {

/// Dual step of the weighted Huber term on one link (i to j):
/// p <- prox(p + sigma (nbar_j - nbar_i)).
inline void linkDualStep(const PlanarImage& nbar, PlanarImage& p, float w,
                         float sigma, float eps, int i, int j) {
  float v[3];
  for (int c = 0; c < 3; ++c) {
    const float* nb = nbar.plane(c);
    v[c] = p.plane(c)[i] + sigma * (nb[j] - nb[i]);
  }
  reference::huberDualProx(v, w, sigma, eps);
  for (int c = 0; c < 3; ++c) p.plane(c)[i] = v[c];
}

}  // namespace

bool runInnerActive(const PreparedLevel& level, const InnerParams& params,
                    IterationState& s, const ActiveSet& active,
                    int iterations) {
  const int W = level.width, H = level.height;
  const long num_h = static_cast<long>(active.links_h.size());
  const long num_v = static_cast<long>(active.links_v.size());
  const long num_px = static_cast<long>(active.pixels.size());
  const float* w_h = level.edge_weight.plane(0);
  const float* w_v = level.edge_weight.plane(1);
  // The stop request, read by one thread before each iteration (the single
  // construct's barrier then gives every thread the same decision).
  bool stop = false;
#pragma omp parallel num_threads(params.num_threads)
  for (int it = 0; it < iterations; ++it) {
    // A stop request ends the run before the iteration.
#pragma omp single
    stop = stopRequested(params.cancel);
    if (stop) {
      break;
    }
    // Dual ascent on the smoothness terms of the links that touch an active
    // pixel: p_d <- prox(p_d + sigma grad_d nbar).
#pragma omp for schedule(static) nowait
    for (long k = 0; k < num_h; ++k) {
      const int i = active.links_h[k];
      linkDualStep(s.nbar, s.p_h, w_h[i], params.sigma, params.huber_eps, i,
                   i + 1);
    }
#pragma omp for schedule(static)
    for (long k = 0; k < num_v; ++k) {
      const int i = active.links_v[k];
      linkDualStep(s.nbar, s.p_v, w_v[i], params.sigma, params.huber_eps, i,
                   i + W);
    }
#pragma omp for schedule(static)
    for (long k = 0; k < num_px; ++k) {
      const int i = active.pixels[k];
      const int x = i % W, y = i / W;
      // Dual ascent on each data term: q_l <- prox(q_l + sigma (nbar - f_l)).
      float q_sum[3] = {0.0f, 0.0f, 0.0f};
      for (int l = 0; l < level.num_inputs; ++l) {
        const float c_w = level.data_weight[l].plane(0)[i];
        float v[3];
        for (int c = 0; c < 3; ++c) {
          v[c] = s.q[l].plane(c)[i] +
                 params.sigma_data *
                     (s.nbar.plane(c)[i] - level.data[l].plane(c)[i]);
        }
        reference::dataDualProx(
            v, c_w, level.data_huber ? level.data_eps[l].plane(0)[i] : 0.0f,
            params.sigma_data, params.penalty);
        for (int c = 0; c < 3; ++c) {
          s.q[l].plane(c)[i] = v[c];
          q_sum[c] += v[c];
        }
      }
      // Primal descent: n <- Proj_C(n + tau (div p - sum q)), div the
      // backward differences of p (0 beyond the image), over-relaxation.
      float v[3], n0_px[3], r[3], n_old[3];
      for (int c = 0; c < 3; ++c) {
        const float* ph = s.p_h.plane(c);
        const float* pv = s.p_v.plane(c);
        const float div =
            (x + 1 < W ? ph[i] : 0.0f) - (x > 0 ? ph[i - 1] : 0.0f) +
            (y + 1 < H ? pv[i] : 0.0f) - (y > 0 ? pv[i - W] : 0.0f);
        n_old[c] = s.n.plane(c)[i];
        n0_px[c] = s.n0.plane(c)[i];
        v[c] = n_old[c] + params.tau * (div - q_sum[c]);
      }
      level.ray(x, y, r);
      projectTangentFeasible(n0_px, r, params.soft_visibility, v);
      for (int c = 0; c < 3; ++c) {
        s.n.plane(c)[i] = v[c];
        s.nbar.plane(c)[i] = 2.0f * v[c] - n_old[c];
      }
    }
  }
  return !stop;
}

double energyActive(const PreparedLevel& level, double huber_eps,
                    DataPenalty penalty, const PlanarImage& normals,
                    const ActiveSet& active, int num_threads) {
  const int W = level.width;
  // w huber(|n_j - n_i|) of one link.
  auto link = [&](const float* w, int i, int j) {
    double g2 = 0.0;
    for (int c = 0; c < 3; ++c) {
      const double g =
          static_cast<double>(normals.plane(c)[j]) - normals.plane(c)[i];
      g2 += g * g;
    }
    return w[i] * huberPenalty(std::sqrt(g2), huber_eps);
  };
  const long num_h = static_cast<long>(active.links_h.size());
  const long num_v = static_cast<long>(active.links_v.size());
  const long num_px = static_cast<long>(active.pixels.size());
  double total = 0.0;
#pragma omp parallel num_threads(num_threads) reduction(+ : total)
  {
    // Smoothness: w_h huber(grad_h n) + w_v huber(grad_v n) of each link.
#pragma omp for schedule(static) nowait
    for (long k = 0; k < num_h; ++k) {
      const int i = active.links_h[k];
      total += link(level.edge_weight.plane(0), i, i + 1);
    }
#pragma omp for schedule(static) nowait
    for (long k = 0; k < num_v; ++k) {
      const int i = active.links_v[k];
      total += link(level.edge_weight.plane(1), i, i + W);
    }
    // Data terms: sum_l c_l phi(n - f_l) at each active pixel.
#pragma omp for schedule(static) nowait
    for (long k = 0; k < num_px; ++k) {
      const int i = active.pixels[k];
      const double n[3] = {normals.plane(0)[i], normals.plane(1)[i],
                           normals.plane(2)[i]};
      total += dataEnergyAt(level, penalty, i, n);
    }
  }
  return total;
}

}  // namespace internal
}  // namespace normal_fusion
