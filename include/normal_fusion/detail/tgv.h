// The second-order smoothness term (SolverSettings::tgv_alpha0): total
// generalized variation of order 2 on the normal field (Bredies, Kunisch,
// Pock 2010), on the reference backend. docs/method.md, "Second-order
// smoothness", states the energy and the iteration.
#pragma once

#include "normal_fusion/detail/kernel_backend.h"
#include "normal_fusion/detail/solver_internal.h"

namespace normal_fusion {
namespace internal {

namespace tgv {
/// Symmetrized gradient E v, per component: e_hh = D_h^- v_h (x in
/// [1, W-2], else 0), e_vv = D_v^- v_v (y in [1, H-2]), e_hv = (D_v^+ v_h +
/// D_h^+ v_v) / 2 (x < W-1 and y < H-1): the differences of v between the
/// links it lives on.
void symmetrizedGradient(const PlanarImage& v_h, const PlanarImage& v_v,
                         PlanarImage& e_hh, PlanarImage& e_vv,
                         PlanarImage& e_hv);
/// Its negative adjoint under <e, r> = sum e_hh r_hh + e_vv r_vv +
/// 2 e_hv r_hv: <E v, r> = -<v, div r> for every v that is 0 on the last
/// column (v_h) and row (v_v); div_h is 0 on the last column, div_v on the
/// last row.
void symmetrizedDivergence(const PlanarImage& r_hh, const PlanarImage& r_vv,
                           const PlanarImage& r_hv, PlanarImage& div_h,
                           PlanarImage& div_v);
/// |e(x)| = sqrt(sum_c e_hh^2 + e_vv^2 + 2 e_hv^2) at pixel i.
double symmetricNorm(const PlanarImage& e_hh, const PlanarImage& e_vv,
                     const PlanarImage& e_hv, std::size_t i);
/// r <- clamp_alpha0(r + sigma e) per pixel, in the norm of symmetricNorm().
void proxSymmetricDual(const PlanarImage& e_hh, const PlanarImage& e_vv,
                       const PlanarImage& e_hv, float sigma, float alpha0,
                       PlanarImage& r_hh, PlanarImage& r_vv, PlanarImage& r_hv);
/// v_d <- v_d + tau_v (p_d + div_d r), vbar_d <- 2 v_d - v_d,old; v_h stays
/// 0 on the last column, v_v on the last row.
void primalStepV(const PlanarImage& p_h, const PlanarImage& p_v,
                 const PlanarImage& div_h, const PlanarImage& div_v,
                 float tau_v, TgvState& t);
}  // namespace tgv

/// `iterations` Chambolle-Pock iterations of the tangent-plane problem with
/// the second-order term, in the variables (n, v); as runInnerReference()
/// otherwise (the same cancel contract).
bool runInnerTgvReference(const PreparedLevel& level, const InnerParams& params,
                          IterationState& state, int iterations);

/// E(n, v) = data(n) + sum_x sum_d w_d huber_eps(|grad_d n - v_d|) +
/// alpha0 sum_x |E v(x)|, v = tgv.v_h, tgv.v_v (double accumulation).
double tgvEnergy(const PreparedLevel& level, double huber_eps,
                 DataPenalty penalty, double alpha0, const TgvState& tgv,
                 const PlanarImage& normals, int num_threads);

/// The automatic (or explicit) steps of (n, v, p, r) from the first-order
/// ones of SolverImpl::stepSizes(): with diagonal preconditioning sigma_p =
/// 1/3, tau_v = 1 / (3 + sqrt 2), sigma_r = 1 / (2 sqrt 2), times `balance`
/// as the others; else tau_v = tau and sigma_r = sigma.
void setTgvSteps(double alpha0, bool preconditioned, double balance,
                 InnerParams& params);

/// The reference backend with the second-order term in the whole-image
/// iterations and E; the warm start's local refinement stays first order
/// (the reference backend's).
const KernelBackend& tgvReferenceBackend();

}  // namespace internal
}  // namespace normal_fusion
