// The variables and step sizes of the second-order smoothness term (total
// generalized variation of order 2, SolverSettings::tgv_alpha0): the
// auxiliary field v and the dual r of its symmetrized gradient
// (docs/method.md, "Second-order smoothness"). Kept apart from
// solver_internal.h so that the iteration state can hold them.
#pragma once

#include <cstddef>

#include "normal_fusion/types.h"

namespace normal_fusion {
namespace internal {

/// Squared norm bound of the operator (n, v) -> (grad n - v, E v) (Bredies
/// 2014: (17 + sqrt(33)) / 2 < 12); each data term adds 1, as for grad.
constexpr double kTgvOperatorNorm2 = 12.0;

/// Model constant and steps of the second-order term (alpha0 = 0: off).
struct TgvParams {
  float alpha0 = 0.0f;   ///< weight of |E v|
  float tau_v = 0.0f;    ///< primal step of v
  float sigma_r = 0.0f;  ///< dual step of r
};

/// Variables of the second-order term at one level; empty while it is off.
/// v_d(x) approximates grad_d n(x) on the links (v_h on the last column and
/// v_v on the last row are held at 0, as grad is there).
struct TgvState {
  PlanarImage v_h, v_v;        ///< auxiliary field, 3 planes each
  PlanarImage vbar_h, vbar_v;  ///< over-relaxed v
  /// Dual of E v: components hh, vv and hv (the off-diagonal entry, counted
  /// twice in every norm and inner product), 3 planes each.
  PlanarImage r_hh, r_vv, r_hv;
  /// Scratch: E vbar (e_*) and the divergence of r (div_h, div_v).
  PlanarImage e_hh, e_vv, e_hv, div_h, div_v;

  /// Sizes every buffer for a W x H level and sets v = vbar = r = 0.
  void reset(int width, int height);
  /// Frees every buffer (the term is off).
  void release();
  bool empty() const { return v_h.pixelCount() == 0; }
  /// Bytes of memory its buffers hold.
  std::size_t bytesHeld() const;
};

}  // namespace internal
}  // namespace normal_fusion
