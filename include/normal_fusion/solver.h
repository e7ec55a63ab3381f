// The variational regularizer and fuser of surface-normal maps
// (Huber-TV on unit vectors, majorize-minimize, Chambolle-Pock).
#pragma once

#include <chrono>
#include <memory>
#include <vector>

#include "normal_fusion/settings.h"
#include "normal_fusion/types.h"

namespace normal_fusion {

/// One normal-map input of a fusion problem.
struct NormalInput {
  NormalMap normals;     ///< 3 planes, as the producer gives them
  ScalarMap confidence;  ///< optional 1 plane in [0, 1] (empty = 1 everywhere)
  double weight = 1.0;   ///< global weight of this data term (>= 0)
  Orientation orientation;  ///< applied on input: n_optical = M n_input
};

/// What one frame gives the solver.
struct FusionProblem {
  ColorImage image;                 ///< guide image, 1 or 3 planes in [0, 1]
  CameraIntrinsics K;               ///< intrinsics of the image
  std::vector<NormalInput> inputs;  ///< L >= 1 inputs, in priority order
};

/// Solver state carried from frame to frame (warm start): the normals and all
/// dual variables, in global 3-D coordinates.
struct SolverState {
  NormalMap normals;                   ///< 3 planes, unit length
  PlanarImage dual_h;                  ///< p_h, 3 planes
  PlanarImage dual_v;                  ///< p_v, 3 planes
  std::vector<PlanarImage> dual_data;  ///< q_l, 3 planes each
  /// The normals come from a solve that its time budget cut short (a
  /// stream's anytime cold start): a warm start under a time budget then
  /// iterates the whole image instead of refining locally, until an outer
  /// step no longer lowers the energy or the tolerance is met.
  bool converging = false;

  /// True when the state can warm-start a problem of this size and input count.
  bool compatible(int width, int height, int num_inputs) const;
  /// Sizes every buffer for that problem (allocates only when a size
  /// changes): e.g. a warp's scratch state before the stream starts, so that
  /// the first warm frame does not pay for it.
  void resize(int width, int height, int num_inputs);
  void clear();
  /// Empty, as after clear(), but the buffers keep their memory: sized
  /// again for the same problem (the next solve's output), they allocate
  /// nothing.
  void clearKeepingCapacity();
  /// Bytes of memory its buffers hold (their capacity).
  std::size_t bytesHeld() const;
};

/// What a solve did.
struct SolveReport {
  int outer_iterations = 0;  ///< outer steps at the finest level
  int rejected_outer_steps =
      0;  ///< steps whose normalized result raised E (kept n0)
  int inner_iterations = 0;  ///< Chambolle-Pock iterations at the finest level
  int coarse_inner_iterations =
      0;                        ///< iterations on the coarser pyramid levels
  int inconsistent_pixels = 0;  ///< warm-start pixels the inputs contradict
  int edge_pixels = 0;        ///< warm-start pixels at an edge of the warm map
  int refined_pixels = 0;     ///< pixels of the warm start's local refinement
  int refine_iterations = 0;  ///< its inner iterations (on those pixels only)
  /// Of these, the ones run on one thread instead of num_threads because
  /// one was measured to be faster (SolverSettings::adaptive_refine_threads).
  int refine_single_thread_iterations = 0;
  /// The face correction after it (SolverSettings::warm_face_steps): the
  /// faces it turned, its steps (and of these the ones kept), by how much
  /// it lowered E and its time.
  int corrected_faces = 0;
  int face_steps = 0;
  int face_steps_accepted = 0;
  double face_energy_decrease = 0.0;
  double face_seconds = 0.0;
  /// E at the finest level: start, then each accepted outer step. Empty
  /// (and initial_energy, final_energy NaN) when the whole-image step was
  /// left out after a warm start's local refinement: always under a time
  /// budget (live), otherwise when the refinement used up the iterations'
  /// time; and when a stream's cold start ran out of cold_start_budget_ms
  /// before its finest level began.
  std::vector<double> energies;
  std::vector<double> energy_seconds;  ///< when each of `energies` was reached,
                                       ///< since the solve began
  double initial_energy = 0.0;
  double final_energy = 0.0;
  double seconds = 0.0;
  /// Where `seconds` went: preparing the inputs (all pyramid levels), making
  /// the warm start usable (sanitizing, finding the pixels to refine, filling
  /// the unknown ones) and the local refinement's iterations. The rest is the
  /// whole-image levels and the output.
  double prepare_seconds = 0.0;
  double warm_start_seconds = 0.0;
  double refine_seconds = 0.0;
  bool warm_started = false;
  bool converged = false;         ///< stopped on the relative tolerance
  bool budget_exhausted = false;  ///< stopped on the wall-clock budget
  /// Stopped by Solver::requestCancel(): the frame is unfinished (not to be
  /// published); see there for what the state then holds.
  bool cancelled = false;
  /// A stream's cold start under time_budget_ms: the solve ran under
  /// SolverSettings::cold_start_budget_ms instead.
  bool cold_start_budget_used = false;
  /// Of that budget, the seconds set aside for the solve's tail (the levels
  /// left out once the budget ran out, the finest level's start and the
  /// output, as the last such cold start took them: its levels end that
  /// much earlier; at most half of the budget), and what this one's tail
  /// took (seconds; 0 when no budget was used).
  double cold_start_tail_reserved_seconds = 0.0;
  double cold_start_tail_seconds = 0.0;
  /// The state handed on is not yet converged (SolverState::converging).
  bool still_converging = false;
  int pyramid_levels = 1;
  int num_inputs = 0;
  int valid_pixels = 0;   ///< pixels with at least one usable observation
  int filled_pixels = 0;  ///< pixels without any (filled in by the regularizer)
};

class SolverImpl;

/// Solves frame after frame, reusing its buffers. Not thread-safe: one solve at
/// a time per instance; only the cancellation below may be called from other
/// threads.
///
/// Memory: buffers are sized on the first frame of a size and reused, so a
/// stream of frames of one size allocates nothing once running; a frame
/// much smaller than the one before (below a quarter of the values a buffer
/// has room for) gives the larger buffers' memory back (PlanarImage::resize()).
class Solver {
 public:
  explicit Solver(const SolverSettings& settings = SolverSettings());
  ~Solver();
  Solver(Solver&&) noexcept;
  Solver& operator=(Solver&&) noexcept;

  /// Validates and replaces the settings (throws ParameterError, keeping the
  /// old ones). Takes effect on the next solve.
  void setSettings(const SolverSettings& settings);
  const SolverSettings& settings() const;

  /// Solves one frame. On return `state` holds the fused unit normals (every
  /// pixel) and the duals. With `warm_start` and a compatible `state`, starts
  /// from it; otherwise cold-starts (see SolveReport::warm_started; with
  /// `warm_start` that is a stream's cold start, which runs under
  /// SolverSettings::cold_start_budget_ms).
  /// Throws InputError on bad input; `state` is then left unchanged.
  SolveReport solve(const FusionProblem& problem, SolverState& state,
                    bool warm_start = false);

  /// The same, filling a caller-owned report: with the report, the state and
  /// the problem's buffers reused, a steady stream of frames of one size
  /// allocates no heap memory inside the solver.
  void solve(const FusionProblem& problem, SolverState& state, bool warm_start,
             SolveReport& report);

  /// The next solve's time budget (SolverSettings::time_budget_ms) counts
  /// from `frame_start` instead of from the call, so that work done for the
  /// frame before the solve (the warp of the state) is inside the budget.
  /// Applies to that one solve.
  void setBudgetStart(std::chrono::steady_clock::time_point frame_start);

  /// Convenience: cold start, returns the fused normals (empty when
  /// cancelled before the finest level began; see requestCancel()).
  NormalMap solve(const FusionProblem& problem, SolveReport* report = nullptr);

  /// Cancellation. Asks the solve in progress to stop, and every later
  /// solve to stop at once, until clearCancel(). Thread-safe, from any
  /// thread (a lock-free atomic store: also from a signal handler).
  ///
  /// A solve reads the request before it starts, between the steps of the
  /// input preparation, and inside the inner iterations of every pyramid
  /// level, of the outer loop and of the warm start's local refinement
  /// (every row of the fast backend's sweeps, every iteration of the
  /// reference backend), so it returns within about one iteration of the
  /// request. It then returns normally (no exception: the state stays
  /// usable) with SolveReport::cancelled set, and:
  /// - before the finest level began (requested before the call, while
  ///   the inputs and the pyramid were prepared, or while a coarser level
  ///   ran): with `state` unchanged (a request before the call: at once,
  ///   the problem not even validated);
  /// - later: `state` holds the problem's size, unit normals and finite
  ///   duals: the last accepted outer step of the finest level, or the
  ///   start it had reached (the warm start as made usable so far, or the
  ///   cold start / the upsampled coarser level). Iterations after that
  ///   step are dropped.
  /// Report entries of what did not run stay 0 (energies empty and NaN when
  /// the finest level's were not measured).
  /// Uncancelled solves are unchanged by the checks (the same bits).
  ///
  /// The solver never withdraws a request itself, in particular not when a
  /// solve starts: a request made just before solve() (e.g. a shutdown
  /// racing the next frame) must stop that solve, and is never lost.
  void requestCancel() noexcept;
  /// Withdraws the request, so that later solves run. The caller decides
  /// when: e.g. the thread that calls solve(), after a cancelled solve
  /// returned and before the next one, to cancel one frame only. A request
  /// that arrives after this call stops the next solve; one withdrawn while
  /// a solve runs may already have stopped it (see its report).
  void clearCancel() noexcept;
  /// True while a request is pending (requestCancel() without clearCancel()).
  bool cancelRequested() const noexcept;

  /// Sizes the local refinement's buffers (warm_refine_iterations) for up
  /// to `active_pixels` refined pixels of a `width` x `height` problem with
  /// `num_inputs` inputs. A cold start sizes them for 1/16 of the pixels;
  /// they grow on their own when a frame refines more. Throws InputError
  /// for an empty size or no input.
  void reserveRefinement(int width, int height, int num_inputs,
                         int active_pixels);

  /// Bytes of memory the solver's own buffers hold (prepared levels,
  /// iteration state, scratch; not the caller's SolverState).
  std::size_t bytesHeld() const;

 private:
  std::unique_ptr<SolverImpl> impl_;
};

/// Checks a problem; throws InputError saying what was expected and what came.
void validateProblem(const FusionProblem& problem);

/// Edge weights w_h, w_v (2 planes: 0 = horizontal, 1 = vertical) of an image.
PlanarImage computeEdgeWeights(const ColorImage& image,
                               const EdgeWeightSettings& settings);

/// The energy E(n) of docs/algorithm.md for the given normals (need not be
/// unit), with the problem's inputs prepared as the solver prepares them
/// (orientation, validity, confidence, hard visibility).
double computeEnergy(const FusionProblem& problem,
                     const SolverSettings& settings, const NormalMap& normals);

}  // namespace normal_fusion
