// Dynamic guidance of the edge weights (docs/method.md): each link's weight
// w = w_img + mu (1 - w_img) phi(|n_p - n_q| / s) from the outer iterate, and
// the guidance's share of the energy that the weighted energy lacks.
#include "normal_fusion/detail/dynamic_guidance.h"

#include <algorithm>
#include <cmath>

#include "normal_fusion/detail/multiversion.h"

namespace normal_fusion {
namespace internal {
namespace {

constexpr double kPi = 3.14159265358979323846;

/// One row's links in one direction (the other end `next` values on):
/// w = w_img + k phi(|n_q - n_p|) with k = mu (1 - w_img), or 0 where an end
/// is unobserved; returns the row's share of the correction, sum k (Psi -
/// phi huber). Branch-free, so that it vectorises.
NF_MULTIVERSION
double guidedRow(int count, std::size_t next, const float* __restrict n0,
                 const float* __restrict n1, const float* __restrict n2,
                 const float* __restrict img, const float* __restrict gain,
                 float* __restrict w, GuidancePenaltyTerms psi) {
  double correction = 0.0;
  const double inv_scale = 1.0 / psi.scale;
#pragma omp simd reduction(+ : correction)
  for (int x = 0; x < count; ++x) {
    const float d0 = n0[x + next] - n0[x];
    const float d1 = n1[x + next] - n1[x];
    const float d2 = n2[x + next] - n2[x];
    const double t =
        std::sqrt(static_cast<double>(d0 * d0 + d1 * d1 + d2 * d2));
    const double xs = t * inv_scale;
    // phi = exp(-(t / s)^2), once for the weight and for Psi.
    const double phi = expNonPositive(-xs * xs);
    w[x] = img[x] + gain[x] * static_cast<float>(phi);
    correction += gain[x] * psi.correction(t, phi);
  }
  return correction;
}

/// The links past the last column or row couple nothing (d = 0): phi = 1.
void outerLinks(int count, const float* img, float* w, float mu) {
  for (int x = 0; x < count; ++x) {
    w[x] = img[x] + mu * std::max(0.0f, 1.0f - img[x]);
  }
}

}  // namespace

GuidanceTerms guidanceTerms(const SolverSettings& settings) {
  GuidanceTerms terms;
  terms.mu = static_cast<float>(settings.dynamic_guidance);
  // The chord |n_p - n_q| of two unit normals at the angle given.
  terms.scale = static_cast<float>(
      2.0 * std::sin(0.5 * settings.dynamic_guidance_deg * kPi / 180.0));
  terms.huber_eps = static_cast<float>(settings.huber_eps);
  return terms;
}

void DynamicGuidance::begin(PreparedLevel& level, const PreparedLevel& finest,
                            const GuidanceTerms& terms, int threads) {
  level_ = &level;
  terms_ = terms;
  // Sized for the finest level first, so that the pyramid's smaller levels
  // and the frames after reuse the buffers.
  image_weight_.resize(finest.width, finest.height, 2);
  image_weight_.resizeKeepingCapacity(level.width, level.height, 2);
  link_gain_.resize(finest.width, finest.height, 2);
  link_gain_.resizeKeepingCapacity(level.width, level.height, 2);
  // A much larger frame's buffers are given back (PlanarImage's rule).
  releaseIfOversized(row_sums_, static_cast<std::size_t>(finest.height));
  releaseIfOversized(observed_, finest.edge_weight.pixelCount());
  if (row_sums_.size() < static_cast<std::size_t>(finest.height)) {
    row_sums_.resize(finest.height);
  }
  const std::size_t pixels = level.edge_weight.pixelCount();
  if (observed_.capacity() < finest.edge_weight.pixelCount()) {
    observed_.reserve(finest.edge_weight.pixelCount());
  }
  observed_.resize(pixels);
  const int W = level.width, H = level.height, L = level.num_inputs;
  const float* w_h = level.edge_weight.plane(0);
  const float* w_v = level.edge_weight.plane(1);
  float* img_h = image_weight_.plane(0);
  float* img_v = image_weight_.plane(1);
  float* k_h = link_gain_.plane(0);
  float* k_v = link_gain_.plane(1);
  float* observed = observed_.data();
  const float mu = terms.mu;
  // Observed: some input has weight at the pixel (1, else 0).
#pragma omp parallel for num_threads(threads) schedule(static)
  for (int y = 0; y < H; ++y) {
    const std::size_t row = static_cast<std::size_t>(y) * W;
    float* o = observed + row;
    for (int x = 0; x < W; ++x) o[x] = 0.0f;
    for (int l = 0; l < L; ++l) {
      const float* c = level.data_weight[l].plane(0) + row;
      for (int x = 0; x < W; ++x) o[x] = c[x] > 0.0f ? 1.0f : o[x];
    }
  }
  // The image weights kept, and k = mu (1 - w_img) of each link inside the
  // image, 0 where an end is unobserved (the link keeps w_img there) and on
  // the links past the last column and row.
#pragma omp parallel for num_threads(threads) schedule(static)
  for (int y = 0; y < H; ++y) {
    const std::size_t row = static_cast<std::size_t>(y) * W;
    const float* o = observed + row;
    for (int x = 0; x < W; ++x) {
      img_h[row + x] = w_h[row + x];
      img_v[row + x] = w_v[row + x];
    }
    for (int x = 0; x + 1 < W; ++x) {
      k_h[row + x] =
          o[x] * o[x + 1] * mu * std::max(0.0f, 1.0f - img_h[row + x]);
    }
    k_h[row + W - 1] = 0.0f;
    if (y + 1 == H) {
      std::fill(k_v + row, k_v + row + W, 0.0f);
      continue;
    }
    const float* o_below = o + W;
    for (int x = 0; x < W; ++x) {
      k_v[row + x] =
          o[x] * o_below[x] * mu * std::max(0.0f, 1.0f - img_v[row + x]);
    }
  }
}

double DynamicGuidance::reweight(const PlanarImage& normals, int threads) {
  PreparedLevel& level = *level_;
  const int W = level.width, H = level.height;
  const float* const n[3] = {normals.plane(0), normals.plane(1),
                             normals.plane(2)};
  const float* img_h = image_weight_.plane(0);
  const float* img_v = image_weight_.plane(1);
  float* w_h = level.edge_weight.plane(0);
  float* w_v = level.edge_weight.plane(1);
  const GuidanceTerms terms = terms_;
  const GuidancePenaltyTerms psi(terms.scale, terms.huber_eps);
  const float* k_h = link_gain_.plane(0);
  const float* k_v = link_gain_.plane(1);
  double* sums = row_sums_.data();
#pragma omp parallel for num_threads(threads) schedule(static)
  for (int y = 0; y < H; ++y) {
    const std::size_t row = static_cast<std::size_t>(y) * W;
    const float* n_row[3] = {n[0] + row, n[1] + row, n[2] + row};
    double correction = guidedRow(W - 1, 1, n_row[0], n_row[1], n_row[2],
                                  img_h + row, k_h + row, w_h + row, psi);
    outerLinks(1, img_h + row + W - 1, w_h + row + W - 1, terms.mu);
    if (y + 1 < H) {
      correction +=
          guidedRow(W, static_cast<std::size_t>(W), n_row[0], n_row[1],
                    n_row[2], img_v + row, k_v + row, w_v + row, psi);
    } else {
      outerLinks(W, img_v + row, w_v + row, terms.mu);
    }
    sums[y] = correction;
  }
  // Rows added in order: the same sum for any thread count.
  double total = 0.0;
  for (int y = 0; y < H; ++y) total += sums[y];
  return total;
}

void DynamicGuidance::end() {
  if (level_ == nullptr) return;
  const std::size_t values = 2 * level_->edge_weight.pixelCount();
  std::copy(image_weight_.data(), image_weight_.data() + values,
            level_->edge_weight.data());
  level_ = nullptr;
}

std::size_t DynamicGuidance::bytesHeld() const {
  return image_weight_.bytesHeld() + link_gain_.bytesHeld() +
         internal::bytesHeld(row_sums_) + internal::bytesHeld(observed_);
}

}  // namespace internal
}  // namespace normal_fusion
