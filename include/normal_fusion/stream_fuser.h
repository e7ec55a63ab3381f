// A stream of frames fused one after the other: when the previous result
// warm-starts the next frame (moved by the camera's rotation, or by its full
// motion through the previous frame's depth), when the stream restarts, the
// inputs' averages over time and the frame budget's reserves. The policy the
// node runs, without ROS: the ROS pipeline, the benchmarks and the tools all
// fuse their streams through it.
#pragma once

#include <array>
#include <chrono>
#include <cstdint>
#include <optional>
#include <string>

#include "normal_fusion/detail/stream_defaults.h"
#include "normal_fusion/solver.h"
#include "normal_fusion/temporal.h"
#include "normal_fusion/warp.h"
#include "normal_fusion/warp_motion.h"

namespace normal_fusion {

/// What a stream is configured with.
struct StreamSettings {
  SolverSettings solver;
  /// Each frame warm-started from the previous frame's result when the
  /// stream continues (see StreamFuser::continuesStream).
  bool warm_start = stream_default::warm_start;
  /// Largest stamp gap to warm-start over, seconds, on top of the time the
  /// previous frame took (frames arriving meanwhile are dropped by a live
  /// caller, so the gap to the next frame solved is at least that long).
  double warm_start_max_gap = stream_default::warm_start_max_gap;
  /// Each input averaged over the stream's frames before the solve.
  TemporalSettings temporal;
  /// What the warp (rotation or motion) does with the duals; unset: reset
  /// while the solver's local refinement is on (warm_refine_iterations > 0),
  /// else rotated (see DualWarp).
  std::optional<DualWarp> dual_warp;
};

/// The camera's rotation from the previous frame to this one, as far as the
/// caller knows it, and its translation where that is known too (the full
/// motion: the warm start then follows it through the previous frame's
/// depth, see StreamFuser::fuse).
struct FrameRotation {
  enum class Kind {
    kStill,    ///< not compensated: the camera is taken as still
    kKnown,    ///< R_cur_prev holds it
    kUnknown,  ///< compensation wanted, but it could not be found (reason)
  };
  Kind kind = Kind::kStill;
  /// X_cur = R_cur_prev X_prev, row-major (kKnown).
  std::array<double, 9> R_cur_prev{};
  /// kKnown: t_cur_prev holds the translation (X_cur = R_cur_prev X_prev +
  /// t_cur_prev, metres); false: the rotation alone is known.
  bool has_translation = false;
  std::array<double, 3> t_cur_prev{};
  std::string reason;  ///< kUnknown: why

  static FrameRotation still() { return FrameRotation(); }
  static FrameRotation known(const std::array<double, 9>& R_cur_prev);
  /// The full motion T_cur_prev (rotation and translation) is known.
  static FrameRotation knownMotion(const Pose& T_cur_prev);
  static FrameRotation unknown(const std::string& reason);
};

/// What one fused frame gives, besides the fused normals and the solve's
/// report (StreamFuser::fusedNormals(), StreamFuser::lastReport()).
struct StreamResult {
  /// The stream (re)started with this frame while warm starts are on: its
  /// cold start, and restart_reason why.
  bool stream_started = false;
  std::string restart_reason;
  /// The rotation was applied (the state warped, or the averages carried).
  bool rotated = false;
  /// The state was warped by the full motion through the previous frame's
  /// depth (warpStateByMotion) instead of the rotation alone.
  bool motion_warped = false;
  /// The inputs joined the previous frames' averages.
  bool inputs_averaged = false;
  double average_seconds = 0.0;  ///< the temporal averaging's time
  double warp_seconds = 0.0;     ///< the warp's time
  /// The overrun reserve this frame's budget was given, seconds.
  double budget_reserve_seconds = 0.0;
  /// A rotation asked for (not kStill) could not be used on a frame that
  /// continues the stream: the frame was then cold-started and its averages
  /// restarted (rotation_consequence says which of the two applies).
  bool rotation_failed = false;
  /// Why (FrameRotation::reason, or the warp's refusal of the rotation).
  std::string rotation_unknown;
  std::string rotation_consequence;
  /// Worth a warning: time went backwards and the stream was reset.
  std::string warning;
  /// Worth an info line: the stream (re)started with a cold start, why, and
  /// under which budget; empty otherwise.
  std::string note;
};

/// The per-stream state and policy: one instance per camera stream, one
/// frame at a time (not thread-safe except requestCancel()).
///
/// A frame continues the stream when there is a previous result of the same
/// size, input count and K, its stamp is not earlier, and the stamp gap is
/// at most warm_start_max_gap plus the previous frame's time. Otherwise the
/// stream restarts: the warm start and the averages start anew (with warm
/// starts on, its cold start runs under SolverSettings::cold_start_budget_ms).
/// A stamp earlier than the previous one resets the stream with a warning.
/// An unknown rotation cold-starts that one frame under the frame budget and
/// restarts the averages. A solve that throws, is cancelled or gives a
/// pixel that is not a finite unit normal resets the stream as well.
class StreamFuser {
 public:
  /// `name` starts the messages of the errors thrown (e.g. the image topic).
  explicit StreamFuser(const StreamSettings& settings,
                       const std::string& name = "stream");

  /// New settings; take effect with the next frame (the stream goes on).
  void setSettings(const StreamSettings& settings);
  const StreamSettings& settings() const { return settings_; }

  /// Whether a frame with this stamp (nanoseconds), K, size and input count
  /// would continue the stream, and otherwise why not: only then is its
  /// rotation to the previous frame (previousStampNs()) needed.
  bool continuesStream(std::int64_t stamp_ns, const CameraIntrinsics& K,
                       int width, int height, int num_inputs,
                       std::string* reason) const;
  std::int64_t previousStampNs() const { return previous_stamp_ns_; }

  /// Fuses one frame: `frame` holds the guide image, K and one input per
  /// stream input (all of the image's size; an absent input as an
  /// all-missing map). Its inputs' normals are replaced by their averages
  /// when temporal averaging is on. The frame budget
  /// (SolverSettings::time_budget_ms) counts from `started`, less the
  /// reserves for the caller's encoding and for overruns. Throws what the
  /// solver throws, Cancelled, or Error when the solve gives a pixel without
  /// a finite unit normal; the stream is then reset. Call endFrame() once
  /// the frame's outputs are done.
  ///
  /// `depth_m` (optional): this frame's depth in metres (one plane, NaN =
  /// none, aligned with the image: its size and K), kept for the next frame:
  /// when that one's rotation comes with its translation, its warm start
  /// follows the full motion through this depth (warpStateByMotion);
  /// without either, the rotation alone (warpStateByRotation). A depth of
  /// another size is not kept. The input averages follow the rotation alone.
  void fuse(std::int64_t stamp_ns, FusionProblem& frame,
            const FrameRotation& rotation,
            std::chrono::steady_clock::time_point started, StreamResult* result,
            const ScalarMap* depth_m = nullptr);

  /// Sizes and first touches every buffer that a stream of `width` x
  /// `height` frames with `num_inputs` inputs uses (the solver's levels and
  /// scratch, the state, the warps' buffers, the averages; the motion warp's
  /// with `with_depth`), so that its first frames pay nothing for memory: at
  /// 640x480 that first touch takes longer than a 33 ms frame. It runs the
  /// stream's cold start and one warm frame on a flat frame of that size
  /// (as long as a first frame takes); the stream then restarts with its
  /// next frame, whose results are those of a stream never reserved. For a
  /// caller that knows the size before the first frame (the node, from the
  /// first camera_info). Returns the seconds it took; throws InputError for
  /// a size below 2x2 or no input.
  double reserve(int width, int height, int num_inputs,
                 bool with_depth = false);

  /// Bytes of memory the stream's buffers hold (solver, state, warps,
  /// averages, the kept depth).
  std::size_t bytesHeld() const;

  /// Whether the previous frame's depth is kept for the next frame's motion
  /// warp.
  bool hasPreviousDepth() const { return has_previous_depth_; }

  /// Ends the frame fused last: `encode_seconds` of the caller's work on its
  /// outputs join the estimate reserved in later budgets, and the frame's
  /// time (since `started`) moves the overrun reserve. Returns that time.
  double endFrame(double encode_seconds);

  /// Forgets the previous frame: the next frame restarts the stream.
  void reset();

  /// From any thread: the solve under way (and every later one) stops within
  /// an inner iteration block; fuse() then throws Cancelled.
  void requestCancel() noexcept { solver_.requestCancel(); }

  /// The fused normals and report of the last frame (valid after fuse()).
  const NormalMap& fusedNormals() const { return state_.normals; }
  const SolverState& state() const { return state_; }
  const SolveReport& lastReport() const { return report_; }
  /// Frames fused since construction.
  std::uint64_t framesFused() const { return frames_fused_; }
  /// Seconds set aside in the budget for overruns (the 98th percentile of
  /// the frames' overruns).
  double overrunReserveSeconds() const { return overrun_reserve_s_; }

 private:
  /// Applies a known rotation to the state (warm starts; by the full motion
  /// when its translation and the previous depth are known, then
  /// *motion_warped) or checks it; returns false with the reason when it
  /// cannot be used.
  bool applyRotation(const CameraIntrinsics& K, const FrameRotation& rotation,
                     std::string* reason, double* seconds, bool* motion_warped);
  /// Forgets the previous frame (reset()); with `keep_buffers` the state's
  /// buffers keep their memory.
  void forget(bool keep_buffers);
  /// Keeps `depth_m` (or forgets the previous one) for the next frame.
  void keepDepth(const ScalarMap* depth_m, const FusionProblem& frame);
  /// The inputs' temporal averages for this frame; restarted unless
  /// `joined`.
  void averageInputs(FusionProblem& frame, const FrameRotation& rotation,
                     bool rotated, bool joined, double* seconds);
  void solve(FusionProblem& frame, bool warm,
             std::chrono::steady_clock::time_point started);
  std::string streamStartNote(const std::string& reason) const;

  StreamSettings settings_;
  std::string name_;
  Solver solver_;
  SolverState state_;
  SolverState warp_scratch_;          ///< buffers of the rotation warp, reused
  MotionWarpScratch motion_scratch_;  ///< buffers of the motion warp, reused
  /// The previous frame's depth, metres (valid when has_previous_depth_).
  ScalarMap previous_depth_m_;
  bool has_previous_depth_ = false;
  SolveReport report_;
  TemporalAverage temporal_;
  /// The averages were updated with the previous frame (averaging was on).
  bool averages_current_ = false;
  bool has_previous_ = false;
  std::int64_t previous_stamp_ns_ = 0;
  CameraIntrinsics previous_K_;
  /// Wall time the previous frame took, seconds (see warm_start_max_gap).
  double previous_seconds_ = 0.0;
  std::chrono::steady_clock::time_point frame_started_;
  std::uint64_t frames_fused_ = 0;
  /// Seconds the caller's encoding takes, reserved inside the frame budget.
  double encode_estimate_s_ = 0.0;
  /// Seconds the last frame's checks after its solve took (the output's
  /// unit normals, the depth kept), reserved inside the next frame's budget.
  double checks_s_ = 0.0;
  /// Seconds reserved for what the solve's own deadline cannot foresee (a
  /// loaded machine).
  double overrun_reserve_s_ = 0.0;
};

}  // namespace normal_fusion
