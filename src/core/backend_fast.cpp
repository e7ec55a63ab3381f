// The fast backend behind KernelBackend: the fused, vectorised and
// multithreaded kernels of kernels_fast*.cpp, and the local refinement on
// its variables gathered into contiguous arrays (ActiveBuffers).
#include "normal_fusion/detail/kernel_backend.h"

namespace normal_fusion {
namespace internal {
namespace {

class FastBackend final : public KernelBackend {
 public:
  double energy(const PreparedLevel& level, const EnergyTerms& terms,
                const PlanarImage& normals, int threads) const override {
    return energyFast(level, terms.huber_eps, terms.penalty, normals, threads);
  }

  bool runInner(const PreparedLevel& level, const InnerParams& params,
                IterationState& state, int iterations) const override {
    return runInnerFast(level, params, state, iterations);
  }

  double beginRefinement(const PreparedLevel& level, const EnergyTerms& terms,
                         IterationState& state, RefinementBuffers& refine,
                         int threads) const override {
    refine.gathered.gather(level, state, refine.active, threads);
    return refine.gathered.energy(terms.huber_eps, terms.penalty, threads);
  }

  bool runRefinement(const PreparedLevel& level, const InnerParams& params,
                     IterationState& /*state*/, RefinementBuffers& refine,
                     int iterations) const override {
    return runInnerActiveFast(level, params, refine.gathered, iterations);
  }

  double candidateEnergy(const PreparedLevel& /*level*/,
                         const EnergyTerms& terms, IterationState& /*state*/,
                         RefinementBuffers& refine,
                         int threads) const override {
    refine.gathered.normalizeCandidate();
    return refine.gathered.energy(terms.huber_eps, terms.penalty, threads);
  }

  void acceptCandidate(IterationState& /*state*/,
                       RefinementBuffers& refine) const override {
    refine.gathered.acceptCandidate();
  }

  // The candidate lives in node_n only: n and nbar hold the iterate.
  void rejectCandidate(IterationState& /*state*/,
                       RefinementBuffers& /*refine*/) const override {}

  void endRefinement(IterationState& state, RefinementBuffers& refine,
                     int threads) const override {
    refine.gathered.scatter(state, threads);
  }

  bool measuresRefinementThreads() const override { return true; }
};

}  // namespace

const KernelBackend& fastBackend() {
  static const FastBackend backend;
  return backend;
}

}  // namespace internal
}  // namespace normal_fusion
