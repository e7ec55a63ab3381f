// Dynamic guidance of the edge weights (docs/method.md): the weight of each
// link combines the image's weight with one from the outer iterate's own
// normal differences, recomputed at every accepted outer step.
#pragma once

#include <cmath>
#include <vector>

#include "normal_fusion/detail/solver_internal.h"

namespace normal_fusion {
namespace internal {

/// Model constants of the dynamic guidance.
struct GuidanceTerms {
  float mu = 0.0f;         ///< SolverSettings::dynamic_guidance, in [0, 1]
  float scale = 1.0f;      ///< s: the chord of dynamic_guidance_deg
  float huber_eps = 0.0f;  ///< the smoothness term's Huber threshold
};

/// The terms of `settings`; mu = 0 when the guidance is off.
GuidanceTerms guidanceTerms(const SolverSettings& settings);

/// The normals' weight of a link whose normals differ by `chord`:
/// phi = exp(-(chord / s)^2) (Welsch).
inline float guidanceKernel(float chord, float scale) {
  const float x = chord / scale;
  return std::exp(-x * x);
}

/// Psi_s(t) = int_0^t phi(u) huber_eps'(u) du: the bounded penalty whose
/// derivative with respect to huber_eps(t) is phi(t), so that the guided
/// weight is its majorizer's weight (docs/method.md#the-energy).
inline double guidancePenalty(double t, double scale, double eps) {
  constexpr double kHalfSqrtPi = 0.88622692545275801365;
  const double s2 = scale * scale;
  if (eps <= 0.0) return scale * kHalfSqrtPi * std::erf(t / scale);
  if (t <= eps) return -s2 / (2.0 * eps) * std::expm1(-t * t / s2);
  return -s2 / (2.0 * eps) * std::expm1(-eps * eps / s2) +
         scale * kHalfSqrtPi * (std::erf(t / scale) - std::erf(eps / scale));
}

/// The guided weights of one level while its outer steps run. The level's
/// image weights w_img are kept at begin() and put back at end(); in
/// between, reweight() writes w = w_img + mu (1 - w_img) phi(|n_p - n_q|)
/// into level.edge_weight. Buffers keep their capacity (sized for the finest
/// level at the first begin()), so a stream allocates nothing here.
class DynamicGuidance {
 public:
  /// Keeps the image weights of `level` (`finest`: the solve's finest level,
  /// which the buffers are sized for).
  void begin(PreparedLevel& level, const PreparedLevel& finest,
             const GuidanceTerms& terms);
  /// The guided weights at `normals` (unit, the level's size) into the
  /// level's edge weights; returns the guidance's share of E that the
  /// weighted E lacks at `normals`: sum over links of mu (1 - w_img)
  /// (Psi(|d|) - phi(|d|) huber_eps(|d|)), >= 0.
  double reweight(const PlanarImage& normals, int threads);
  /// Puts the image weights back into the level.
  void end();
  /// Bytes of memory its buffers hold.
  std::size_t bytesHeld() const;

 private:
  PreparedLevel* level_ = nullptr;
  GuidanceTerms terms_;
  PlanarImage image_weight_;  ///< w_img of the level (planes h, v)
  /// Per pixel: some input observes it (c_l > 0). A link with an
  /// unobserved end keeps w_img: there the normals are the smoothing's own
  /// fill-in, and only the image tells where it may bend.
  std::vector<unsigned char> observed_;
  std::vector<double> row_sums_;  ///< reweight(): one partial sum per row
};

}  // namespace internal
}  // namespace normal_fusion
