// The per-input noise estimate across scales (SolverSettings::noise_radius):
// how much an input's spread grows from the local window to wider ones. White
// noise spreads alike at every scale; noise that neighbouring pixels share (a
// plane fit over a window, a stereo block match) hides from a small window and
// shows in a wide one.
#pragma once

#include <array>

#include "normal_fusion/types.h"

namespace normal_fusion {
namespace internal {

/// Adds one row of f (3 planes) and its validity (f != 0) to the column sums.
void columnSums(int W, const float* __restrict fx, const float* __restrict fy,
                const float* __restrict fz, float* __restrict sx,
                float* __restrict sy, float* __restrict sz,
                float* __restrict count);

/// out(x) = sum of in(u), u = x - r .. x + r inside the row.
void windowSums(int W, int r, const float* __restrict in,
                float* __restrict out);

/// The rows windowResultantRow() works in: column sums col[0..3] and window
/// sums win[0..3] (resultant x, y, z and the valid count), W values each.
struct WindowSumRows {
  /// The kRows rows laid out in the first kRows * W values of `scratch`.
  WindowSumRows(float* scratch, int W) {
    for (int k = 0; k < 4; ++k) {
      col[k] = scratch + k * W;
      win[k] = scratch + (4 + k) * W;
    }
  }
  static constexpr int kRows = 8;
  float* col[4];
  float* win[4];
};

/// Window sums of row y of f (3 planes, 0 where missing) over the
/// (2 r + 1)^2 window, separably: the rows y - r .. y + r summed per column
/// into rows.col, then the columns x - r .. x + r into rows.win.
void windowResultantRow(const PlanarImage& data, int r, int y,
                        WindowSumRows& rows);

/// The noise level of f (3 planes, unit or 0 where missing) in the
/// (2 r + 1)^2 window around (x, y), as white noise would read it, computed
/// in double. Around the window's mean:
///   sigma_r = s_r / sqrt(1 - 1 / n_r),
/// s_r = sqrt(2 (1 - |sum f| / n_r)) the RMS spread around the mean and n_r
/// the window's valid pixels (the factor undoes the spread's bias for n_r
/// independent samples); -1 below 2 samples. With plane_residual, around
/// the window's least-squares plane (each component fitted as a + b u + c v
/// over the valid pixels at offsets (u, v) from (x, y)):
///   sigma_r = sqrt(RSS_r / (n_r - 3)) / (1 - 1 / (9 (n_r - 3)))^1.5
/// (the last factor: a chi's median over its RMS, since the median is read),
/// so that a surface turning steadily (a cylinder, a sphere) reads its noise
/// and not its bend; -1 where fewer than 4 valid pixels or pixels all on
/// one line leave the plane undetermined.
float windowSpreadAt(const PlanarImage& data, int r, int x, int y,
                     bool plane_residual);

/// About how many window centres estimateNoise() reads.
constexpr int kNoiseSamples = 1024;

/// The spacing of estimateNoise()'s grid of centres (x, y = stride / 2 +
/// k stride): about kNoiseSamples centres, every pixel on small images.
int noiseSampleStride(int width, int height);

/// The most scales of a NoiseEstimate (radii r0, 2 r0, 4 r0, ...).
constexpr int kMaxNoiseScales = 8;

/// One input's noise across scales.
struct NoiseEstimate {
  int scales = 0;
  std::array<int, kMaxNoiseScales> radius{};
  /// Median of sigma_r over the centres with 2 samples at the smallest
  /// radius.
  std::array<float, kMaxNoiseScales> sigma{};
  /// max over the scales of sigma_r / sigma_r0, at least 1 (also where the
  /// input has too few samples), at most (2 r_max + 1) / (2 r0 + 1): about 1
  /// for white noise, growing with the noise's correlation length where
  /// neighbours share their error.
  float gain = 1.0f;
};

/// The estimate of f at radii base_radius, 2 base_radius, 4 base_radius, ...
/// up to max_radius (max_radius itself the last one), read at the centres of
/// noiseSampleStride()'s grid (windowSpreadAt()), each spread around the
/// window's mean or, with plane_residual, around its least-squares plane; an
/// input whose base windows determine a plane at fewer than half of the
/// centres it observes (a sparse input) is read around the mean. Buffers grown
/// once per thread, then reused.
NoiseEstimate estimateNoise(const PlanarImage& data, int base_radius,
                            int max_radius, int threads,
                            bool plane_residual = false);

}  // namespace internal
}  // namespace normal_fusion
