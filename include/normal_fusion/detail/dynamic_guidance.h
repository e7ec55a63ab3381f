// Dynamic guidance of the edge weights (docs/method.md): the weight of each
// link combines the image's weight with one from the outer iterate's own
// normal differences, recomputed at every accepted outer step.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
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

/// exp(t) for t <= 0, branch-free so that a loop of it vectorises:
/// exp(t) = 2^k exp(r), k = round(t / ln 2), r = t - k ln 2 in
/// [-ln 2 / 2, ln 2 / 2] (ln 2 split in two for exactness), exp(r) by its
/// Taylor polynomial to r^11, 2^k built in the exponent bits. Relative error
/// below 1e-14; t below -700 is clamped there.
inline double expNonPositive(double t) {
  constexpr double kLog2e = 1.4426950408889634074;
  constexpr double kLn2Hi = 6.93147180369123816490e-01;
  constexpr double kLn2Lo = 1.90821492927058770002e-10;
  t = std::max(t, -700.0);
  // k = round(t / ln 2) for t <= 0 (truncation of t / ln 2 - 0.5).
  const int k = static_cast<int>(t * kLog2e - 0.5);
  const double kd = static_cast<double>(k);
  const double r = (t - kd * kLn2Hi) - kd * kLn2Lo;
  double p = 1.0 / 39916800.0;
  p = p * r + 1.0 / 3628800.0;
  p = p * r + 1.0 / 362880.0;
  p = p * r + 1.0 / 40320.0;
  p = p * r + 1.0 / 5040.0;
  p = p * r + 1.0 / 720.0;
  p = p * r + 1.0 / 120.0;
  p = p * r + 1.0 / 24.0;
  p = p * r + 1.0 / 6.0;
  p = p * r + 0.5;
  p = p * r + 1.0;
  p = p * r + 1.0;
  const std::int64_t bits = static_cast<std::int64_t>(k + 1023) << 52;
  double two_k;
  std::memcpy(&two_k, &bits, sizeof(two_k));
  return p * two_k;
}

/// erf(x) for x >= 0 from e = exp(-x^2), which the kernel has already
/// computed (Abramowitz and Stegun 7.1.26, absolute error below 1.5e-7): the
/// reweighting then needs no erf call per link.
inline double erfFromGaussian(double x, double e) {
  const double u = 1.0 / (1.0 + 0.3275911 * x);
  const double poly =
      u * (0.254829592 +
           u * (-0.284496736 +
                u * (1.421413741 + u * (-1.453152027 + u * 1.061405429))));
  return 1.0 - poly * e;
}

/// Psi_s(t) of guidancePenalty and a link's share of the guidance's
/// correction, Psi_s(t) - phi(t) huber_eps(t), from e = phi(t) =
/// exp(-(t / s)^2), with the constants of one (s, eps) pair precomputed:
/// within 2.7e-7 s of the exact values (the erf approximation's error at t
/// and at eps), without erf or expm1 calls and
/// without branches (the reweighting's loops vectorise).
struct GuidancePenaltyTerms {
  double scale = 1.0, eps = 0.0;
  double half_sqrt_pi_scale = 0.0;  ///< s sqrt(pi) / 2
  double quadratic = 0.0;           ///< s^2 / (2 eps) (eps > 0)
  double psi_at_eps = 0.0;          ///< Psi_s(eps), exact
  double erf_at_eps = 0.0;          ///< erfFromGaussian at eps / s

  GuidancePenaltyTerms(double scale_in, double eps_in)
      : scale(scale_in), eps(std::max(eps_in, 0.0)) {
    constexpr double kHalfSqrtPi = 0.88622692545275801365;
    half_sqrt_pi_scale = kHalfSqrtPi * scale;
    if (eps > 0.0) {
      quadratic = scale * scale / (2.0 * eps);
      psi_at_eps = guidancePenalty(eps, scale, eps);
      const double x = eps / scale;
      erf_at_eps = erfFromGaussian(x, std::exp(-x * x));
    }
  }

  /// Psi_s(t) given e = exp(-(t / s)^2).
  double penalty(double t, double e) const {
    const double x = t / scale;
    // Quadratic zone: -s^2 / (2 eps) (e - 1); beyond eps: the erf part.
    const double inner = quadratic * (1.0 - e);
    const double outer =
        psi_at_eps + half_sqrt_pi_scale * (erfFromGaussian(x, e) - erf_at_eps);
    return t <= eps ? inner : outer;
  }

  /// Psi_s(t) - phi(t) huber_eps(t) given e = phi(t) (>= 0).
  double correction(double t, double e) const {
    const double x = t / scale;
    // Quadratic zone: s^2 / (2 eps) (1 - e (1 + x^2)).
    const double inner = quadratic * (1.0 - e * (1.0 + x * x));
    const double outer =
        psi_at_eps + half_sqrt_pi_scale * (erfFromGaussian(x, e) - erf_at_eps) -
        e * (t - 0.5 * eps);
    return t <= eps ? inner : outer;
  }
};

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
             const GuidanceTerms& terms, int threads = 1);
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
  PlanarImage link_gain_;     ///< k = mu (1 - w_img) per link, 0: kept
  /// Per pixel: some input observes it (c_l > 0). A link with an
  /// unobserved end keeps w_img: there the normals are the smoothing's own
  /// fill-in, and only the image tells where it may bend.
  std::vector<float> observed_;   ///< begin(): 1 where some input has weight
  std::vector<double> row_sums_;  ///< reweight(): one partial sum per row
};

}  // namespace internal
}  // namespace normal_fusion
