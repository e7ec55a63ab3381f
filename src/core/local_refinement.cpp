// Local refinement of a warm start: which pixels to refine (unknown,
// contradicted by the inputs, edges of the warm map, and their surroundings),
// how the unknown ones are filled, and the Chambolle-Pock iteration restricted
// to them with every other pixel held fixed: the reference path (the
// reference backend's per-pixel steps through index lists) and the gathered
// arrays of the fast path (its kernel is in kernels_fast.cpp). The work is in
// proportion to the active pixels, not the image.
#include <omp.h>

#include <algorithm>
#include <cmath>
#include <limits>

#include "normal_fusion/detail/multiversion.h"
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

namespace {
template <typename T>
void growTo(std::vector<T>& v, std::size_t n) {
  if (v.size() < n) v.resize(n);
}
}  // namespace

void ActiveBuffers::preallocate(int W, int H, int L, int active) {
  const std::size_t N = static_cast<std::size_t>(W) * H;
  const std::size_t P = static_cast<std::size_t>(active);
  // About 2.5 links (the dummies included) and 1.5 nodes per active pixel
  // (ghosts included).
  const std::size_t links = 3 * P + 1, nodes = 2 * P;
  if (node_of.size() != N) node_of.assign(N, -1);
  node_pixel.reserve(nodes);
  for (auto* v : {&link_a, &link_b, &link_pixel}) growTo(*v, links);
  growTo(link_w, links);
  for (auto& component : p) growTo(component, links);
  for (int ch = 0; ch < 3; ++ch) {
    growTo(nbar[ch], nodes);
    growTo(node_n[ch], nodes);
    for (auto* v : {&n[ch], &n0[ch], &ray[ch], &d[ch]}) growTo(*v, P);
  }
  growTo(q, 3 * L * P);
  growTo(f, 3 * L * P);
  growTo(c, L * P);
  growTo(delta, L * P);
  // energy()'s partial sums, one per block of terms.
  growTo(block_sums, (links + kEnergyBlock - 1) / kEnergyBlock +
                         L * ((P + kEnergyBlock - 1) / kEnergyBlock));
  for (auto* list : {&left_link, &above_link}) growTo(*list, P);
}

std::size_t ActiveBuffers::bytesHeld() const {
  std::size_t bytes =
      internal::bytesHeld(node_pixel) + internal::bytesHeld(node_of) +
      internal::bytesHeld(q) + internal::bytesHeld(f) + internal::bytesHeld(c) +
      internal::bytesHeld(delta) + internal::bytesHeld(left_link) +
      internal::bytesHeld(above_link) + internal::bytesHeld(link_a) +
      internal::bytesHeld(link_b) + internal::bytesHeld(link_pixel) +
      internal::bytesHeld(link_w) + internal::bytesHeld(block_sums);
  for (int ch = 0; ch < 3; ++ch) {
    for (const auto* v :
         {&nbar[ch], &n[ch], &n0[ch], &ray[ch], &p[ch], &d[ch], &node_n[ch]}) {
      bytes += internal::bytesHeld(*v);
    }
  }
  return bytes;
}

void ActiveBuffers::gather(const PreparedLevel& level, const IterationState& s,
                           const ActiveSet& active, int threads) {
  const int W = level.width, H = level.height;
  const int L = level.num_inputs;
  const std::size_t N = static_cast<std::size_t>(W) * H;
  num_inputs = L;
  num_active = static_cast<int>(active.pixels.size());
  const int P = num_active;
  if (node_of.size() != N) node_of.assign(N, -1);
  // Nodes: the active pixels, then the ghosts met through the links (one
  // thread: the numbering).
  node_pixel.clear();
  for (int i : active.pixels) {
    node_of[i] = static_cast<int>(node_pixel.size());
    node_pixel.push_back(i);
  }
  auto node = [&](int i) {
    if (node_of[i] < 0) {
      node_of[i] = static_cast<int>(node_pixel.size());
      node_pixel.push_back(i);
    }
    return node_of[i];
  };
  // Links: the link to the right of active pixel k is link k, the one below
  // it link P + k (a dummy with a = b = k and w = 0 where the image ends),
  // then the horizontal and the vertical links whose first (left, upper)
  // pixel is a ghost. So a link's first node is contiguous for 2 P of them,
  // and so are the right and lower links of the active pixels.
  num_ghost_links_h = 0;
  int num_ghost_links_v = 0;
  for (int i : active.links_h) num_ghost_links_h += active.mask[i] == 0;
  for (int i : active.links_v) num_ghost_links_v += active.mask[i] == 0;
  num_links = 2 * P + num_ghost_links_h + num_ghost_links_v;
  const std::size_t links = static_cast<std::size_t>(num_links) + 1;
  growTo(link_a, links);
  growTo(link_b, links);
  growTo(link_w, links);
  growTo(link_pixel, links);
  for (auto& component : p) growTo(component, links);
  for (int ch = 0; ch < 3; ++ch) growTo(ray[ch], P);
  // The active pixels come in raster order (ActiveSet::build): their rows
  // are followed, not divided out.
  int y = 0, row_start = 0;
  for (int k = 0; k < P; ++k) {
    const int i = active.pixels[k];
    while (i >= row_start + W) {
      row_start += W;
      ++y;
    }
    const int x = i - row_start;
    float r[3];
    level.ray(x, y, r);
    for (int ch = 0; ch < 3; ++ch) ray[ch][k] = r[ch];
    const bool has_right = x + 1 < W, has_below = y + 1 < H;
    link_a[k] = link_a[P + k] = k;
    link_b[k] = has_right ? node(i + 1) : k;
    link_pixel[k] = has_right ? i : -1;
    link_b[P + k] = has_below ? node(i + W) : k;
    link_pixel[P + k] = has_below ? i : -1;
  }
  int m = 2 * P;
  for (int i : active.links_h) {
    if (active.mask[i] != 0) continue;
    link_a[m] = node(i);
    link_b[m] = node(i + 1);
    link_pixel[m++] = i;
  }
  for (int i : active.links_v) {
    if (active.mask[i] != 0) continue;
    link_a[m] = node(i);
    link_b[m] = node(i + W);
    link_pixel[m++] = i;
  }
  // The dummy link: no force.
  link_a[num_links] = link_b[num_links] = 0;
  link_w[num_links] = 0.0f;
  for (int ch = 0; ch < 3; ++ch) p[ch][num_links] = 0.0f;
  const long num_nodes = static_cast<long>(node_pixel.size());
  for (int ch = 0; ch < 3; ++ch) {
    growTo(nbar[ch], num_nodes);
    growTo(n[ch], P);
    growTo(n0[ch], P);
    growTo(d[ch], P);
  }
  for (int ch = 0; ch < 3; ++ch) growTo(node_n[ch], num_nodes);
  growTo(q, static_cast<std::size_t>(3) * L * P);
  growTo(f, static_cast<std::size_t>(3) * L * P);
  growTo(c, static_cast<std::size_t>(L) * P);
  growTo(delta, static_cast<std::size_t>(L) * P);
  for (auto* list : {&left_link, &above_link}) growTo(*list, P);
    // The values, copied in parallel.
#pragma omp parallel num_threads(threads)
  {
#pragma omp for schedule(static) nowait
    for (int m = 0; m < num_links; ++m) {
      const int i = link_pixel[m];
      if (i < 0) {  // a dummy: no force
        link_w[m] = 0.0f;
        for (int ch = 0; ch < 3; ++ch) p[ch][m] = 0.0f;
        continue;
      }
      const bool horizontal = isHorizontal(m);
      const PlanarImage& dual = horizontal ? s.p_h : s.p_v;
      link_w[m] = level.edge_weight.plane(horizontal ? 0 : 1)[i];
      for (int ch = 0; ch < 3; ++ch) p[ch][m] = dual.plane(ch)[i];
    }
    // Every node starts at n0 (ghosts stay there).
#pragma omp for schedule(static) nowait
    for (long k = 0; k < num_nodes; ++k) {
      for (int ch = 0; ch < 3; ++ch) {
        nbar[ch][k] = node_n[ch][k] = s.n0.plane(ch)[node_pixel[k]];
      }
    }
#pragma omp for schedule(static)
    for (int k = 0; k < P; ++k) {
      const int i = node_pixel[k];
      for (int ch = 0; ch < 3; ++ch) n[ch][k] = n0[ch][k] = s.n0.plane(ch)[i];
      for (int l = 0; l < L; ++l) {
        for (int ch = 0; ch < 3; ++ch) {
          q[(3 * l + ch) * P + k] = s.q[l].plane(ch)[i];
          f[(3 * l + ch) * P + k] = level.data[l].plane(ch)[i];
        }
        c[l * P + k] = level.data_weight[l].plane(0)[i];
        delta[l * P + k] =
            level.data_huber ? level.data_eps[l].plane(0)[i] : 0.0f;
      }
      left_link[k] = above_link[k] = num_links;
    }
    // Each link is the left (upper) link of its second node (one link per
    // entry: no two threads write the same one).
#pragma omp for schedule(static) nowait
    for (int m = 0; m < num_links; ++m) {
      if (link_pixel[m] < 0 || link_b[m] >= P) continue;  // dummy, ghost
      (isHorizontal(m) ? left_link : above_link)[link_b[m]] = m;
    }
#pragma omp for schedule(static)
    for (long k = 0; k < num_nodes; ++k) node_of[node_pixel[k]] = -1;
  }
}

void RefineThreadChooser::reset(int max_threads) {
  max_threads_ = std::max(1, max_threads);
  cost_one_ = cost_all_ = 0.0;
  steps_since_probe_ = 0;
}

int RefineThreadChooser::choose() {
  if (max_threads_ == 1) return 1;
  // Each count measured once before the costs decide.
  if (cost_all_ == 0.0) return max_threads_;
  if (cost_one_ == 0.0) return 1;
  const int cheaper = cost_one_ < cost_all_ ? 1 : max_threads_;
  // Every kProbeInterval-th step the other count, so that a change of the
  // machine's load is noticed.
  if (++steps_since_probe_ >= kProbeInterval) {
    steps_since_probe_ = 0;
    return cheaper == 1 ? max_threads_ : 1;
  }
  return cheaper;
}

void RefineThreadChooser::record(int threads,
                                 double seconds_per_pixel_iteration) {
  if (!(seconds_per_pixel_iteration > 0.0) ||
      !std::isfinite(seconds_per_pixel_iteration)) {
    return;
  }
  (threads == 1 ? cost_one_ : cost_all_) = seconds_per_pixel_iteration;
}

void ActiveBuffers::normalizeCandidate() {
  for (int k = 0; k < num_active; ++k) {
    const float inv = 1.0f / std::sqrt(n[0][k] * n[0][k] + n[1][k] * n[1][k] +
                                       n[2][k] * n[2][k]);
    for (int ch = 0; ch < 3; ++ch) node_n[ch][k] = n[ch][k] * inv;
  }
}

void ActiveBuffers::acceptCandidate() {
  for (int ch = 0; ch < 3; ++ch) {
    for (int k = 0; k < num_active; ++k) {
      n0[ch][k] = n[ch][k] = nbar[ch][k] = node_n[ch][k];
    }
  }
}

void ActiveBuffers::scatter(IterationState& s, int threads) const {
  const int L = num_inputs, P = num_active;
#pragma omp parallel num_threads(threads)
  {
#pragma omp for schedule(static) nowait
    for (int k = 0; k < P; ++k) {
      const int i = node_pixel[k];
      for (int ch = 0; ch < 3; ++ch) {
        s.n0.plane(ch)[i] = n0[ch][k];
        for (int l = 0; l < L; ++l) {
          s.q[l].plane(ch)[i] = q[(3 * l + ch) * P + k];
        }
      }
    }
#pragma omp for schedule(static)
    for (int m = 0; m < num_links; ++m) {
      const int i = link_pixel[m];
      if (i < 0) continue;  // a dummy
      PlanarImage& dual = isHorizontal(m) ? s.p_h : s.p_v;
      for (int ch = 0; ch < 3; ++ch) dual.plane(ch)[i] = p[ch][m];
    }
  }
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

namespace {

/// The terms of E that involve pixel i when it holds the unit normal v: its
/// data terms and the links to its 4-neighbours j with use[j] == 1 (the
/// others left out).
double pixelEnergy(const PreparedLevel& level, double huber_eps,
                   DataPenalty penalty, const PlanarImage& normals,
                   const unsigned char* use, int i, const float v[3]) {
  const int W = level.width, H = level.height;
  const int x = i % W, y = i / W;
  const double n[3] = {v[0], v[1], v[2]};
  double total = dataEnergyAt(level, penalty, i, n);
  // w huber(|v - n_j|) of the link between i and j, weight w_h or w_v at the
  // link's left or upper pixel.
  auto link = [&](int j, float w) {
    if (use[j] != 1) return;
    double g2 = 0.0;
    for (int c = 0; c < 3; ++c) {
      const double g = static_cast<double>(normals.plane(c)[j]) - v[c];
      g2 += g * g;
    }
    total += w * huberPenalty(std::sqrt(g2), huber_eps);
  };
  const float* w_h = level.edge_weight.plane(0);
  const float* w_v = level.edge_weight.plane(1);
  if (x > 0) link(i - 1, w_h[i - 1]);
  if (x + 1 < W) link(i + 1, w_h[i]);
  if (y > 0) link(i - W, w_v[i - W]);
  if (y + 1 < H) link(i + W, w_v[i]);
  return total;
}

/// Pixel i takes, among the normals of its 4-neighbours j with use[j] == 1,
/// each input's observation and its window mean (projected onto the visible
/// set in soft mode), the one of lowest pixelEnergy(); it keeps its normal if
/// there is none.
void chooseCandidate(const PreparedLevel& level, double huber_eps,
                     DataPenalty penalty, bool soft, PlanarImage& normals,
                     const unsigned char* use, int i) {
  const int W = level.width, H = level.height;
  const int x = i % W, y = i / W;
  float r[3];
  level.ray(x, y, r);
  float best_v[3] = {normals.plane(0)[i], normals.plane(1)[i],
                     normals.plane(2)[i]};
  double best = std::numeric_limits<double>::infinity();
  auto consider = [&](float v[3]) {
    if (soft) projectVisible(r, v);
    const double e = pixelEnergy(level, huber_eps, penalty, normals, use, i, v);
    if (e < best) {
      best = e;
      for (int c = 0; c < 3; ++c) best_v[c] = v[c];
    }
  };
  const int neighbours[4] = {x > 0 ? i - 1 : -1, x + 1 < W ? i + 1 : -1,
                             y > 0 ? i - W : -1, y + 1 < H ? i + W : -1};
  for (int j : neighbours) {
    if (j < 0 || use[j] != 1) continue;
    float v[3] = {normals.plane(0)[j], normals.plane(1)[j],
                  normals.plane(2)[j]};
    consider(v);
  }
  for (int l = 0; l < level.num_inputs; ++l) {
    if (!(level.data_weight[l].plane(0)[i] > 0.0f)) continue;
    float v[3] = {level.data[l].plane(0)[i], level.data[l].plane(1)[i],
                  level.data[l].plane(2)[i]};
    consider(v);
    // The input's window mean, when there is one.
    if (l < static_cast<int>(level.data_mean.size()) &&
        level.data_mean[l].plane(3)[i] >= 0.0f) {
      float m[3] = {level.data_mean[l].plane(0)[i],
                    level.data_mean[l].plane(1)[i],
                    level.data_mean[l].plane(2)[i]};
      consider(m);
    }
  }
  for (int c = 0; c < 3; ++c) normals.plane(c)[i] = best_v[c];
}

}  // namespace

void fillUnknownPixels(const PreparedLevel& level, double huber_eps,
                       DataPenalty penalty, bool soft, PlanarImage& normals,
                       std::vector<unsigned char>& known,
                       const ActiveSet& active, int max_passes,
                       std::vector<unsigned char>& filled,
                       std::vector<int>& pending, int threads,
                       const std::atomic<bool>* cancel) {
  const int W = level.width, H = level.height;
  // The unknown pixels, in ascending order; each pass visits only those left.
  pending.clear();
  for (int i : active.pixels) {
    if (known[i] == 0) pending.push_back(i);
  }
  if (filled.size() < pending.size()) filled.resize(pending.size());
  // Pass by pass inwards from the known pixels: an unknown pixel with a known
  // 4-neighbour (known before this pass) takes its best candidate. Within a
  // pass, pixels read only known ones and write only themselves (in
  // parallel); they become known after it.
  for (int pass = 0;
       pass < max_passes && !pending.empty() && !stopRequested(cancel);
       ++pass) {
    const long count = static_cast<long>(pending.size());
    long filled_now = 0;
#pragma omp parallel for num_threads(threads) schedule(dynamic, 256) reduction(+ : filled_now)
    for (long k = 0; k < count; ++k) {
      const int i = pending[k];
      const int x = i % W, y = i / W;
      const bool next_to_known =
          (x > 0 && known[i - 1] == 1) || (x + 1 < W && known[i + 1] == 1) ||
          (y > 0 && known[i - W] == 1) || (y + 1 < H && known[i + W] == 1);
      filled[k] = next_to_known ? 1 : 0;
      if (!next_to_known) continue;
      chooseCandidate(level, huber_eps, penalty, soft, normals, known.data(),
                      i);
      ++filled_now;
    }
    // The filled ones become known; the others stay pending.
    long left = 0;
    for (long k = 0; k < count; ++k) {
      if (filled[k] != 0) {
        known[pending[k]] = 1;
      } else {
        pending[left++] = pending[k];
      }
    }
    pending.resize(left);
    if (filled_now == 0) break;
  }
}

int markInconsistentPixels(const PreparedLevel& level,
                           const PlanarImage& normals, int local_radius,
                           std::vector<unsigned char>& unknown, int threads) {
  const int L = static_cast<int>(level.data_mean.size());
  const long N = static_cast<long>(level.width) * level.height;
  const float chord = static_cast<float>(
      2.0 * std::sin(0.5 * kInconsistentDegrees * 3.14159265358979 / 180.0));
  // Two standard errors of a full window's mean per unit of spread.
  const float standard_errors = 2.0f / (2 * local_radius + 1);
  const float* n[3] = {normals.plane(0), normals.plane(1), normals.plane(2)};
  long marked = 0;
  // Chunks of kChunk pixels: per input, branch-free (vectorised) counts of
  // the inputs that observe each pixel and of those that contradict it.
  constexpr long kChunk = 512;
#pragma omp parallel for num_threads(threads) schedule(static) reduction(+ : marked)
  for (long begin = 0; begin < N; begin += kChunk) {
    const int count = static_cast<int>(std::min(kChunk, N - begin));
    unsigned char observing[kChunk] = {};
    unsigned char contradicting[kChunk] = {};
    for (int l = 0; l < L; ++l) {
      const PlanarImage& mean = level.data_mean[l];
      const float* m[4] = {mean.plane(0) + begin, mean.plane(1) + begin,
                           mean.plane(2) + begin, mean.plane(3) + begin};
      const float* c = level.data_weight[l].plane(0) + begin;
      const float* nx = n[0] + begin;
      const float* ny = n[1] + begin;
      const float* nz = n[2] + begin;
      for (int k = 0; k < count; ++k) {
        // An input observes the pixel when it has a sample there and a
        // spread in its window; it contradicts the warm normal when |n - m_l|
        // exceeds chord + 2 s_l / sqrt(window).
        const bool observes = (c[k] > 0.0f) & (m[3][k] >= 0.0f);
        const float dx = nx[k] - m[0][k], dy = ny[k] - m[1][k],
                    dz = nz[k] - m[2][k];
        const float limit = chord + standard_errors * m[3][k];
        const bool contradicts =
            observes & (dx * dx + dy * dy + dz * dz > limit * limit);
        observing[k] += observes ? 1 : 0;
        contradicting[k] += contradicts ? 1 : 0;
      }
    }
    // Every input that observes the pixel must contradict it: one input's
    // artifacts do not count.
    unsigned char* u = unknown.data() + begin;
    for (int k = 0; k < count; ++k) {
      const bool mark =
          (u[k] == 0) & (observing[k] > 0) & (contradicting[k] == observing[k]);
      u[k] = mark ? 1 : u[k];
      marked += mark ? 1 : 0;
    }
  }
  return static_cast<int>(marked);
}

namespace {

/// edge[i + k] for k < count: pixel i + k is known (u == 0) and one of its
/// neighbours left + k, right + k, up + k, down + k is not unknown (u != 1)
/// and more than acos(min_cos) away. Branch-free (vectorised).
NF_MULTIVERSION
void mapEdgesRow(int count, float min_cos, const float* __restrict nx,
                 const float* __restrict ny, const float* __restrict nz,
                 const unsigned char* __restrict u, int i, int left, int right,
                 int up, int down, unsigned char* __restrict edge) {
  for (int k = 0; k < count; ++k) {
    const float x0 = nx[i + k], y0 = ny[i + k], z0 = nz[i + k];
    auto apart = [&](int j) {
      return (u[j] != 1) & (x0 * nx[j] + y0 * ny[j] + z0 * nz[j] < min_cos);
    };
    const bool any =
        apart(left + k) | apart(right + k) | apart(up + k) | apart(down + k);
    edge[i + k] = ((u[i + k] == 0) & any) ? 1 : 0;
  }
}

}  // namespace

int markMapEdges(const PlanarImage& normals,
                 std::vector<unsigned char>& unknown,
                 std::vector<unsigned char>& edge, int threads) {
  const int W = normals.width(), H = normals.height();
  const float min_cos = static_cast<float>(
      std::cos(kInconsistentDegrees * 3.14159265358979 / 180.0));
  const float* nx = normals.plane(0);
  const float* ny = normals.plane(1);
  const float* nz = normals.plane(2);
  edge.resize(unknown.size());
  const unsigned char* u = unknown.data();
  long marked = 0;
#pragma omp parallel num_threads(threads)
  {
    // The edges into `edge` (reading `unknown` only), then merged. A
    // neighbour j of pixel i is apart when it is not unknown (!= 1) and
    // their normals are more than kInconsistentDegrees apart; i is an edge
    // when it is known (0) and some 4-neighbour is apart.
#pragma omp for schedule(static)
    for (int y = 0; y < H; ++y) {
      const int row = y * W;
      // Neighbours above and below (the row itself at the image's border,
      // never apart from itself).
      const int up = y > 0 ? row - W : row;
      const int down = y + 1 < H ? row + W : row;
      // The first and last columns (their missing neighbour: themselves),
      // then the interior (vectorised).
      auto mark = [&](int x, int left, int right) {
        mapEdgesRow(1, min_cos, nx, ny, nz, u, row + x, left, right, up + x,
                    down + x, edge.data());
      };
      mark(0, row, std::min(row + 1, row + W - 1));
      if (W > 1) mark(W - 1, row + W - 2, row + W - 1);
      if (W > 2) {
        mapEdgesRow(W - 2, min_cos, nx, ny, nz, u, row + 1, row, row + 2,
                    up + 1, down + 1, edge.data());
      }
    }
#pragma omp for schedule(static) reduction(+ : marked)
    for (long i = 0; i < static_cast<long>(unknown.size()); ++i) {
      if (edge[i] != 0) {
        unknown[i] = 2;
        ++marked;
      }
    }
  }
  return static_cast<int>(marked);
}

}  // namespace internal
}  // namespace normal_fusion
