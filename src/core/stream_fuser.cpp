#include "normal_fusion/stream_fuser.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "normal_fusion/detail/previous_pixel.h"
#include "normal_fusion/errors.h"

namespace normal_fusion {

FrameRotation FrameRotation::known(const std::array<double, 9>& R_cur_prev) {
  FrameRotation rotation;
  rotation.kind = Kind::kKnown;
  rotation.R_cur_prev = R_cur_prev;
  return rotation;
}

FrameRotation FrameRotation::knownMotion(const Pose& T_cur_prev) {
  FrameRotation rotation = known(T_cur_prev.R);
  rotation.has_translation = true;
  rotation.t_cur_prev = T_cur_prev.t;
  return rotation;
}

FrameRotation FrameRotation::unknown(const std::string& reason) {
  FrameRotation rotation;
  rotation.kind = Kind::kUnknown;
  rotation.reason = reason;
  return rotation;
}

namespace {

/// reserve() sizes the local refinement for 1 / kReservedRefinedShare of the
/// pixels.
constexpr int kReservedRefinedShare = 4;

/// later - earlier in seconds (integer nanoseconds, no overflow for stamps
/// of this era).
double secondsBetween(std::int64_t later_ns, std::int64_t earlier_ns) {
  return 1e-9 * static_cast<double>(later_ns - earlier_ns);
}

double secondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start)
      .count();
}

/// The number of pixels of `normals` that are not finite unit vectors.
std::size_t nonUnitPixels(const NormalMap& normals) {
  std::size_t bad = 0;
  const std::size_t n = normals.pixelCount();
  const float* x = normals.plane(0);
  const float* y = normals.plane(1);
  const float* z = normals.plane(2);
  for (std::size_t i = 0; i < n; ++i) {
    const float length2 = x[i] * x[i] + y[i] * y[i] + z[i] * z[i];
    // NaN fails the comparison and counts as bad.
    bad += !(std::abs(length2 - 1.0f) <= 1e-3f);
  }
  return bad;
}

}  // namespace

StreamFuser::StreamFuser(const StreamSettings& settings,
                         const std::string& name)
    : settings_(settings), name_(name), solver_(settings.solver) {}

void StreamFuser::setSettings(const StreamSettings& settings) {
  solver_.setSettings(settings.solver);
  settings_ = settings;
}

void StreamFuser::reset() { forget(false); }

void StreamFuser::forget(bool keep_buffers) {
  has_previous_ = false;
  if (keep_buffers) {
    state_.clearKeepingCapacity();
  } else {
    state_.clear();
  }
  temporal_.reset();
  averages_current_ = false;
  has_previous_depth_ = false;
}

bool StreamFuser::continuesStream(std::int64_t stamp_ns,
                                  const CameraIntrinsics& K, int width,
                                  int height, int num_inputs,
                                  std::string* reason) const {
  if (!has_previous_) {
    *reason = "no previous frame";
    return false;
  }
  if (stamp_ns < previous_stamp_ns_) {
    *reason = "time went backwards";
    return false;
  }
  if (!state_.compatible(width, height, num_inputs)) {
    *reason = "the image size changed";
    return false;
  }
  for (int i = 0; i < 9; ++i) {
    if (std::abs(K.K[i] - previous_K_.K[i]) >
        1e-9 * std::max(1.0, std::abs(previous_K_.K[i]))) {
      *reason = "K changed";
      return false;
    }
  }
  // The gap the previous frame's own processing opened does not count:
  // after a long solve (a stream's converged start) the next frame solved is
  // the newest, its stamp that much later.
  const double gap = secondsBetween(stamp_ns, previous_stamp_ns_);
  if (gap > settings_.warm_start_max_gap + previous_seconds_) {
    std::ostringstream text;
    text << "stamp gap " << gap << " s exceeds warm_start_max_gap plus the "
         << "previous set's processing (" << previous_seconds_ << " s)";
    *reason = text.str();
    return false;
  }
  return true;
}

bool StreamFuser::applyRotation(const CameraIntrinsics& K,
                                const FrameRotation& rotation,
                                std::string* reason, double* seconds,
                                bool* motion_warped) {
  const auto start = std::chrono::steady_clock::now();
  const std::array<double, 9>& R_cur_prev = rotation.R_cur_prev;
  try {
    if (settings_.warm_start) {
      // With the local refinement the duals are reset (as good, and
      // cheaper: see DualWarp); a state still converging keeps them for its
      // whole-image steps.
      const DualWarp dual_warp = settings_.dual_warp.value_or(
          solver_.settings().warm_refine_iterations > 0 && !state_.converging
              ? DualWarp::kReset
              : DualWarp::kRotate);
      const int threads = solver_.settings().num_threads;
      if (rotation.has_translation && has_previous_depth_) {
        Pose T_cur_prev;
        T_cur_prev.R = R_cur_prev;
        T_cur_prev.t = rotation.t_cur_prev;
        warpStateByMotion(state_, previous_depth_m_, K, T_cur_prev,
                          motion_scratch_, threads, dual_warp);
        *motion_warped = true;
      } else {
        warpStateByRotation(state_, K, R_cur_prev, warp_scratch_, threads,
                            dual_warp);
      }
    } else {
      internal::checkRotation(R_cur_prev, "the transform");
    }
  } catch (const Error& e) {
    *reason = e.what();
    return false;
  }
  *seconds = secondsSince(start);
  return true;
}

void StreamFuser::averageInputs(FusionProblem& frame,
                                const FrameRotation& rotation, bool rotated,
                                bool joined, double* seconds) {
  const auto start = std::chrono::steady_clock::now();
  // A new stream, or averages left from before averaging was last turned
  // off (stale): they restart with this frame.
  if (!joined) temporal_.reset();
  try {
    temporal_.apply(
        frame.inputs, frame.K, rotated ? &rotation.R_cur_prev : nullptr,
        settings_.temporal, resolveThreadCount(settings_.solver.num_threads));
  } catch (...) {
    reset();
    throw;
  }
  averages_current_ = true;
  *seconds = secondsSince(start);
}

void StreamFuser::solve(FusionProblem& frame, bool warm,
                        std::chrono::steady_clock::time_point started) {
  try {
    // time_budget_ms covers the whole frame, the caller's encoding of the
    // outputs included: its time (as the last frames took), the checks
    // after the solve (as the last frame's took) and the overrun reserve are
    // set aside by starting the budget that much earlier.
    const auto reserve =
        std::chrono::duration_cast<std::chrono::steady_clock::duration>(
            std::chrono::duration<double>(encode_estimate_s_ + checks_s_ +
                                          overrun_reserve_s_));
    solver_.setBudgetStart(started - reserve);
    solver_.solve(frame, state_, warm, report_);
    if (report_.cancelled) throw Cancelled(name_ + ": solve cancelled");
    // The warp's buffers, sized with the state (allocates on the first frame
    // of a size only).
    warp_scratch_.resize(state_.normals.width(), state_.normals.height(),
                         static_cast<int>(state_.dual_data.size()));
  } catch (...) {
    reset();
    throw;
  }
}

std::string StreamFuser::streamStartNote(const std::string& reason) const {
  std::ostringstream text;
  text << "stream (re)started (" << reason << "): cold start in "
       << std::lround(1e3 * report_.seconds) << " ms, "
       << report_.inner_iterations + report_.coarse_inner_iterations
       << " inner iterations";
  if (report_.cold_start_budget_used) {
    const double budget = solver_.settings().cold_start_budget_ms;
    text << " under cold_start_budget_ms ";
    if (budget > 0.0) {
      text << "(" << budget << " ms)";
    } else {
      text << "(none: the iteration caps)";
    }
    text << " instead of time_budget_ms (" << solver_.settings().time_budget_ms
         << " ms)";
  }
  return text.str();
}

void StreamFuser::fuse(std::int64_t stamp_ns, FusionProblem& frame,
                       const FrameRotation& rotation,
                       std::chrono::steady_clock::time_point started,
                       StreamResult* result, const ScalarMap* depth_m) {
  *result = StreamResult();
  frame_started_ = started;
  if (has_previous_ && stamp_ns < previous_stamp_ns_) {
    std::ostringstream text;
    text << "time went backwards by "
         << secondsBetween(previous_stamp_ns_, stamp_ns)
         << " s (a bag loop or a restarted player): warm start reset";
    result->warning = text.str();
    reset();
  }
  // A warm start wanted but the previous map unusable: the stream
  // (re)starts here. Its cold start is solved under cold_start_budget_ms
  // (the solver's rule for a warm start asked for without a usable state),
  // since the warm frames after it carry its map on. An unknown rotation is
  // a one-frame failure instead: that frame is cold-started under the frame
  // budget. The averages follow the same stream: carried by the same
  // rotation, restarted where the warm start would be.
  const bool averaging = settings_.temporal.enabled();
  bool continuous = false;  // this frame continues the previous one's stream
  if (settings_.warm_start || averaging) {
    continuous = continuesStream(
        stamp_ns, frame.K, frame.image.width(), frame.image.height(),
        static_cast<int>(frame.inputs.size()), &result->restart_reason);
    if (!continuous && settings_.warm_start) {
      result->stream_started = true;
      // Its buffers kept: a restart of the same size allocates nothing.
      state_.clearKeepingCapacity();
    }
  }
  if (continuous && rotation.kind != FrameRotation::Kind::kStill) {
    std::string why = rotation.reason;
    result->rotated =
        rotation.kind == FrameRotation::Kind::kKnown &&
        applyRotation(frame.K, rotation, &why, &result->warp_seconds,
                      &result->motion_warped);
    if (!result->rotated) {
      result->rotation_failed = true;
      result->rotation_unknown = why;
      result->rotation_consequence =
          settings_.warm_start && averaging
              ? "cold start, input averages restarted"
              : (settings_.warm_start ? "cold start"
                                      : "input averages restarted");
    }
  }
  // Aligned with the previous frame: by the rotation, or taken as still.
  const bool aligned =
      continuous &&
      (rotation.kind == FrameRotation::Kind::kStill || result->rotated);
  const bool warm = settings_.warm_start && aligned;
  // This frame's samples join the previous frames' averages (else restart).
  result->inputs_averaged = averaging && aligned && averages_current_;
  if (averaging) {
    averageInputs(frame, rotation, result->rotated, result->inputs_averaged,
                  &result->average_seconds);
  } else {
    averages_current_ = false;
  }
  result->budget_reserve_seconds = overrun_reserve_s_;
  solve(frame, warm || result->stream_started, started);
  const auto checks_start = std::chrono::steady_clock::now();
  if (result->stream_started) {
    result->note = streamStartNote(result->restart_reason);
  }
  const std::size_t bad_pixels = nonUnitPixels(state_.normals);
  if (bad_pixels > 0) {
    // Never given out: a fused map holds a unit normal at every pixel.
    reset();
    std::ostringstream text;
    text << name_ << ": the solve gave " << bad_pixels << " of "
         << state_.normals.pixelCount()
         << " pixels without a finite unit normal (K, the inputs or the "
            "settings are degenerate); frame skipped, stream reset";
    throw Error(text.str());
  }
  keepDepth(depth_m, frame);
  has_previous_ = true;
  previous_stamp_ns_ = stamp_ns;
  previous_K_ = frame.K;
  ++frames_fused_;
  // What the checks after the solve took: reserved in the next budget.
  checks_s_ = secondsSince(checks_start);
  // Until endFrame() says more: the frame's time so far.
  previous_seconds_ = secondsSince(started);
}

void StreamFuser::keepDepth(const ScalarMap* depth_m,
                            const FusionProblem& frame) {
  has_previous_depth_ = settings_.warm_start && depth_m != nullptr &&
                        depth_m->channels() == 1 &&
                        depth_m->sameSize(frame.image);
  if (!has_previous_depth_) return;
  // Copied into buffers of the stream's size: no allocation once running.
  previous_depth_m_.resize(depth_m->width(), depth_m->height(), 1);
  std::copy(depth_m->data(), depth_m->data() + depth_m->pixelCount(),
            previous_depth_m_.data());
  motion_scratch_.resize(state_.normals.width(), state_.normals.height(),
                         static_cast<int>(state_.dual_data.size()));
}

double StreamFuser::reserve(int width, int height, int num_inputs,
                            bool with_depth) {
  if (width < 2 || height < 2 || num_inputs < 1) {
    std::ostringstream text;
    text << name_ << ": reserve: a " << width << "x" << height << " frame with "
         << num_inputs << " inputs (at least 2x2 and one input)";
    throw InputError(text.str());
  }
  const auto start = std::chrono::steady_clock::now();
  forget(true);
  // A flat wall facing the camera, grey, seen by every input but for every
  // 8th pixel (holes put a cold start on the pyramid, as a stream's is):
  // the solves take the stream's own paths and end fast.
  FusionProblem frame;
  frame.image.resize(width, height, 3);
  frame.image.fill(0.5f);
  const double f = std::max(width, height);
  frame.K = CameraIntrinsics(f, f, 0.5 * (width - 1), 0.5 * (height - 1));
  NormalInput flat;
  flat.normals.resize(width, height, 3);
  float* z = flat.normals.plane(2);
  for (long i = 0; i < static_cast<long>(width) * height; ++i) {
    z[i] = i % 8 == 0 ? 0.0f : -1.0f;
  }
  frame.inputs.assign(static_cast<std::size_t>(num_inputs), flat);
  const int threads = resolveThreadCount(solver_.settings().num_threads);
  if (settings_.temporal.enabled()) {
    // Started, then carried by a rotation (its scratch).
    std::vector<NormalInput> inputs = frame.inputs;
    for (const Mat3* R : {static_cast<const Mat3*>(nullptr), &kIdentity3}) {
      temporal_.apply(inputs, frame.K, R, settings_.temporal, threads);
    }
  }
  solve(frame, settings_.warm_start, std::chrono::steady_clock::now());
  if (settings_.warm_start) {
    // The cold start once more, its memory now in place and its budget
    // spent at its first chunk: what its tail takes, every finer level left
    // out (the solver sets that aside in the next cold start's budget), is
    // then at least what the stream's own will take.
    state_.clearKeepingCapacity();
    solve(frame, true,
          std::chrono::steady_clock::now() - std::chrono::hours(1));
    // The flat frame refines nothing: room for a quarter of the pixels (a
    // live frame refines its map's edges and changes, mostly far fewer).
    solver_.reserveRefinement(width, height, num_inputs,
                              width * height / kReservedRefinedShare);
    const DualWarp dual_warp = settings_.dual_warp.value_or(DualWarp::kRotate);
    if (with_depth) {
      const ScalarMap depth_m(width, height, 1, 1.0f);
      keepDepth(&depth_m, frame);
      warpStateByMotion(state_, previous_depth_m_, frame.K, Pose(),
                        motion_scratch_, threads, dual_warp);
    }
    warpStateByRotation(state_, frame.K, kIdentity3, warp_scratch_, threads,
                        dual_warp);
    solve(frame, true, std::chrono::steady_clock::now());
    // The checks after a solve, timed for the first frame's budget.
    const auto checks_start = std::chrono::steady_clock::now();
    if (nonUnitPixels(state_.normals) == 0) {
      checks_s_ = secondsSince(checks_start);
    }
  }
  // Forgotten, the memory kept: the next frame starts the stream.
  forget(true);
  report_ = SolveReport();
  return secondsSince(start);
}

std::size_t StreamFuser::bytesHeld() const {
  return solver_.bytesHeld() + state_.bytesHeld() + warp_scratch_.bytesHeld() +
         motion_scratch_.bytesHeld() + previous_depth_m_.bytesHeld() +
         temporal_.bytesHeld();
}

double StreamFuser::endFrame(double encode_seconds) {
  // A slow running estimate: one frame's hiccup does not halve the next
  // frame's solve.
  encode_estimate_s_ = frames_fused_ == 1
                           ? encode_seconds
                           : 0.8 * encode_estimate_s_ + 0.2 * encode_seconds;
  const double frame_seconds = secondsSince(frame_started_);
  previous_seconds_ = frame_seconds;
  // The overrun reserve tracks the kBudgetQuantile quantile of the frames'
  // overruns (a stochastic quantile estimate): up by q steps after a frame
  // over the budget, down by 1 - q steps after one within, so that about
  // that share of frames keeps the budget whatever the machine's load.
  const double budget_s = 1e-3 * solver_.settings().time_budget_ms;
  if (budget_s > 0.0 && !report_.cold_start_budget_used) {
    constexpr double kBudgetQuantile = 0.98, kStepS = 1e-3;
    overrun_reserve_s_ += frame_seconds > budget_s
                              ? kStepS * kBudgetQuantile
                              : -kStepS * (1.0 - kBudgetQuantile);
    overrun_reserve_s_ =
        std::min(std::max(overrun_reserve_s_, 0.0), 0.5 * budget_s);
  }
  return frame_seconds;
}

}  // namespace normal_fusion
