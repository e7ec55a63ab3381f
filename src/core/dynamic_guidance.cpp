// Dynamic guidance of the edge weights (docs/method.md): each link's weight
// w = w_img + mu (1 - w_img) phi(|n_p - n_q| / s) from the outer iterate, and
// the guidance's share of the energy that the weighted energy lacks.
#include "normal_fusion/detail/dynamic_guidance.h"

#include <algorithm>
#include <cmath>

namespace normal_fusion {
namespace internal {
namespace {

constexpr double kPi = 3.14159265358979323846;

/// The guided weight of one link of image weight `w_img` whose normals are
/// `a` and `b` (planes of three components, index ia and ib); adds the
/// link's share of E to `correction`.
inline float guidedLink(const GuidanceTerms& terms, float w_img,
                        const float* const n[3], std::size_t ia, std::size_t ib,
                        double& correction) {
  const float k = terms.mu * std::max(0.0f, 1.0f - w_img);
  if (k <= 0.0f) return w_img;
  const float d0 = n[0][ib] - n[0][ia];
  const float d1 = n[1][ib] - n[1][ia];
  const float d2 = n[2][ib] - n[2][ia];
  const float chord = std::sqrt(d0 * d0 + d1 * d1 + d2 * d2);
  const float phi = guidanceKernel(chord, terms.scale);
  const double eps = terms.huber_eps;
  correction += k * (guidancePenalty(chord, terms.scale, eps) -
                     static_cast<double>(phi) * huberPenalty(chord, eps));
  return w_img + k * phi;
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
                            const GuidanceTerms& terms) {
  level_ = &level;
  terms_ = terms;
  // Sized for the finest level first, so that the pyramid's smaller levels
  // and the frames after reuse the buffers.
  image_weight_.resize(finest.width, finest.height, 2);
  image_weight_.resizeKeepingCapacity(level.width, level.height, 2);
  // A much larger frame's buffers are given back (PlanarImage's rule).
  releaseIfOversized(row_sums_, static_cast<std::size_t>(finest.height));
  releaseIfOversized(observed_, finest.edge_weight.pixelCount());
  if (row_sums_.size() < static_cast<std::size_t>(finest.height)) {
    row_sums_.resize(finest.height);
  }
  const std::size_t values = 2 * level.edge_weight.pixelCount();
  std::copy(level.edge_weight.data(), level.edge_weight.data() + values,
            image_weight_.data());
  const std::size_t pixels = level.edge_weight.pixelCount();
  if (observed_.capacity() < finest.edge_weight.pixelCount()) {
    observed_.reserve(finest.edge_weight.pixelCount());
  }
  observed_.assign(pixels, 0);
  for (int l = 0; l < level.num_inputs; ++l) {
    const float* c = level.data_weight[l].plane(0);
    for (std::size_t i = 0; i < pixels; ++i) {
      if (c[i] > 0.0f) observed_[i] = 1;
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
  const unsigned char* observed = observed_.data();
  double* sums = row_sums_.data();
#pragma omp parallel for num_threads(threads) schedule(static)
  for (int y = 0; y < H; ++y) {
    double correction = 0.0;
    const std::size_t row = static_cast<std::size_t>(y) * W;
    for (int x = 0; x < W; ++x) {
      const std::size_t i = row + x;
      // The links past the last column and row couple nothing (d = 0).
      // Links with an unobserved end keep w_img (mu = 0 there).
      if (x + 1 >= W) {
        w_h[i] = img_h[i] + terms.mu * std::max(0.0f, 1.0f - img_h[i]);
      } else if (observed[i] && observed[i + 1]) {
        w_h[i] = guidedLink(terms, img_h[i], n, i, i + 1, correction);
      } else {
        w_h[i] = img_h[i];
      }
      if (y + 1 >= H) {
        w_v[i] = img_v[i] + terms.mu * std::max(0.0f, 1.0f - img_v[i]);
      } else if (observed[i] && observed[i + W]) {
        w_v[i] = guidedLink(terms, img_v[i], n, i, i + W, correction);
      } else {
        w_v[i] = img_v[i];
      }
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
  return image_weight_.bytesHeld() + internal::bytesHeld(row_sums_) +
         internal::bytesHeld(observed_);
}

}  // namespace internal
}  // namespace normal_fusion
