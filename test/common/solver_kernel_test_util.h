// Random levels, steps and comparisons shared by the tests of the solver's
// iterations (test/core/test_kernels_fast.cpp, test_local_refinement.cpp).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <initializer_list>
#include <utility>

#include "normal_fusion/detail/solver_internal.h"
#include "test_util.h"

namespace normal_fusion {
namespace test {

/// Builds a random level with L inputs (some missing) for backend comparisons;
/// with `data_huber`, random per-pixel data thresholds delta in [0, 0.6].
inline internal::PreparedLevel randomLevel(int W, int H, int L,
                                           std::uint64_t seed,
                                           bool data_huber = false) {
  internal::PreparedLevel level;
  level.width = W;
  level.height = H;
  level.num_inputs = L;
  level.K = CameraIntrinsics(0.9 * W, 0.9 * W, W / 2.0, H / 2.0);
  level.K_inv = level.K.inverse();
  level.edge_weight = test::randomImage(W, H, 2, seed);
  for (std::size_t i = 0; i < level.edge_weight.pixelCount() * 2; ++i) {
    level.edge_weight.data()[i] = 0.01f + std::abs(level.edge_weight.data()[i]);
  }
  for (int l = 0; l < L; ++l) {
    PlanarImage f = test::randomImage(W, H, 3, seed + 10 + l);
    PlanarImage c = test::randomImage(W, H, 1, seed + 20 + l);
    for (std::size_t i = 0; i < f.pixelCount(); ++i) {
      float v[3] = {f.plane(0)[i], f.plane(1)[i],
                    -std::abs(f.plane(2)[i]) - 0.2f};
      const float len = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
      const bool missing = c.plane(0)[i] < -0.7f;
      for (int k = 0; k < 3; ++k) f.plane(k)[i] = missing ? 0.0f : v[k] / len;
      c.plane(0)[i] = missing ? 0.0f : std::abs(c.plane(0)[i]);
    }
    level.data.push_back(f);
    level.data_weight.push_back(c);
    PlanarImage delta = test::randomImage(W, H, 1, seed + 30 + l);
    for (std::size_t i = 0; i < delta.pixelCount(); ++i) {
      delta.plane(0)[i] =
          data_huber ? 0.6f * std::abs(delta.plane(0)[i]) : 0.0f;
    }
    level.data_eps.push_back(delta);
  }
  level.data_huber = data_huber;
  return level;
}

/// Diagonally preconditioned steps for L data terms (tau = 1 / (4 + L),
/// sigma = 1/2 for the differences, 1 for the data terms), Huber threshold
/// 0.05, soft visibility.
inline internal::InnerParams preconditionedParams(int L, int threads) {
  internal::InnerParams params;
  params.tau = 1.0f / (4.0f + L);
  params.sigma = 0.5f;
  params.sigma_data = 1.0f;
  params.huber_eps = 0.05f;
  params.soft_visibility = true;
  params.num_threads = threads;
  return params;
}

/// The iteration state at the first input's normals (facing the camera
/// where it has none), every dual 0.
inline void initState(const internal::PreparedLevel& level,
                      internal::IterationState& s) {
  s.resize(level.width, level.height, level.num_inputs);
  s.n0 = level.data[0];
  for (std::size_t i = 0; i < s.n0.pixelCount(); ++i) {
    if (level.data_weight[0].plane(0)[i] <= 0.0f) {
      s.n0.plane(0)[i] = 0.0f;
      s.n0.plane(1)[i] = 0.0f;
      s.n0.plane(2)[i] = -1.0f;
    }
  }
  s.n = s.n0;
  s.nbar = s.n0;
  s.p_h.fill(0.0f);
  s.p_v.fill(0.0f);
  for (auto& q : s.q) q.fill(0.0f);
}

/// Largest |a - b| over all values of the pairs of images.
inline double maxAbsDiff(
    std::initializer_list<std::pair<const PlanarImage*, const PlanarImage*>>
        pairs) {
  double max_diff = 0.0;
  for (const auto& pair : pairs) {
    const std::size_t n = pair.first->pixelCount() * pair.first->channels();
    for (std::size_t i = 0; i < n; ++i) {
      max_diff = std::max(
          max_diff, static_cast<double>(std::abs(pair.first->data()[i] -
                                                 pair.second->data()[i])));
    }
  }
  return max_diff;
}

}  // namespace test
}  // namespace normal_fusion
