// The operations that the solver's outer loop asks of a kernel backend
// (SolverSettings::backend): the inner Chambolle-Pock iterations of a level,
// the energy E, and the steps of a warm start's local refinement. The
// reference backend (backend_reference.cpp) writes each step of the maths as
// a plain function; the fast one (backend_fast.cpp) fuses and vectorises
// them. Calls are per level or per chunk of iterations, never per pixel.
#pragma once

#include <vector>

#include "normal_fusion/detail/solver_internal.h"

namespace normal_fusion {
namespace internal {

/// The buffers of a warm start's local refinement, kept across frames.
struct RefinementBuffers {
  ActiveSet active;        ///< the pixels refined and their links
  ActiveBuffers gathered;  ///< fast backend: their variables, gathered
  /// Reference backend: the iterate at the active pixels while n holds its
  /// normalized candidate (restored when the candidate is rejected).
  std::vector<float> iterate_saved;
};

/// Model constants of the energy E of docs/algorithm.md.
struct EnergyTerms {
  double huber_eps = 0.0;
  DataPenalty penalty = DataPenalty::kL2;
  /// The second-order term: its weight and the v that E(n, v) is taken at.
  double tgv_alpha0 = 0.0;
  const TgvState* tgv = nullptr;
};

class KernelBackend {
 public:
  virtual ~KernelBackend() = default;

  /// E(n) on a level.
  virtual double energy(const PreparedLevel& level, const EnergyTerms& terms,
                        const PlanarImage& normals, int threads) const = 0;

  /// `iterations` inner iterations on the tangent plane at state.n0; false
  /// when params.cancel stopped them (runInnerReference()).
  virtual bool runInner(const PreparedLevel& level, const InnerParams& params,
                        IterationState& state, int iterations) const = 0;

  // The local refinement on refine.active, every other pixel fixed: begin,
  // then steps of iterations, each closed by its candidate's energy and an
  // accept or a reject, then end.

  /// n = nbar = n0 on the active pixels; returns their terms of E at n0.
  virtual double beginRefinement(const PreparedLevel& level,
                                 const EnergyTerms& terms,
                                 IterationState& state,
                                 RefinementBuffers& refine,
                                 int threads) const = 0;
  /// `iterations` iterations on the active pixels (runInnerActive()).
  virtual bool runRefinement(const PreparedLevel& level,
                             const InnerParams& params, IterationState& state,
                             RefinementBuffers& refine,
                             int iterations) const = 0;
  /// The candidate n / |n| at the active pixels and its terms of E.
  virtual double candidateEnergy(const PreparedLevel& level,
                                 const EnergyTerms& terms,
                                 IterationState& state,
                                 RefinementBuffers& refine,
                                 int threads) const = 0;
  /// n0 <- the candidate; n = nbar = n0 (a new outer step).
  virtual void acceptCandidate(IterationState& state,
                               RefinementBuffers& refine) const = 0;
  /// The candidate is dropped: the iterations go on from their iterate.
  virtual void rejectCandidate(IterationState& state,
                               RefinementBuffers& refine) const = 0;
  /// n0 and the duals of the refinement written to `state`.
  virtual void endRefinement(IterationState& state, RefinementBuffers& refine,
                             int threads) const = 0;
  /// True when the refinement's cost is measured per thread count
  /// (RefineThreadChooser): its steps may run on one thread.
  virtual bool measuresRefinementThreads() const = 0;
};

/// The two backends (stateless singletons).
const KernelBackend& referenceBackend();
const KernelBackend& fastBackend();

/// The backend of SolverSettings::backend.
inline const KernelBackend& kernelBackend(SolverBackend kind) {
  return kind == SolverBackend::kReference ? referenceBackend() : fastBackend();
}

}  // namespace internal
}  // namespace normal_fusion
