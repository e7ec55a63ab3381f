// The levels of a solve (solver_levels.cpp): the coarse-to-fine pyramid and
// the starts of each level's iterations.
#pragma once

#include "normal_fusion/detail/solver_internal.h"

namespace normal_fusion {
namespace internal {

/// The next coarser level (into reused buffers): 2x2 blocks, validity-weighted
/// means of the data (normalized), weights averaged and doubled (the data term
/// scales with area, the smoothness term with length), K scaled, edge weights
/// recomputed.
void downsampleInto(const PreparedLevel& fine, const SolverSettings& settings,
                    PreparedLevel& coarse, EdgeWeightScratch& scratch,
                    int threads);

/// Cold start: per pixel the first input with a usable observation
/// (projected onto the visible set in soft mode), else -r/|r|.
void initializeCold(const PreparedLevel& level, VisibilityMode mode,
                    PlanarImage& n, int threads);

/// Cold start from an edge-aware filter of the inputs: sum_l c_l f_l (the
/// data-weighted mean, c_l the data weights) smoothed by the domain
/// transform's recursive filter (3 passes, extent `radius` pixels) whose
/// link between neighbours is a^(1 / w_d), w_d the level's edge weights;
/// normalized and projected onto the visible set in soft mode. Pixels no data
/// reaches start as in initializeCold(). `scratch` (5 planes) is reused.
void initializeFiltered(const PreparedLevel& level, VisibilityMode mode,
                        int radius, PlanarImage& scratch, PlanarImage& n,
                        int threads);

/// Upsamples a coarse unit normal map bilinearly (pixel centres aligned),
/// normalizes, and projects onto the visible set in soft mode.
void upsampleNormals(const PlanarImage& coarse, const PreparedLevel& fine,
                     VisibilityMode mode, PlanarImage& n, int threads);

/// The duals of a coarser level's result carried to the finer `fine`
/// (piecewise constant: each fine link takes the dual of the coarse link or
/// pixel it lies in): the smoothness duals copied, the data duals halved (the
/// coarser data weights are doubled), each clamped to the fine level's
/// weight; the links past the last column and row 0.
void upsampleDuals(const PlanarImage& coarse_p_h, const PlanarImage& coarse_p_v,
                   const std::vector<PlanarImage>& coarse_q,
                   const PreparedLevel& fine, IterationState& state,
                   int threads);

/// out <- n / |n| per pixel (the projection onto the sphere; |n| >= 1 on the
/// tangent plane).
void normalizeInto(const PlanarImage& n, PlanarImage& out, int threads);

}  // namespace internal
}  // namespace normal_fusion
