// The reference backend with the second-order term (SolverSettings::
// tgv_alpha0 > 0; the solver takes it for either backend setting): the
// whole-image iterations and E in (n, v) (kernels_tgv_reference.cpp); the
// warm start's local refinement is the reference backend's, first order,
// with its own energy, which it keeps monotone as without the term.
#include "normal_fusion/detail/tgv.h"

namespace normal_fusion {
namespace internal {
namespace {

class TgvReferenceBackend final : public KernelBackend {
 public:
  double energy(const PreparedLevel& level, const EnergyTerms& terms,
                const PlanarImage& normals, int threads) const override {
    if (terms.tgv_alpha0 > 0.0 && terms.tgv != nullptr &&
        terms.tgv->v_h.sameSize(normals)) {
      return tgvEnergy(level, terms.huber_eps, terms.penalty, terms.tgv_alpha0,
                       *terms.tgv, normals, threads);
    }
    return base().energy(level, terms, normals, threads);
  }

  bool runInner(const PreparedLevel& level, const InnerParams& params,
                IterationState& state, int iterations) const override {
    if (params.tgv.alpha0 > 0.0f && state.tgv.v_h.sameSize(state.n)) {
      return runInnerTgvReference(level, params, state, iterations);
    }
    return base().runInner(level, params, state, iterations);
  }

  double beginRefinement(const PreparedLevel& level, const EnergyTerms& terms,
                         IterationState& state, RefinementBuffers& refine,
                         int threads) const override {
    return base().beginRefinement(level, terms, state, refine, threads);
  }
  bool runRefinement(const PreparedLevel& level, const InnerParams& params,
                     IterationState& state, RefinementBuffers& refine,
                     int iterations) const override {
    return base().runRefinement(level, params, state, refine, iterations);
  }
  double candidateEnergy(const PreparedLevel& level, const EnergyTerms& terms,
                         IterationState& state, RefinementBuffers& refine,
                         int threads) const override {
    return base().candidateEnergy(level, terms, state, refine, threads);
  }
  void acceptCandidate(IterationState& state,
                       RefinementBuffers& refine) const override {
    base().acceptCandidate(state, refine);
  }
  void rejectCandidate(IterationState& state,
                       RefinementBuffers& refine) const override {
    base().rejectCandidate(state, refine);
  }
  void endRefinement(IterationState& state, RefinementBuffers& refine,
                     int threads) const override {
    base().endRefinement(state, refine, threads);
  }
  bool measuresRefinementThreads() const override {
    return base().measuresRefinementThreads();
  }

 private:
  static const KernelBackend& base() { return referenceBackend(); }
};

}  // namespace

const KernelBackend& tgvReferenceBackend() {
  static const TgvReferenceBackend backend;
  return backend;
}

}  // namespace internal
}  // namespace normal_fusion
