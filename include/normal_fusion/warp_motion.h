// Full-motion warm start: moving a solver state between frames of a camera
// that rotated and translated, through the previous frame's depth.
#pragma once

#include <cstdint>
#include <vector>

#include "normal_fusion/geometry.h"
#include "normal_fusion/solver.h"
#include "normal_fusion/warp.h"

namespace normal_fusion {

/// Relative depth difference below which two splats that reach one current
/// pixel count as the same surface (the nearer of them decides visibility,
/// the one nearest to the pixel centre gives the normal).
constexpr double kMotionWarpSameSurfaceRatio = 0.05;

/// The buffers a stream's motion warp reuses between frames (sized on the
/// first frame of a size, then never again).
struct MotionWarpScratch {
  SolverState state;  ///< the warped state, swapped in
  /// Per layer of splats (nearest pixels, then the rest of the 2x2) and
  /// current pixel: the z-buffer, the float bits of the nearest depth.
  std::vector<std::uint32_t> nearest_depth_bits;
  /// The same: the winning splat, its squared distance to the pixel centre
  /// (float bits) above the previous pixel's index.
  std::vector<std::uint64_t> winner;
  /// Per previous pixel: where it lands in the current image and its depth
  /// there (+inf: nowhere).
  std::vector<float> splat_u, splat_v, splat_z;
  /// Per previous row: the range of v its splats land in.
  std::vector<float> row_v_min, row_v_max;

  /// Sizes every buffer for a width x height state of num_inputs inputs
  /// (-1: normals only); allocates only when a size changes.
  void resize(int width, int height, int num_inputs) {
    if (num_inputs >= 0) {
      state.resize(width, height, num_inputs);
    } else {
      state.normals.resize(width, height, 3);
    }
    const std::size_t layers =
        2 * static_cast<std::size_t>(width) * static_cast<std::size_t>(height);
    nearest_depth_bits.resize(layers);
    winner.resize(layers);
    splat_u.resize(layers / 2);
    splat_v.resize(layers / 2);
    splat_z.resize(layers / 2);
    row_v_min.resize(static_cast<std::size_t>(height));
    row_v_max.resize(static_cast<std::size_t>(height));
  }

  /// Bytes of memory its buffers hold (their capacity).
  std::size_t bytesHeld() const {
    return state.bytesHeld() +
           nearest_depth_bits.capacity() * sizeof(std::uint32_t) +
           winner.capacity() * sizeof(std::uint64_t) +
           (splat_u.capacity() + splat_v.capacity() + splat_z.capacity() +
            row_v_min.capacity() + row_v_max.capacity()) *
               sizeof(float);
  }
};

/// Warps a state solved on the previous frame into the current one, for a
/// camera that moved by T_cur_prev (X_cur = R X_prev + t, t in metres), with
/// the previous frame's depth `depth_prev_m` (metres, one plane, NaN = none,
/// aligned with the previous image: the state's size and K).
///
/// Every previous pixel with depth is back-projected, moved by T_cur_prev and
/// projected into the current image. Each splat reaches the pixel nearest
/// to it (within half a pixel in x and y) and, as a second layer, the rest
/// of its 2x2 (closer than one pixel): a pixel that no splat is nearest to
/// (a one-pixel crack of a surface that the motion magnifies, up to twice per
/// frame) takes the second layer, so that cracks close without a surface
/// growing over its neighbour by the wider footprint. Per layer a z-buffer
/// over the splats decides which surface is visible at a pixel; among the
/// splats of that surface (within kMotionWarpSameSurfaceRatio of the nearest
/// depth) the one nearest to the pixel centre gives the pixel its normal,
/// rotated by R (the duals likewise, or reset: DualWarp). Pixels that no splat
/// reaches (disoccluded, outside the previous view, or seen only where the
/// previous depth was missing) get NaN normals and zero duals, as the rotation
/// warp's unknown pixels: the solver's warm start fills them from the current
/// inputs. Throws InputError on a bad K, a state without normals, a depth of
/// another size, a non-rotation R or a non-finite t.
void warpStateByMotion(SolverState& state, const ScalarMap& depth_prev_m,
                       const CameraIntrinsics& K, const Pose& T_cur_prev);

/// The same for a live stream: written into `scratch`'s buffers and swapped
/// in (a stream of frames of one size allocates nothing once running), with
/// `num_threads` threads (0 = all hardware threads). The result does not
/// depend on the thread count.
void warpStateByMotion(SolverState& state, const ScalarMap& depth_prev_m,
                       const CameraIntrinsics& K, const Pose& T_cur_prev,
                       MotionWarpScratch& scratch, int num_threads,
                       DualWarp dual_warp = DualWarp::kRotate);

namespace internal {

/// Per-pixel reference of warpStateByMotion (one thread, a new state each
/// call): for each current pixel it searches every previous pixel for the
/// splats that reach it, W^2 H^2 steps, so for small test images only. The
/// test oracle of the fast version.
void warpStateByMotionReference(SolverState& state,
                                const ScalarMap& depth_prev_m,
                                const CameraIntrinsics& K,
                                const Pose& T_cur_prev);

}  // namespace internal

}  // namespace normal_fusion
