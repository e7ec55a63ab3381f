// Fast backend, energies: E on a whole level (float terms per row, rows in
// double) and the terms of a local refinement (fixed blocks, summed in
// double in order: the same for any thread count).
#include <algorithm>
#include <cmath>

#include "kernels_fast_steps.h"
#include "normal_fusion/detail/multiversion.h"
#include "normal_fusion/detail/solver_internal.h"

namespace normal_fusion {
namespace internal {

using namespace fast;

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