// Rotation-compensated warm start: moving a solver state between frames of a
// camera that rotated by R, with no depth needed.
#pragma once

#include <array>

#include "normal_fusion/solver.h"

namespace normal_fusion {

/// Largest angle between the source normals that the warp blends, degrees.
constexpr double kMaxBlendDegrees = 15.0;

/// Warps a state solved on the previous frame into the current one, for a
/// camera that rotated by R_cur_prev (row-major; a point in the previous
/// camera frame X_prev appears at R_cur_prev X_prev in the current one; any
/// translation is ignored). Pixels move by the homography K R_cur_prev K^-1
/// and normals (and the duals, which live in the same 3-D coordinates) are
/// rotated by R_cur_prev. Pixels that come from outside the previous image,
/// and pixels whose source pixels hold normals more than kMaxBlendDegrees apart
/// (an edge of the map: a bilinear blend would be a normal of neither side,
/// and a translation of the camera, which the warp ignores, moves edges
/// anyway), get NaN normals (the solver's warm start fills them as a cold
/// start would, from the current inputs) and zero duals. Throws InputError on
/// a bad K or a non-rotation R.
void warpStateByRotation(SolverState& state, const CameraIntrinsics& K,
                         const std::array<double, 9>& R_cur_prev);

/// What a warp does with the state's duals.
enum class DualWarp {
  kRotate,  ///< moved and rotated like the normals (zero where not predicted)
  kReset,   ///< set to zero: the cheaper choice when the solver's local
            ///< refinement (warm_refine_iterations > 0) re-solves the pixels
            ///< where the warm start is uncertain (bench_streaming measures
            ///< the same live PSNR either way)
};

/// The same for a live stream: the warped state is written into `scratch`'s
/// buffers and swapped in (the old buffers become the next call's scratch, so
/// that a stream of frames of one size allocates nothing once running), with
/// `num_threads` threads (0 = all hardware threads).
void warpStateByRotation(SolverState& state, const CameraIntrinsics& K,
                         const std::array<double, 9>& R_cur_prev,
                         SolverState& scratch, int num_threads,
                         DualWarp dual_warp = DualWarp::kRotate);

namespace internal {

/// Swaps a warp's output buffers (`warped`: normals, and the duals when
/// `has_duals`) into `state`; a state without usable duals keeps none.
void swapInWarped(SolverState& state, SolverState& warped, bool has_duals);

/// Per-pixel reference of warpStateByRotation (one thread, a new state each
/// call): the test oracle of the fast version.
void warpStateByRotationReference(SolverState& state, const CameraIntrinsics& K,
                                  const std::array<double, 9>& R_cur_prev);

}  // namespace internal

}  // namespace normal_fusion
