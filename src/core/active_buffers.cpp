// The fast path of a local refinement: the variables of the active pixels,
// their links and ghosts gathered into contiguous arrays (ActiveBuffers) and
// written back, and the choice of its thread count (RefineThreadChooser).
// Its kernel is in kernels_fast_active.cpp.
#include <algorithm>
#include <cmath>

#include "normal_fusion/detail/solver_internal.h"

namespace normal_fusion {
namespace internal {

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
  gatherTopology(level, active);
  gatherValues(level, s, threads);
}

void ActiveBuffers::gatherTopology(const PreparedLevel& level,
                                   const ActiveSet& active) {
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
  sizeNodeBuffers();
}

void ActiveBuffers::sizeNodeBuffers() {
  const int L = num_inputs, P = num_active;
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
}

void ActiveBuffers::gatherValues(const PreparedLevel& level,
                                 const IterationState& s, int threads) {
  const int L = num_inputs, P = num_active;
  const long num_nodes = static_cast<long>(node_pixel.size());
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

int RefineThreadChooser::cheaper() const {
  if (max_threads_ == 1 || cost_all_ == 0.0 || cost_one_ == 0.0) {
    return max_threads_;
  }
  return cost_one_ < cost_all_ ? 1 : max_threads_;
}

int RefineThreadChooser::choose() {
  if (max_threads_ == 1) return 1;
  // Each count measured once before the costs decide.
  if (cost_all_ == 0.0) return max_threads_;
  if (cost_one_ == 0.0) return 1;
  const int cheaper = this->cheaper();
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

void RefineThreadChooser::shrink(int threads) {
  (threads == 1 ? cost_one_ : cost_all_) *= kShrink;
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

}  // namespace internal
}  // namespace normal_fusion
