// The second-order smoothness term on the reference backend: the
// symmetrized gradient of v and its adjoint, the proxes of r and the step of
// v, the whole iteration in (n, v) and the energy E(n, v), each step of
// docs/method.md ("Second-order smoothness") one plain function.
#include <cmath>

#include "normal_fusion/detail/tgv.h"

namespace normal_fusion {
namespace internal {

void TgvState::reset(int width, int height) {
  for (PlanarImage* image : {&v_h, &v_v, &vbar_h, &vbar_v, &r_hh, &r_vv, &r_hv,
                             &e_hh, &e_vv, &e_hv, &div_h, &div_v}) {
    image->resizeKeepingCapacity(width, height, 3);
  }
  for (PlanarImage* image :
       {&v_h, &v_v, &vbar_h, &vbar_v, &r_hh, &r_vv, &r_hv}) {
    image->fill(0.0f);
  }
}

void TgvState::release() { *this = TgvState(); }

std::size_t TgvState::bytesHeld() const {
  std::size_t bytes = 0;
  for (const PlanarImage* image :
       {&v_h, &v_v, &vbar_h, &vbar_v, &r_hh, &r_vv, &r_hv, &e_hh, &e_vv, &e_hv,
        &div_h, &div_v}) {
    bytes += image->bytesHeld();
  }
  return bytes;
}

namespace {

/// The three entries of E v at component c of pixel (x, y)
/// (symmetrizedGradient()), in T = float (the iteration) or double (the
/// energy).
template <typename T>
void symmetrizedGradientAt(const PlanarImage& v_h, const PlanarImage& v_v,
                           int c, int y, int x, T e[3]) {
  const int W = v_h.width(), H = v_h.height();
  e[0] =
      x >= 1 && x + 1 < W ? T(v_h.at(c, y, x)) - T(v_h.at(c, y, x - 1)) : T(0);
  e[1] =
      y >= 1 && y + 1 < H ? T(v_v.at(c, y, x)) - T(v_v.at(c, y - 1, x)) : T(0);
  e[2] = x + 1 < W && y + 1 < H
             ? T(0.5) * ((T(v_h.at(c, y + 1, x)) - T(v_h.at(c, y, x))) +
                         (T(v_v.at(c, y, x + 1)) - T(v_v.at(c, y, x))))
             : T(0);
}

}  // namespace

namespace tgv {

void symmetrizedGradient(const PlanarImage& v_h, const PlanarImage& v_v,
                         PlanarImage& e_hh, PlanarImage& e_vv,
                         PlanarImage& e_hv) {
  const int W = v_h.width(), H = v_h.height();
  for (int c = 0; c < 3; ++c) {
    for (int y = 0; y < H; ++y) {
      for (int x = 0; x < W; ++x) {
        float e[3];
        symmetrizedGradientAt(v_h, v_v, c, y, x, e);
        e_hh.at(c, y, x) = e[0];
        e_vv.at(c, y, x) = e[1];
        e_hv.at(c, y, x) = e[2];
      }
    }
  }
}

void symmetrizedDivergence(const PlanarImage& r_hh, const PlanarImage& r_vv,
                           const PlanarImage& r_hv, PlanarImage& div_h,
                           PlanarImage& div_v) {
  const int W = r_hh.width(), H = r_hh.height();
  for (int c = 0; c < 3; ++c) {
    for (int y = 0; y < H; ++y) {
      for (int x = 0; x < W; ++x) {
        // div_h = D_h^+ r_hh + D_v^- r_hv, each read where E writes it.
        float h = 0.0f;
        if (x + 1 < W) {
          const float hh_right = x + 2 < W ? r_hh.at(c, y, x + 1) : 0.0f;
          const float hh_here = x >= 1 ? r_hh.at(c, y, x) : 0.0f;
          const float hv_here = y + 1 < H ? r_hv.at(c, y, x) : 0.0f;
          const float hv_up = y >= 1 ? r_hv.at(c, y - 1, x) : 0.0f;
          h = (hh_right - hh_here) + (hv_here - hv_up);
        }
        // div_v = D_v^+ r_vv + D_h^- r_hv.
        float v = 0.0f;
        if (y + 1 < H) {
          const float vv_down = y + 2 < H ? r_vv.at(c, y + 1, x) : 0.0f;
          const float vv_here = y >= 1 ? r_vv.at(c, y, x) : 0.0f;
          const float hv_here = x + 1 < W ? r_hv.at(c, y, x) : 0.0f;
          const float hv_left = x >= 1 ? r_hv.at(c, y, x - 1) : 0.0f;
          v = (vv_down - vv_here) + (hv_here - hv_left);
        }
        div_h.at(c, y, x) = h;
        div_v.at(c, y, x) = v;
      }
    }
  }
}

double symmetricNorm(const PlanarImage& e_hh, const PlanarImage& e_vv,
                     const PlanarImage& e_hv, std::size_t i) {
  double sum = 0.0;
  for (int c = 0; c < 3; ++c) {
    const double hh = e_hh.plane(c)[i], vv = e_vv.plane(c)[i],
                 hv = e_hv.plane(c)[i];
    sum += hh * hh + vv * vv + 2.0 * hv * hv;
  }
  return std::sqrt(sum);
}

void proxSymmetricDual(const PlanarImage& e_hh, const PlanarImage& e_vv,
                       const PlanarImage& e_hv, float sigma, float alpha0,
                       PlanarImage& r_hh, PlanarImage& r_vv,
                       PlanarImage& r_hv) {
  const std::size_t N = r_hh.pixelCount();
  for (std::size_t i = 0; i < N; ++i) {
    // u = r + sigma E vbar.
    for (int c = 0; c < 3; ++c) {
      r_hh.plane(c)[i] += sigma * e_hh.plane(c)[i];
      r_vv.plane(c)[i] += sigma * e_vv.plane(c)[i];
      r_hv.plane(c)[i] += sigma * e_hv.plane(c)[i];
    }
    // r = clamp_alpha0(u): the prox of sigma (alpha0 |.|)^*.
    const double len = symmetricNorm(r_hh, r_vv, r_hv, i);
    const float scale =
        !(alpha0 > 0.0f)
            ? 0.0f
            : (len > alpha0 ? static_cast<float>(alpha0 / len) : 1.0f);
    if (scale == 1.0f) continue;
    for (int c = 0; c < 3; ++c) {
      r_hh.plane(c)[i] *= scale;
      r_vv.plane(c)[i] *= scale;
      r_hv.plane(c)[i] *= scale;
    }
  }
}

void primalStepV(const PlanarImage& p_h, const PlanarImage& p_v,
                 const PlanarImage& div_h, const PlanarImage& div_v,
                 float tau_v, TgvState& t) {
  const int W = p_h.width(), H = p_h.height();
  for (int c = 0; c < 3; ++c) {
    for (int y = 0; y < H; ++y) {
      for (int x = 0; x < W; ++x) {
        // v_h <- v_h + tau_v (p_h + div_h r); 0 where no link is.
        const float h_old = t.v_h.at(c, y, x);
        const float h =
            x + 1 < W ? h_old + tau_v * (p_h.at(c, y, x) + div_h.at(c, y, x))
                      : 0.0f;
        t.v_h.at(c, y, x) = h;
        t.vbar_h.at(c, y, x) = 2.0f * h - h_old;
        const float v_old = t.v_v.at(c, y, x);
        const float v =
            y + 1 < H ? v_old + tau_v * (p_v.at(c, y, x) + div_v.at(c, y, x))
                      : 0.0f;
        t.v_v.at(c, y, x) = v;
        t.vbar_v.at(c, y, x) = 2.0f * v - v_old;
      }
    }
  }
}

}  // namespace tgv

bool runInnerTgvReference(const PreparedLevel& level, const InnerParams& params,
                          IterationState& s, int iterations) {
  const std::size_t N = s.n.pixelCount();
  TgvState& t = s.tgv;
  for (PlanarImage* image : {&s.grad_h, &s.grad_v, &s.div, &s.q_sum}) {
    image->resizeKeepingCapacity(s.n.width(), s.n.height(), 3);
  }
  for (int it = 0; it < iterations; ++it) {
    if (stopRequested(params.cancel)) return false;
    // p_d <- prox(p_d + sigma (grad_d nbar - vbar_d)).
    reference::gradient(s.nbar, s.grad_h, s.grad_v);
    for (int c = 0; c < 3; ++c) {
      for (std::size_t i = 0; i < N; ++i) {
        s.grad_h.plane(c)[i] -= t.vbar_h.plane(c)[i];
        s.grad_v.plane(c)[i] -= t.vbar_v.plane(c)[i];
      }
    }
    reference::proxHuberDual(s.p_h, s.grad_h, level.edge_weight.plane(0),
                             params.sigma, params.huber_eps);
    reference::proxHuberDual(s.p_v, s.grad_v, level.edge_weight.plane(1),
                             params.sigma, params.huber_eps);
    // r <- clamp_alpha0(r + sigma_r E vbar).
    tgv::symmetrizedGradient(t.vbar_h, t.vbar_v, t.e_hh, t.e_vv, t.e_hv);
    tgv::proxSymmetricDual(t.e_hh, t.e_vv, t.e_hv, params.tgv.sigma_r,
                           params.tgv.alpha0, t.r_hh, t.r_vv, t.r_hv);
    // q_l <- prox(q_l + sigma (nbar - f_l)), as the first-order iteration.
    s.q_sum.fill(0.0f);
    for (int l = 0; l < level.num_inputs; ++l) {
      reference::proxDataDual(
          s.q[l], s.nbar, level.data[l], level.data_weight[l].plane(0),
          level.data_huber ? level.data_eps[l].plane(0) : nullptr,
          params.sigma_data, params.penalty);
      for (int c = 0; c < 3; ++c) {
        for (std::size_t i = 0; i < N; ++i) {
          s.q_sum.plane(c)[i] += s.q[l].plane(c)[i];
        }
      }
    }
    // n <- Proj_C(n + tau (div p - sum q)), nbar <- 2 n - n_old.
    reference::divergence(s.p_h, s.p_v, s.div);
    reference::primalStep(level, params, s.div, s.q_sum, s.n0, s.n, s.nbar);
    // v_d <- v_d + tau_v (p_d + div_d r), vbar_d <- 2 v_d - v_d,old.
    tgv::symmetrizedDivergence(t.r_hh, t.r_vv, t.r_hv, t.div_h, t.div_v);
    tgv::primalStepV(s.p_h, s.p_v, t.div_h, t.div_v, params.tgv.tau_v, t);
  }
  return true;
}

double tgvEnergy(const PreparedLevel& level, double huber_eps,
                 DataPenalty penalty, double alpha0, const TgvState& tgv,
                 const PlanarImage& normals, int num_threads) {
  const int W = level.width, H = level.height;
  double total = 0.0;
#pragma omp parallel for num_threads(num_threads) reduction(+ : total) schedule(static)
  for (int y = 0; y < H; ++y) {
    double row_sum = 0.0;
    for (int x = 0; x < W; ++x) {
      const std::size_t i = static_cast<std::size_t>(y) * W + x;
      const double n[3] = {normals.at(0, y, x), normals.at(1, y, x),
                           normals.at(2, y, x)};
      // Data terms: sum_l c_l phi(n - f_l).
      row_sum += dataEnergyAt(level, penalty, i, n);
      // First part: w_d huber(|grad_d n - v_d|) on the links.
      double g2_h = 0.0, g2_v = 0.0, e2 = 0.0;
      for (int c = 0; c < 3; ++c) {
        if (x + 1 < W) {
          const double g = normals.at(c, y, x + 1) - n[c] - tgv.v_h.at(c, y, x);
          g2_h += g * g;
        }
        if (y + 1 < H) {
          const double g = normals.at(c, y + 1, x) - n[c] - tgv.v_v.at(c, y, x);
          g2_v += g * g;
        }
        // Second part: alpha0 |E v|.
        double e[3];
        symmetrizedGradientAt(tgv.v_h, tgv.v_v, c, y, x, e);
        e2 += e[0] * e[0] + e[1] * e[1] + 2.0 * e[2] * e[2];
      }
      if (x + 1 < W) {
        row_sum += level.edge_weight.at(0, y, x) *
                   huberPenalty(std::sqrt(g2_h), huber_eps);
      }
      if (y + 1 < H) {
        row_sum += level.edge_weight.at(1, y, x) *
                   huberPenalty(std::sqrt(g2_v), huber_eps);
      }
      row_sum += alpha0 * std::sqrt(e2);
    }
    total += row_sum;
  }
  return total;
}

void setTgvSteps(double alpha0, bool preconditioned, double balance,
                 InnerParams& params) {
  params.tgv = TgvParams();
  if (!(alpha0 > 0.0)) return;
  params.tgv.alpha0 = static_cast<float>(alpha0);
  if (!preconditioned) {
    // Scalar steps: tau sigma (12 + L) < 1 holds for v and r as for n, p.
    params.tgv.tau_v = params.tau;
    params.tgv.sigma_r = params.sigma;
    return;
  }
  // Diagonal preconditioning (Pock & Chambolle 2011, alpha = 1): the rows of
  // p now hold grad (2) and -v (1); the columns of v hold -I (1), E_hh (2)
  // and E_hv (2 / sqrt 2, in the orthonormal coordinates sqrt 2 r_hv); the
  // rows of r at most 4 / sqrt 2 (one step for all of r, as its ball couples
  // them).
  const double sqrt2 = std::sqrt(2.0);
  params.sigma = static_cast<float>(1.0 / 3.0 / balance);
  params.tgv.tau_v = static_cast<float>(balance / (3.0 + sqrt2));
  params.tgv.sigma_r = static_cast<float>(1.0 / (2.0 * sqrt2) / balance);
}

}  // namespace internal
}  // namespace normal_fusion
