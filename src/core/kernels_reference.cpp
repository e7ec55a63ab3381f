// Reference backend: the Chambolle-Pock iteration written step by step, one
// plain single-threaded function per operator. It is the oracle that the fast
// backend is tested against; keep it simple rather than fast.
#include <cmath>

#include "normal_fusion/detail/solver_internal.h"

namespace normal_fusion {
namespace internal {

bool IterationState::resize(int width, int height, int num_inputs,
                            const std::atomic<bool>* cancel) {
  for (PlanarImage* image : {&n0, &n, &nbar, &p_h, &p_v}) {
    if (stopRequested(cancel)) return false;
    image->resizeKeepingCapacity(width, height, 3);
  }
  q.resize(num_inputs);
  for (PlanarImage& q_l : q) {
    if (stopRequested(cancel)) return false;
    q_l.resizeKeepingCapacity(width, height, 3);
  }
  return true;
}

void IterationState::fit(int width, int height, int threads) {
  // Release only (allocating here would be memory the levels may not
  // need, and time a cancelled solve could not give back).
  const std::size_t values = static_cast<std::size_t>(3) * width * height;
  for (PlanarImage* image :
       {&n0, &n, &nbar, &p_h, &p_v, &grad_h, &grad_v, &div, &q_sum}) {
    releaseIfOversized(*image, values);
  }
  for (PlanarImage& q_l : q) releaseIfOversized(q_l, values);
  if (values < tgv.v_h.bytesHeld() / sizeof(float) / 4) tgv.release();
  // The fast backend's rows: three per thread.
  releaseIfOversized(row_scratch,
                     static_cast<std::size_t>(3) * width * threads);
}

std::size_t IterationState::bytesHeld() const {
  std::size_t bytes = 0;
  for (const PlanarImage* image :
       {&n0, &n, &nbar, &p_h, &p_v, &grad_h, &grad_v, &div, &q_sum}) {
    bytes += image->bytesHeld();
  }
  for (const PlanarImage& q_l : q) bytes += q_l.bytesHeld();
  return bytes + tgv.bytesHeld() + internal::bytesHeld(row_scratch) +
         internal::bytesHeld(progress);
}

namespace reference {

/// Forward differences with Neumann ends: grad_h n(x,y) = n(x+1,y) - n(x,y),
/// 0 on the last column; grad_v likewise down the rows.
void gradient(const PlanarImage& n, PlanarImage& grad_h, PlanarImage& grad_v) {
  const int W = n.width(), H = n.height();
  for (int c = 0; c < 3; ++c) {
    for (int y = 0; y < H; ++y) {
      for (int x = 0; x < W; ++x) {
        grad_h.at(c, y, x) = x + 1 < W ? n.at(c, y, x + 1) - n.at(c, y, x) : 0;
        grad_v.at(c, y, x) = y + 1 < H ? n.at(c, y + 1, x) - n.at(c, y, x) : 0;
      }
    }
  }
}

/// Divergence, the negative adjoint of gradient(): backward differences with
/// Dirichlet ends, div_h p(x) = p(x) - p(x-1), p(-1) = 0, p(W-1) read as 0.
void divergence(const PlanarImage& p_h, const PlanarImage& p_v,
                PlanarImage& div) {
  const int W = p_h.width(), H = p_h.height();
  for (int c = 0; c < 3; ++c) {
    for (int y = 0; y < H; ++y) {
      for (int x = 0; x < W; ++x) {
        const float h_here = x + 1 < W ? p_h.at(c, y, x) : 0.0f;
        const float h_left = x > 0 ? p_h.at(c, y, x - 1) : 0.0f;
        const float v_here = y + 1 < H ? p_v.at(c, y, x) : 0.0f;
        const float v_up = y > 0 ? p_v.at(c, y - 1, x) : 0.0f;
        div.at(c, y, x) = (h_here - h_left) + (v_here - v_up);
      }
    }
  }
}

/// The relaxed step (Condat 2013): x <- x_old + rho (x_hat - x_old) on the
/// three channels of v = x_hat; rho = 1 leaves x_hat as it is, bit for bit.
void relax(const float old[3], float rho, float v[3]) {
  if (rho == 1.0f) return;
  for (int c = 0; c < 3; ++c) v[c] = old[c] + rho * (v[c] - old[c]);
}

/// clamp_c(v) = v / max(1, |v| / c); c = 0 gives 0.
void clampVector(float v[3], float radius) {
  if (!(radius > 0.0f)) {
    v[0] = v[1] = v[2] = 0.0f;
    return;
  }
  const float len = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
  if (len > radius) {
    const float s = radius / len;
    v[0] *= s;
    v[1] *= s;
    v[2] *= s;
  }
}

/// p <- clamp_w(v / (1 + sigma eps / w)): the prox of sigma (w huber_eps)^*
/// at v = p + sigma grad nbar.
void huberDualProx(float v[3], float w, float sigma, float eps) {
  const float shrink = w > 0.0f ? 1.0f / (1.0f + sigma * eps / w) : 0.0f;
  for (int c = 0; c < 3; ++c) v[c] *= shrink;
  clampVector(v, w);
}

/// The prox of sigma F^*, F(z) = c phi(z - f), at v = q + sigma (nbar - f):
/// unsquared: clamp_c(v / (1 + sigma delta / c)) (Huber with threshold
///            delta; delta = 0: plain clamp);
/// squared:   v / (1 + sigma / c).
void dataDualProx(float v[3], float c_weight, float delta, float sigma,
                  DataPenalty penalty) {
  if (penalty == DataPenalty::kL2) {
    if (delta > 0.0f && c_weight > 0.0f) {
      for (int c = 0; c < 3; ++c) v[c] /= 1.0f + sigma * delta / c_weight;
    }
    clampVector(v, c_weight);
  } else {
    const float s = c_weight > 0.0f ? 1.0f / (1.0f + sigma / c_weight) : 0.0f;
    for (int c = 0; c < 3; ++c) v[c] *= s;
  }
}

/// Dual step of the weighted Huber term (prox of sigma (w huber_eps)^*):
/// p_hat = clamp_w((p + sigma grad nbar) / (1 + sigma eps / w)), then
/// p <- p + rho (p_hat - p).
void proxHuberDual(PlanarImage& p, const PlanarImage& grad, const float* weight,
                   float sigma, float eps, float rho) {
  const std::size_t N = p.pixelCount();
  for (std::size_t i = 0; i < N; ++i) {
    float v[3], old[3];
    for (int c = 0; c < 3; ++c) {
      old[c] = p.plane(c)[i];
      v[c] = old[c] + sigma * grad.plane(c)[i];
    }
    huberDualProx(v, weight[i], sigma, eps);
    relax(old, rho, v);
    for (int c = 0; c < 3; ++c) p.plane(c)[i] = v[c];
  }
}

/// Dual step of one data term (prox of sigma F_l^*, F_l(z) = c phi(z - f)):
/// q_hat = dataDualProx(q + sigma (nbar - f)), then q <- q + rho (q_hat - q).
void proxDataDual(PlanarImage& q, const PlanarImage& nbar, const PlanarImage& f,
                  const float* c_weight, const float* delta, float sigma,
                  DataPenalty penalty, float rho) {
  const std::size_t N = q.pixelCount();
  for (std::size_t i = 0; i < N; ++i) {
    float v[3], old[3];
    for (int c = 0; c < 3; ++c) {
      old[c] = q.plane(c)[i];
      v[c] = old[c] + sigma * (nbar.plane(c)[i] - f.plane(c)[i]);
    }
    dataDualProx(v, c_weight[i], delta != nullptr ? delta[i] : 0.0f, sigma,
                 penalty);
    relax(old, rho, v);
    for (int c = 0; c < 3; ++c) q.plane(c)[i] = v[c];
  }
}

/// Primal step: n_hat = Proj_C(n + tau (div p - sum_l q_l)), C the tangent
/// plane at n0 (intersected with n . r <= 0 in soft visibility mode); then
/// nbar <- 2 n_hat - n_old and n <- n_old + rho (n_hat - n_old) (n = n_hat
/// for rho = 1). The extrapolation uses n_hat: the relaxed iteration is
/// the plain one applied to the relaxed pair (n, p, q).
void primalStep(const PreparedLevel& level, const InnerParams& params,
                const PlanarImage& div, const PlanarImage& q_sum,
                const PlanarImage& n0, PlanarImage& n, PlanarImage& nbar) {
  const int W = n.width(), H = n.height();
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      float v[3], n0_px[3], r[3], n_old[3];
      for (int c = 0; c < 3; ++c) {
        n_old[c] = n.at(c, y, x);
        n0_px[c] = n0.at(c, y, x);
        v[c] = n_old[c] + params.tau * (div.at(c, y, x) - q_sum.at(c, y, x));
      }
      level.ray(x, y, r);
      projectTangentFeasible(n0_px, r, params.soft_visibility, v);
      for (int c = 0; c < 3; ++c) nbar.at(c, y, x) = 2.0f * v[c] - n_old[c];
      relax(n_old, params.relaxation, v);
      for (int c = 0; c < 3; ++c) n.at(c, y, x) = v[c];
    }
  }
}

}  // namespace reference

bool runInnerReference(const PreparedLevel& level, const InnerParams& params,
                       IterationState& s, int iterations) {
  const std::size_t N = s.n.pixelCount();
  // Scratch of the level's size (allocated once per size: the finest level
  // sets the capacity that the coarser ones reuse).
  for (PlanarImage* image : {&s.grad_h, &s.grad_v, &s.div, &s.q_sum}) {
    image->resizeKeepingCapacity(s.n.width(), s.n.height(), 3);
  }
  for (int it = 0; it < iterations; ++it) {
    // A stop request ends the run between iterations.
    if (stopRequested(params.cancel)) return false;
    // Dual ascent on the smoothness terms: p_d <- prox(p_d + sigma grad_d
    // nbar), relaxed by rho.
    reference::gradient(s.nbar, s.grad_h, s.grad_v);
    reference::proxHuberDual(s.p_h, s.grad_h, level.edge_weight.plane(0),
                             params.sigma, params.huber_eps, params.relaxation);
    reference::proxHuberDual(s.p_v, s.grad_v, level.edge_weight.plane(1),
                             params.sigma, params.huber_eps, params.relaxation);
    // Dual ascent on each data term: q_l <- prox(q_l + sigma (nbar - f_l)).
    s.q_sum.fill(0.0f);
    for (int l = 0; l < level.num_inputs; ++l) {
      reference::proxDataDual(
          s.q[l], s.nbar, level.data[l], level.data_weight[l].plane(0),
          level.data_huber ? level.data_eps[l].plane(0) : nullptr,
          params.sigma_data, params.penalty, params.relaxation);
      for (int c = 0; c < 3; ++c) {
        for (std::size_t i = 0; i < N; ++i) {
          s.q_sum.plane(c)[i] += s.q[l].plane(c)[i];
        }
      }
    }
    // Primal descent: n <- Proj_C(n + tau (div p - sum q)), over-relaxation.
    reference::divergence(s.p_h, s.p_v, s.div);
    reference::primalStep(level, params, s.div, s.q_sum, s.n0, s.n, s.nbar);
  }
  return true;
}

double energy(const PreparedLevel& level, double huber_eps, DataPenalty penalty,
              const PlanarImage& normals, int num_threads) {
  const int W = level.width, H = level.height;
  double total = 0.0;
#pragma omp parallel for num_threads(num_threads) reduction(+ : total) schedule(static)
  for (int y = 0; y < H; ++y) {
    double row_sum = 0.0;
    for (int x = 0; x < W; ++x) {
      const double n[3] = {normals.at(0, y, x), normals.at(1, y, x),
                           normals.at(2, y, x)};
      // Data terms: sum_l c_l phi(n - f_l).
      row_sum +=
          dataEnergyAt(level, penalty, static_cast<std::size_t>(y) * W + x, n);
      // Smoothness: w_h huber(grad_h n) + w_v huber(grad_v n).
      if (x + 1 < W) {
        double g2 = 0.0;
        for (int ch = 0; ch < 3; ++ch) {
          const double g = normals.at(ch, y, x + 1) - n[ch];
          g2 += g * g;
        }
        row_sum += level.edge_weight.at(0, y, x) *
                   huberPenalty(std::sqrt(g2), huber_eps);
      }
      if (y + 1 < H) {
        double g2 = 0.0;
        for (int ch = 0; ch < 3; ++ch) {
          const double g = normals.at(ch, y + 1, x) - n[ch];
          g2 += g * g;
        }
        row_sum += level.edge_weight.at(1, y, x) *
                   huberPenalty(std::sqrt(g2), huber_eps);
      }
    }
    total += row_sum;
  }
  return total;
}

}  // namespace internal
}  // namespace normal_fusion
