// The solver's public API and the solve of one frame: input preparation, the
// coarse-to-fine pyramid, each level's start (cold, upsampled or warm) and
// its majorize-minimize iterations (solver_outer_loop.cpp), on the kernel
// backend of SolverSettings::backend (detail/kernel_backend.h).
#include "normal_fusion/solver.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <utility>

#include "normal_fusion/detail/solver_levels.h"
#include "normal_fusion/detail/tgv.h"
#include "normal_fusion/errors.h"
#include "solver_impl.h"

namespace normal_fusion {

using internal::InnerParams;
using internal::PreparedLevel;
using namespace solver_constants;

namespace {

/// Seconds from `t` to now.
double secondsSince(SolverImpl::Clock::time_point t) {
  return std::chrono::duration<double>(SolverImpl::Clock::now() - t).count();
}

}  // namespace

void SolverImpl::solve(const FusionProblem& problem, SolverState& out,
                       bool warm, SolveReport& report) {
  const Clock::time_point start = Clock::now();
  solve_start_ = start;
  const Clock::time_point budget_start =
      has_budget_start_ ? budget_start_ : start;
  has_budget_start_ = false;
  deadline_.start(budget_start, settings_.time_budget_ms);
  threads_ = resolveThreadCount(settings_.num_threads);
  if (refine_threads_.maxThreads() != threads_) refine_threads_.reset(threads_);
  // The second-order term runs on the reference backend only.
  backend_ = settings_.tgv_alpha0 > 0.0
                 ? &internal::tgvReferenceBackend()
                 : &internal::kernelBackend(settings_.backend);
  cancelled_ = false;
  resetReport(report);

  // Cancelled before the levels start (a request made before the call, or
  // while the inputs are prepared): `out` is unchanged.
  // A live frame (warm, under a time budget) may use the inputs' noise
  // gains of the frames before it; without a budget every frame estimates
  // its own, so that it solves the same E as its cold solve would.
  const bool live_warm =
      warm && settings_.time_budget_ms > 0.0 &&
      out.compatible(problem.image.width(), problem.image.height(),
                     static_cast<int>(problem.inputs.size()));
  if (cancelled() || !prepare(problem, live_warm, report)) {
    finishCancelledBeforeStart(report, start);
    return;
  }
  const PreparedLevel& finest = levels_[0];
  const int W = finest.width, H = finest.height, L = finest.num_inputs;
  const bool use_warm = warm && out.compatible(W, H, L);
  if (warm && !use_warm && deadline_.active()) {
    // A stream's cold start (a warm start asked for, nothing usable to start
    // from) under a frame budget: its own budget (none by default), since
    // the warm frames after it carry its map on. Its levels end early by
    // what the last one's tail took (the levels left out, the finest level's
    // start and the output), so that the frame ends within it (at most half
    // of it).
    const double budget_ms = settings_.cold_start_budget_ms;
    report.cold_start_tail_reserved_seconds =
        budget_ms > 0.0 ? std::min(cold_start_tail_seconds_, 0.5e-3 * budget_ms)
                        : 0.0;
    deadline_.start(budget_start,
                    budget_ms - 1e3 * report.cold_start_tail_reserved_seconds);
    report.cold_start_budget_used = true;
  }
  // A request made while the inputs were prepared ends the solve before the
  // refinement's buffers and the pyramid are sized (at 1920x1440 they take
  // a noticeable share of the deadline a cancel is held to).
  if (cancelled()) {
    finishCancelledBeforeStart(report, start);
    return;
  }
  if (!use_warm && settings_.warm_refine_iterations > 0) {
    // For 1/16 of the pixels; they grow if a frame needs more.
    preallocateRefinement(W, H, L, W * H / 16, false);
  }
  report.warm_started = use_warm;
  warm_converging_ = use_warm && out.converging;
  remaining_inner_ = settings_.max_total_inner_iterations;

  // Coarse-to-fine on a cold start (always under a budget: the coarser
  // levels' result, upsampled, is a far better anytime answer than the raw
  // inputs).
  const int num_levels = use_warm ? 1 : buildPyramid(deadline_.active());
  releaseUnusedLevels(num_levels);
  report.pyramid_levels = num_levels;
  if (cancelled()) {
    finishCancelledBeforeStart(report, start);
    return;
  }
  report.prepare_seconds = secondsSince(start);

  double tail_seconds = 0.0;  // see cold_start_tail_seconds_
  for (int li = num_levels - 1; li >= 0; --li) {
    // Cancelled before the finest level starts: `out` is unchanged, since
    // that start writes every buffer of the problem's size (fresh memory
    // on a first solve: far longer than an iteration at large sizes).
    if (li + 1 < num_levels && cancelled()) {
      finishReport(report, start);
      return;
    }
    const Clock::time_point level_start = Clock::now();
    const PreparedLevel& level = levels_[li];
    // The buffers' first sizing (fresh memory) stops on a request too.
    if (!state_.resize(level.width, level.height, level.num_inputs,
                       &cancel_request_)) {
      cancelled_ = true;
      finishReport(report, start);
      return;
    }
    const bool warm_finest = li == 0 && use_warm;
    const bool from_coarser = li + 1 < num_levels;
    if (warm_finest) {
      startWarm(level, out, report);
    } else {
      startCold(level, from_coarser);
    }
    // v and r start from 0 at every level (E(n0, 0) is the first-order E).
    if (settings_.tgv_alpha0 > 0.0) {
      state_.tgv.reset(level.width, level.height);
    } else if (!state_.tgv.empty()) {
      state_.tgv.release();
    }
    const double start_seconds = secondsSince(level_start);
    const bool runs =
        !cancelled() && levelRuns(warm_finest, from_coarser, report);
    if (runs) runLevel(level, li == 0, report);
    if (li > 0) {
      coarse_result_ = state_.n0;
      if (settings_.prolong_duals) {
        coarse_p_h_ = state_.p_h;
        coarse_p_v_ = state_.p_v;
        coarse_q_ = state_.q;
      }
    }
    // The tail that follows a cold start's last iterations: every level left
    // out, and the finest level's start.
    if (!runs) {
      tail_seconds += secondsSince(level_start);
    } else if (li == 0) {
      tail_seconds += start_seconds;
    }
  }
  const Clock::time_point output_start = Clock::now();
  writeOutput(out, W, H, L);
  if (!cancelled_ && report.cold_start_budget_used) {
    report.cold_start_tail_seconds = tail_seconds + secondsSince(output_start);
    cold_start_tail_seconds_ = report.cold_start_tail_seconds;
  }
  if (!cancelled_) {
    // A warm state converges when an outer step meets the tolerance or a
    // whole one is rejected (a step the budget cut to a few iterations
    // says little).
    const bool whole_step_rejected =
        report.rejected_outer_steps > 0 &&
        report.inner_iterations >= settings_.inner_iterations;
    out.converging =
        use_warm ? warm_converging_ && !report.converged && !whole_step_rejected
                 : deadline_.active() && report.budget_exhausted &&
                       !report.converged;
  }
  report.still_converging = out.converging;
  finishReport(report, start);
}

bool SolverImpl::prepare(const FusionProblem& problem, bool warm,
                         SolveReport& report) {
  if (levels_.empty()) levels_.resize(1);
  if (!internal::prepareFinestInto(problem, settings_, levels_[0],
                                   edge_scratch_, threads_, &cancel_request_,
                                   &noise_gains_, warm)) {
    cancelled_ = true;
    return false;
  }
  const PreparedLevel& finest = levels_[0];
  const int W = finest.width, H = finest.height;
  if (finest.valid_pixels == 0) {
    throw InputError(
        "inputs: no valid observation in any input (all missing, zero weight "
        "or, in hard visibility mode, facing away from the camera)");
  }
  // Throws on bad explicit steps before the state is touched.
  stepSizes(finest.num_inputs, settings_.step_balance);
  report.num_inputs = finest.num_inputs;
  report.valid_pixels = finest.valid_pixels;
  report.filled_pixels = W * H - finest.valid_pixels;
  fitBuffers(W, H);
  return !cancelled();
}

int SolverImpl::buildPyramid(bool budgeted) {
  const PreparedLevel& finest = levels_[0];
  int wanted = settings_.pyramid_levels;
  if (wanted == 0 && budgeted) {
    wanted = kAutoPyramidLevels;
  } else if (wanted == 0) {
    const double missing =
        1.0 - static_cast<double>(finest.valid_pixels) /
                  (static_cast<double>(finest.width) * finest.height);
    wanted = missing > 0.005 ? kAutoPyramidLevels : 1;
  }
  int num_levels = 1;
  while (num_levels < wanted &&
         std::min(levels_[num_levels - 1].width,
                  levels_[num_levels - 1].height) >= 32 &&
         !cancelled()) {
    if (static_cast<int>(levels_.size()) <= num_levels) levels_.emplace_back();
    internal::downsampleInto(levels_[num_levels - 1], settings_,
                             levels_[num_levels], edge_scratch_, threads_);
    ++num_levels;
  }
  return num_levels;
}

void SolverImpl::startCold(const PreparedLevel& level, bool from_coarser) {
  if (from_coarser) {
    internal::upsampleNormals(coarse_result_, level, settings_.visibility,
                              state_.n0, threads_);
  } else if (settings_.cold_filter_radius > 0) {
    internal::initializeFiltered(level, settings_.visibility,
                                 settings_.cold_filter_radius, cold_filter_,
                                 state_.n0, threads_);
  } else {
    internal::initializeCold(level, settings_.visibility, state_.n0, threads_);
  }
  if (from_coarser && settings_.prolong_duals) {
    internal::upsampleDuals(coarse_p_h_, coarse_p_v_, coarse_q_, level, state_,
                            threads_);
    return;
  }
  state_.p_h.fill(0.0f);
  state_.p_v.fill(0.0f);
  for (PlanarImage& q : state_.q) q.fill(0.0f);
}

bool SolverImpl::levelRuns(bool warm_finest, bool from_coarser,
                           SolveReport& report) {
  if (!warm_finest) {
    // A stream's cold start whose budget ran out before this finer level
    // began: the upsampled coarser result is the frame's answer, since the
    // level's first chunk and closing energy would only overrun the frame
    // (its energies are then not measured).
    if (from_coarser && report.cold_start_budget_used && deadline_.active() &&
        deadline_.secondsLeft() <= 0.0) {
      report.budget_exhausted = true;
      return false;
    }
    return true;
  }
  if (settings_.warm_refine_iterations > 0 && deadline_.active() &&
      !warm_converging_) {
    // Live (a time budget and the local refinement): the frame's time goes
    // to the refinement, and the frame ends when it does. The whole-image
    // steps after it gained nothing and, started near the deadline, overran
    // it (docs/experiments/2026-11.md). Their energies are not measured.
    // A state still converging (SolverState::converging) is iterated on
    // over the whole image instead, as far as the budget allows.
    return false;
  }
  if (!deadline_.allowsLevel(level_seconds_)) {
    // A warm start under a time budget without the refinement: what is left
    // of the budget would not hold a whole-image step, which is left out
    // (its energies are then not measured). A state still converging halves
    // the estimate, so that one slow measurement does not leave every later
    // frame without steps.
    if (warm_converging_) level_seconds_ *= 0.5;
    report.budget_exhausted = true;
    return false;
  }
  return true;
}

void SolverImpl::writeOutput(SolverState& out, int W, int H, int L) {
  // The accepted (unit) normals and the duals for the next frame, swapped
  // out (the state's old buffers become the next solve's scratch). The
  // state's buffers are sized first, so that the iteration state keeps sized
  // buffers: a first solve into an empty state allocates here, not the next
  // (warm) frame. (Not when cancelled: the next solve sizes them.)
  out.dual_data.resize(L);
  if (!cancelled_) {
    out.normals.resize(W, H, 3);
    out.dual_h.resize(W, H, 3);
    out.dual_v.resize(W, H, 3);
    for (PlanarImage& q : out.dual_data) q.resize(W, H, 3);
  }
  std::swap(out.normals, state_.n0);
  std::swap(out.dual_h, state_.p_h);
  std::swap(out.dual_v, state_.p_v);
  for (int l = 0; l < L; ++l) std::swap(out.dual_data[l], state_.q[l]);
}

InnerParams SolverImpl::stepSizes(int num_inputs, double balance) const {
  InnerParams params;
  const double K_norm2 =
      (settings_.tgv_alpha0 > 0.0 ? internal::kTgvOperatorNorm2 : 8.0) +
      num_inputs;
  if (settings_.tau > 0.0) {
    if (settings_.tau * settings_.sigma * K_norm2 >= 1.0) {
      std::ostringstream msg;
      msg << "settings tau = " << settings_.tau
          << ", sigma = " << settings_.sigma
          << ": expected tau * sigma * (8 + L) < 1 (12 + L with tgv_alpha0 > "
             "0), got "
          << settings_.tau * settings_.sigma * K_norm2;
      throw ParameterError(msg.str());
    }
    params.tau = static_cast<float>(settings_.tau);
    params.sigma = params.sigma_data = static_cast<float>(settings_.sigma);
    return params;  // explicit steps are not balanced
  }
  if (settings_.preconditioning) {
    // Diagonal preconditioning (Pock & Chambolle 2011, alpha = 1): tau =
    // 1 / (column sums of |K|) = 1 / (4 + L), sigma = 1 / (row sums) = 1/2
    // for the differences and 1 for the data terms.
    params.tau = static_cast<float>(1.0 / (4.0 + num_inputs));
    params.sigma = 0.5f;
    params.sigma_data = 1.0f;
  } else {
    params.tau = params.sigma = params.sigma_data =
        static_cast<float>(0.99 / std::sqrt(K_norm2));
  }
  // The normals' and the duals' share of the step (tau * sigma kept).
  params.tau = static_cast<float>(params.tau * balance);
  params.sigma = static_cast<float>(params.sigma / balance);
  params.sigma_data = static_cast<float>(params.sigma_data / balance);
  return params;
}

InnerParams SolverImpl::innerParams(const PreparedLevel& level,
                                    double balance) const {
  InnerParams params = stepSizes(level.num_inputs, balance);
  params.huber_eps = static_cast<float>(settings_.huber_eps);
  params.penalty = settings_.penalty;
  params.soft_visibility = settings_.visibility == VisibilityMode::kSoft;
  params.num_threads = threads_;
  params.block_depth = kBlockDepth;
  params.cancel = &cancel_request_;
  internal::setTgvSteps(settings_.tgv_alpha0,
                        settings_.preconditioning && !(settings_.tau > 0.0),
                        balance, params);
  return params;
}

Solver::Solver(const SolverSettings& settings)
    : impl_(std::make_unique<SolverImpl>(settings)) {}
Solver::~Solver() = default;
Solver::Solver(Solver&&) noexcept = default;
Solver& Solver::operator=(Solver&&) noexcept = default;

void Solver::setSettings(const SolverSettings& settings) {
  settings.validate();
  impl_->settings_ = settings;
  // Gains estimated under other settings (radii, model) may not hold for
  // these.
  impl_->noise_gains_.clear();
}

const SolverSettings& Solver::settings() const { return impl_->settings_; }

SolveReport Solver::solve(const FusionProblem& problem, SolverState& state,
                          bool warm_start) {
  SolveReport report;
  impl_->solve(problem, state, warm_start, report);
  return report;
}

void Solver::requestCancel() noexcept {
  impl_->cancel_request_.store(true, std::memory_order_relaxed);
}

void Solver::clearCancel() noexcept {
  impl_->cancel_request_.store(false, std::memory_order_relaxed);
}

bool Solver::cancelRequested() const noexcept {
  return impl_->cancel_request_.load(std::memory_order_relaxed);
}

std::size_t Solver::bytesHeld() const { return impl_->bytesHeld(); }

void Solver::reserveRefinement(int width, int height, int num_inputs,
                               int active_pixels) {
  if (width < 1 || height < 1 || num_inputs < 1) {
    std::ostringstream text;
    text << "reserveRefinement: a " << width << "x" << height
         << " problem with " << num_inputs << " inputs";
    throw InputError(text.str());
  }
  impl_->preallocateRefinement(width, height, num_inputs,
                               std::clamp(active_pixels, 0, width * height),
                               true);
}

void Solver::setBudgetStart(std::chrono::steady_clock::time_point frame_start) {
  impl_->budget_start_ = frame_start;
  impl_->has_budget_start_ = true;
}

void Solver::solve(const FusionProblem& problem, SolverState& state,
                   bool warm_start, SolveReport& report) {
  impl_->solve(problem, state, warm_start, report);
}

NormalMap Solver::solve(const FusionProblem& problem, SolveReport* report) {
  SolverState state;
  SolveReport r;
  impl_->solve(problem, state, false, r);
  if (report != nullptr) *report = r;
  return std::move(state.normals);
}

}  // namespace normal_fusion
