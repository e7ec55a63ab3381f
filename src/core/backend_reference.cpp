// The reference backend behind KernelBackend: the plain kernels of
// kernels_reference.cpp and the local refinement on the images themselves
// (local_refinement.cpp), each step of the maths one function.
#include <cmath>
#include <utility>

#include "normal_fusion/detail/kernel_backend.h"

namespace normal_fusion {
namespace internal {
namespace {

class ReferenceBackend final : public KernelBackend {
 public:
  double energy(const PreparedLevel& level, const EnergyTerms& terms,
                const PlanarImage& normals, int threads) const override {
    return internal::energy(level, terms.huber_eps, terms.penalty, normals,
                            threads);
  }

  bool runInner(const PreparedLevel& level, const InnerParams& params,
                IterationState& state, int iterations) const override {
    return runInnerReference(level, params, state, iterations);
  }

  double beginRefinement(const PreparedLevel& level, const EnergyTerms& terms,
                         IterationState& state, RefinementBuffers& refine,
                         int threads) const override {
    // On the images: n = nbar = n0 (everywhere).
    state.n = state.n0;
    state.nbar = state.n0;
    const std::size_t values = 3 * refine.active.pixels.size();
    if (refine.iterate_saved.size() < values) {
      refine.iterate_saved.resize(values);
    }
    return energyActive(level, terms.huber_eps, terms.penalty, state.n0,
                        refine.active, threads);
  }

  bool runRefinement(const PreparedLevel& level, const InnerParams& params,
                     IterationState& state, RefinementBuffers& refine,
                     int iterations) const override {
    return runInnerActive(level, params, state, refine.active, iterations);
  }

  double candidateEnergy(const PreparedLevel& level, const EnergyTerms& terms,
                         IterationState& state, RefinementBuffers& refine,
                         int threads) const override {
    // n <- n / |n| at the active pixels, the iterate kept for a reject.
    const std::vector<int>& pixels = refine.active.pixels;
    const long count = static_cast<long>(pixels.size());
    for (long j = 0; j < count; ++j) {
      const int i = pixels[j];
      float* n[3] = {state.n.plane(0) + i, state.n.plane(1) + i,
                     state.n.plane(2) + i};
      const float inv =
          1.0f / std::sqrt(*n[0] * *n[0] + *n[1] * *n[1] + *n[2] * *n[2]);
      for (int c = 0; c < 3; ++c) {
        refine.iterate_saved[3 * j + c] = *n[c];
        *n[c] *= inv;
      }
    }
    return energyActive(level, terms.huber_eps, terms.penalty, state.n,
                        refine.active, threads);
  }

  void acceptCandidate(IterationState& state,
                       RefinementBuffers& refine) const override {
    std::swap(state.n0, state.n);  // state.n (the old n0) is n0 off the set
    for (int i : refine.active.pixels) {
      for (int c = 0; c < 3; ++c) {
        state.n.plane(c)[i] = state.nbar.plane(c)[i] = state.n0.plane(c)[i];
      }
    }
  }

  void rejectCandidate(IterationState& state,
                       RefinementBuffers& refine) const override {
    const std::vector<int>& pixels = refine.active.pixels;
    const long count = static_cast<long>(pixels.size());
    for (long j = 0; j < count; ++j) {
      for (int c = 0; c < 3; ++c) {
        state.n.plane(c)[pixels[j]] = refine.iterate_saved[3 * j + c];
      }
    }
  }

  void endRefinement(IterationState& /*state*/, RefinementBuffers& /*refine*/,
                     int /*threads*/) const override {}

  bool measuresRefinementThreads() const override { return false; }
};

}  // namespace

const KernelBackend& referenceBackend() {
  static const ReferenceBackend backend;
  return backend;
}

}  // namespace internal
}  // namespace normal_fusion
