// The solver behind Solver: its buffers, kept from frame to frame, and the
// outer loop of docs/algorithm.md over them (solver.cpp: the solve and its
// levels; solver_outer_loop.cpp: majorize-minimize at one level and the warm
// start's local refinement; solver_report.cpp: the report and the memory).
#pragma once

#include <array>
#include <atomic>
#include <chrono>
#include <vector>

#include "normal_fusion/detail/deadline.h"
#include "normal_fusion/detail/dynamic_guidance.h"
#include "normal_fusion/detail/face_correction.h"
#include "normal_fusion/detail/kernel_backend.h"
#include "normal_fusion/detail/solver_internal.h"
#include "normal_fusion/solver.h"

namespace normal_fusion {

namespace solver_constants {

/// Iterations per thread per sweep of the fast backend's temporal blocking.
constexpr int kBlockDepth = 6;
/// Pyramid depth chosen when pyramid_levels = 0 and more than 0.5% of the
/// pixels have no valid observation.
constexpr int kAutoPyramidLevels = 5;
/// Outer steps and relative tolerance of the coarser pyramid levels.
constexpr int kCoarseOuterSteps = 4;
constexpr double kCoarseTolerance = 1e-3;
/// Step balance of the coarser levels (SolverSettings::step_balance is for
/// the finest): they exist to carry normals far, into the holes of sparse
/// inputs, in few iterations, so the normals keep the larger steps
/// (docs/experiments/2026-11.md).
constexpr double kCoarseStepBalance = 1.0;
/// Inner iterations per outer step of a warm start's local refinement: its
/// pixels start far from their solution (filled in) and gain from frequent
/// re-linearization.
constexpr int kRefineStepIterations = 5;
/// Step balance of the local refinement (SolverSettings::step_balance is for
/// whole-image iterations): its duals start reset and its filled normals far
/// from their solution, so the normals keep the larger steps
/// (docs/experiments/2026-11.md).
constexpr double kRefineStepBalance = 1.0;
/// Passes of the fill of a warm start's unknown pixels (each reaches one
/// pixel further from the known ones).
constexpr int kFillPasses = 16;

}  // namespace solver_constants

class SolverImpl {
 public:
  using Clock = std::chrono::steady_clock;

  explicit SolverImpl(const SolverSettings& settings) : settings_(settings) {
    settings_.validate();
  }

  SolverSettings settings_;
  /// The inputs' noise gains kept for the warm frames (cleared with new
  /// settings).
  internal::NoiseGainMemory noise_gains_;

  /// Solves into `report` (its vectors keep their capacity: no allocation in
  /// steady state when the caller reuses it).
  void solve(const FusionProblem& problem, SolverState& out, bool warm,
             SolveReport& report);

  /// Solver::bytesHeld().
  std::size_t bytesHeld() const;

  /// Sizes the local refinement's buffers for `active_pixels` refined
  /// pixels: on a cold start for the warm starts to come, and from
  /// Solver::reserveRefinement().
  /// `with_faces`: the face correction's buffers too (a cold solve leaves
  /// them to its stream's first warm frame or to Solver::reserveRefinement).
  void preallocateRefinement(int W, int H, int num_inputs, int active_pixels,
                             bool with_faces);

  /// Solver::requestCancel(): set by the caller (any thread), read by the
  /// solve, never cleared by it.
  std::atomic<bool> cancel_request_{false};
  static_assert(std::atomic<bool>::is_always_lock_free,
                "requestCancel() must be a lock-free store (signal handlers)");

  /// Solver::setBudgetStart().
  Clock::time_point budget_start_;
  bool has_budget_start_ = false;

 private:
  /// What the inner iterations of one outer step did.
  struct StepIterations {
    int done = 0;              ///< iterations run (whole chunks)
    bool out_of_time = false;  ///< the deadline leaves no room for more
  };

  // solver.cpp: the solve.

  /// Prepares the finest level and checks it; false when cancelled meanwhile.
  /// `warm`: a live warm frame, which may use the kept noise gains.
  bool prepare(const FusionProblem& problem, bool warm, SolveReport& report);
  /// The coarser levels of a cold start (automatic: always when `budgeted`);
  /// returns how many levels there are.
  int buildPyramid(bool budgeted);
  /// Starts a level without a warm start: the upsampled coarser result or
  /// the cold start, duals 0.
  void startCold(const internal::PreparedLevel& level, bool from_coarser);
  /// Whether the whole-image steps of a level run (a warm start's finest
  /// level under a time budget may leave them out, and a stream's cold start
  /// out of its budget those of the levels `from_coarser`).
  bool levelRuns(bool warm_finest, bool from_coarser, SolveReport& report);
  /// The accepted normals and the duals handed to `out`.
  void writeOutput(SolverState& out, int width, int height, int num_inputs);
  /// Step sizes for L data terms; throws ParameterError when explicit steps
  /// break tau * sigma * (8 + L) < 1. `balance` scales the automatic steps
  /// (SolverSettings::step_balance).
  internal::InnerParams stepSizes(int num_inputs, double balance) const;
  /// Step sizes and model constants of the inner iterations at one level.
  internal::InnerParams innerParams(const internal::PreparedLevel& level,
                                    double balance) const;
  internal::EnergyTerms energyTerms() const {
    return {settings_.huber_eps, settings_.penalty, settings_.tgv_alpha0,
            &state_.tgv};
  }
  /// True once this solve has seen the cancel request (latched for the rest
  /// of the solve, so that a request withdrawn meanwhile does not undo what
  /// it stopped).
  bool cancelled() {
    if (!cancelled_ && cancel_request_.load(std::memory_order_relaxed)) {
      cancelled_ = true;
    }
    return cancelled_;
  }

  // solver_outer_loop.cpp: the iterations.

  /// Majorize-minimize at one level: inner iterations on the tangent plane at
  /// n0, then n0 <- n / |n| when that lowers E (never raises it).
  void runLevel(const internal::PreparedLevel& level, bool finest,
                SolveReport& report);
  /// The inner iterations of one outer step (`target`), in chunks that the
  /// deadline sizes; `seconds_per_iteration` is what the last chunk took.
  StepIterations runStepIterations(const internal::PreparedLevel& level,
                                   const internal::InnerParams& params,
                                   int target, double finish_seconds,
                                   double& seconds_per_iteration);
  /// The warm start at the finest level: the previous state made usable, the
  /// pixels to refine found and filled, then refined (refineActive()).
  void startWarm(const internal::PreparedLevel& level, SolverState& out,
                 SolveReport& report);
  /// Local refinement of a warm start (SolverSettings::warm_refine_*):
  /// majorize-minimize on the active pixels, every other pixel fixed.
  void refineActive(const internal::PreparedLevel& level, SolveReport& report);
  /// Sets the face correction's time estimates for this level's size and
  /// thread count (kept while they stay the same).
  void timeFacesFor(const internal::PreparedLevel& level);
  /// What the refinement leaves for the face correction: its set-up and one
  /// step with kFaceMargin when it is due (warm_face_period), else 0.
  double faceReserveSeconds() const;
  /// The face correction after it (SolverSettings::warm_face_steps).
  void correctFaces(const internal::PreparedLevel& level, SolveReport& report);

  // solver_report.cpp: the report and the buffers.

  /// Resets the report, keeping its vectors' capacity.
  void resetReport(SolveReport& report) const;
  /// Appends E of the finest level and when it was reached.
  void recordEnergy(SolveReport& report, double energy) const;
  /// The report of a solve cancelled before its levels started (no
  /// iterations, no energies, the state untouched).
  void finishCancelledBeforeStart(SolveReport& report,
                                  Clock::time_point start) const;
  /// The final energy, the cancellation and the time of a finished solve.
  void finishReport(SolveReport& report, Clock::time_point start) const;
  /// Gives back the memory of the buffers that every level of a solve
  /// shares, and of those of the warm start, when they were sized for a much
  /// larger image than this one (W x H): more than 4 times what it needs
  /// (PlanarImage::resize()'s rule; the same size never reallocates). The
  /// finest level's own buffers follow the rule as they are prepared.
  void fitBuffers(int W, int H);
  /// Releases the pyramid levels past `used` that a much larger image left:
  /// more than 4 times the pixels this image's level of that depth has. (A
  /// stream of one size keeps its cold start's levels for the next one.)
  void releaseUnusedLevels(int used);

  const internal::KernelBackend* backend_ = &internal::fastBackend();
  internal::Deadline deadline_;
  internal::IterationState state_;
  PlanarImage candidate_;
  std::vector<unsigned char> edge_scratch_map_;  ///< markMapEdges(), fill
  std::vector<int> fill_pending_;                ///< fillUnknownPixels()
  std::vector<unsigned char> unknown_;  ///< pixels the warm start lacked
  internal::RefinementBuffers refine_;  ///< the local refinement's buffers
  /// What the last stream's cold start under cold_start_budget_ms spent
  /// outside its levels' iterations after them: the levels it left out, its
  /// finest level's start and the output. Set aside in the next one's
  /// budget.
  double cold_start_tail_seconds_ = 0.0;
  double level_seconds_ = 0.0;  ///< least cost of the finest level, measured
  /// Finest first; grown (releaseUnusedLevels() frees what a larger image
  /// left).
  std::vector<internal::PreparedLevel> levels_;
  PlanarImage coarse_result_;
  /// Scratch of the filtered cold start (cold_filter_radius > 0).
  PlanarImage cold_filter_;
  /// The duals of the last coarser level (SolverSettings::prolong_duals).
  PlanarImage coarse_p_h_, coarse_p_v_;
  std::vector<PlanarImage> coarse_q_;
  internal::EdgeWeightScratch edge_scratch_;
  internal::DynamicGuidance guidance_;  ///< runLevel(): guided edge weights
  Clock::time_point solve_start_;
  bool cancelled_ = false;  ///< cancelled(): this solve saw the request
  /// This solve warm-starts from a state still converging: whole-image
  /// steps instead of the local refinement.
  bool warm_converging_ = false;
  int threads_ = 1;
  int remaining_inner_ = 0;
  /// The local refinement's thread count per step (kept across frames).
  internal::RefineThreadChooser refine_threads_;
  internal::FaceCorrection faces_;  ///< correctFaces()' state and buffers
  /// What the last face-correction set-up (faces and E) and step took (for
  /// the budget; 0: not timed yet).
  double face_begin_seconds_ = 0.0;
  double face_step_seconds_ = 0.0;
  /// The fastest of those times (0: none yet): the estimates never shrink
  /// below them. Measured for one size and thread count (face_timed_for_).
  double face_begin_fastest_ = 0.0;
  double face_step_fastest_ = 0.0;
  std::array<int, 3> face_timed_for_{{0, 0, 0}};
  /// Warm frames since the correction last ran (its set-up and a step, or
  /// a set-up that found no face): SolverSettings::warm_face_period.
  int frames_without_face_step_ = 0;
  /// This frame's refinement held time back for the correction's set-up
  /// and first step, which then run without checking the deadline.
  bool face_time_reserved_ = false;
  /// The safety factor on the correction's last times, what they shrink by
  /// on each frame that skips it, and the share of the budget it needs left
  /// before it is first timed.
  static constexpr double kFaceMargin = 1.25;
  static constexpr double kFaceEstimateDecay = 0.9;
  static constexpr double kFaceFirstShare = 0.3;
  /// A due correction's time is held back only when the frame has this many
  /// times it left where the refinement begins.
  static constexpr double kFaceReserveRoom = 2.0;
};

}  // namespace normal_fusion
