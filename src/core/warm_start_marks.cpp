// The pixels of a warm start to refine: those the inputs contradict, the
// edges of the warm map, and the fill of the unknown ones from their known
// neighbours.
#include <algorithm>
#include <cmath>
#include <limits>

#include "normal_fusion/detail/multiversion.h"
#include "normal_fusion/detail/solver_internal.h"

namespace normal_fusion {
namespace internal {

namespace {

/// The links of a pixel to its 4-neighbours j with use[j] == 1 (left,
/// right, up, down, in that order): each neighbour and the link's weight
/// (w_h or w_v at the link's left or upper pixel). Found once per pixel,
/// not once per candidate.
struct PixelLinks {
  int count = 0;
  int neighbour[4];
  float weight[4];
};

PixelLinks linksOf(const PreparedLevel& level, const unsigned char* use, int i,
                   int x, int y) {
  const int W = level.width, H = level.height;
  const float* w_h = level.edge_weight.plane(0);
  const float* w_v = level.edge_weight.plane(1);
  PixelLinks links;
  auto add = [&](int j, float w) {
    if (use[j] != 1) return;
    links.neighbour[links.count] = j;
    links.weight[links.count++] = w;
  };
  if (x > 0) add(i - 1, w_h[i - 1]);
  if (x + 1 < W) add(i + 1, w_h[i]);
  if (y > 0) add(i - W, w_v[i - W]);
  if (y + 1 < H) add(i + W, w_v[i]);
  return links;
}

/// The terms of E that involve pixel i when it holds the unit normal v: its
/// data terms and the `links` to its neighbours (the others left out).
/// Every term is >= 0, so a partial sum that reaches `bound` is returned as
/// it is: the full sum would not be below `bound` either.
double pixelEnergy(const PreparedLevel& level, double huber_eps,
                   DataPenalty penalty, const PlanarImage& normals,
                   const PixelLinks& links, int i, const float v[3],
                   double bound) {
  const double n[3] = {v[0], v[1], v[2]};
  double total = dataEnergyAt(level, penalty, i, n);
  // w huber(|v - n_j|) of each link.
  for (int k = 0; k < links.count; ++k) {
    if (!(total < bound)) return total;
    const int j = links.neighbour[k];
    double g2 = 0.0;
    for (int c = 0; c < 3; ++c) {
      const double g = static_cast<double>(normals.plane(c)[j]) - v[c];
      g2 += g * g;
    }
    total += links.weight[k] * huberPenalty(std::sqrt(g2), huber_eps);
  }
  return total;
}

/// Pixel i takes, among the normals of its 4-neighbours j with use[j] == 1,
/// each input's observation and its window mean (projected onto the visible
/// set in soft mode), the one of lowest pixelEnergy(); it keeps its normal if
/// there is none.
void chooseCandidate(const PreparedLevel& level, double huber_eps,
                     DataPenalty penalty, bool soft, PlanarImage& normals,
                     const unsigned char* use, int i) {
  const int W = level.width;
  const int x = i % W, y = i / W;
  float r[3];
  level.ray(x, y, r);
  const PixelLinks links = linksOf(level, use, i, x, y);
  float best_v[3] = {normals.plane(0)[i], normals.plane(1)[i],
                     normals.plane(2)[i]};
  double best = std::numeric_limits<double>::infinity();
  auto consider = [&](float v[3]) {
    if (soft) projectVisible(r, v);
    const double e =
        pixelEnergy(level, huber_eps, penalty, normals, links, i, v, best);
    if (e < best) {
      best = e;
      for (int c = 0; c < 3; ++c) best_v[c] = v[c];
    }
  };
  for (int k = 0; k < links.count; ++k) {
    const int j = links.neighbour[k];
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
