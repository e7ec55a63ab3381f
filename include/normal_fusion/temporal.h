// Temporal averaging of a stream's inputs: each input's samples of a pixel,
// carried from frame to frame by the camera's rotation, averaged, so that a
// stream solves on inputs with less noise than any one frame's.
#pragma once

#include <array>
#include <vector>

#include "normal_fusion/detail/stream_defaults.h"
#include "normal_fusion/solver.h"

namespace normal_fusion {

/// How the inputs of a stream are averaged over time.
struct TemporalSettings {
  /// The memory of each pixel's average, in frames: the average is the mean
  /// of the pixel's samples since it (re)started while there are fewer than
  /// `frames` of them, then an exponential average that gives a new sample
  /// the weight 1 / frames. 0 or 1 = off (each frame's own inputs).
  int frames = stream_default::temporal_frames;
  /// A sample more than this many degrees from its pixel's average starts
  /// the average anew: content that moved or changed, an edge that the
  /// camera's translation (which the rotation ignores) shifted, an outlier
  /// that the average held. In (0, 180].
  double gate_degrees = stream_default::temporal_gate_deg;

  bool enabled() const { return frames > 1; }
  /// Throws ParameterError naming the first setting that is out of range.
  void validate() const;
};

/// The running averages of one stream's inputs (one per input), kept between
/// frames. Buffers are sized on the first frame of a size; later frames of
/// that size allocate nothing.
class TemporalAverage {
 public:
  /// Forgets every average (a stream's start, or a frame whose rotation to
  /// the previous one is unknown).
  void reset();

  /// Replaces each input's normals by the average of its samples at that
  /// pixel, this frame's included. The averages are first carried from the
  /// previous frame into this one: pixel x takes the average of the previous
  /// pixel nearest to K R^T K^-1 x (no blending: neighbouring samples are
  /// not averaged across space), its normal rotated by R_cur_prev (nullptr:
  /// the camera did not rotate, the averages stay where they are). Per
  /// pixel, with count = min(samples averaged, settings.frames), this one
  /// included, and w = 1 / count:
  ///   average <- normalize((1 - w) average + w sample),
  /// or average <- sample (count 1) where the pixel had no average or the
  /// sample is more than settings.gate_degrees from it. Pixels without a
  /// valid sample stay without one (nothing is filled in) and keep their
  /// average for later samples. Confidences and weights are left as they
  /// are. Inputs of another size or count than the averages' restart them.
  /// Off (settings.frames <= 1): the inputs are left as they are. Throws
  /// InputError for a bad K or a non-rotation R_cur_prev (the inputs and
  /// averages are then unchanged), ParameterError for bad settings.
  void apply(std::vector<NormalInput>& inputs, const CameraIntrinsics& K,
             const std::array<double, 9>* R_cur_prev,
             const TemporalSettings& settings, int num_threads);

  /// The count of pixel i of input l: samples in its average, at most
  /// settings.frames (0 where it has none).
  int count(int l, int i) const;

  /// Bytes of memory the averages hold (frames of a much smaller size than
  /// before give the larger buffers' memory back: PlanarImage::resize()).
  std::size_t bytesHeld() const;

 private:
  struct History {
    NormalMap average;  ///< per pixel, in the input's own frame
    ScalarMap count;    ///< samples in it (0: none)
    NormalMap scratch_average;
    ScalarMap scratch_count;
  };
  std::vector<History> histories_;
};

}  // namespace normal_fusion
