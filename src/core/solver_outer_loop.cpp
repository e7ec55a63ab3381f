// The outer loop of docs/algorithm.md at one level: majorize-minimize, each
// outer step a run of inner Chambolle-Pock iterations on the tangent plane at
// n0 (in chunks that the deadline sizes) and the projection n0 <- n / |n|
// kept when it lowers E; and the same on the active pixels of a warm start's
// local refinement. The kernels are the backend's (detail/kernel_backend.h).
#include <algorithm>
#include <utility>

#include "normal_fusion/detail/solver_levels.h"
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

/// The last plain primal step n_hat of a relaxed run, into `out`: the
/// primal step left nbar = 2 n_hat - n_old and n = n_old + rho (n_hat -
/// n_old), so n_hat = (n + (1 - rho) nbar) / (2 - rho). It lies in the
/// feasible set C (the relaxed n may not: rho > 1 extrapolates).
void lastPrimalStep(const internal::IterationState& s, float rho,
                    PlanarImage& out, int threads) {
  out.resizeKeepingCapacity(s.n.width(), s.n.height(), 3);
  const long values = static_cast<long>(3 * s.n.pixelCount());
  const float* n = s.n.data();
  const float* nbar = s.nbar.data();
  float* o = out.data();
  const float a = 1.0f - rho, b = 1.0f / (2.0f - rho);
#pragma omp parallel for num_threads(threads) schedule(static)
  for (long i = 0; i < values; ++i) o[i] = (n[i] + a * nbar[i]) * b;
}

}  // namespace

void SolverImpl::runLevel(const PreparedLevel& level, bool finest,
                          SolveReport& report) {
  internal::IterationState& s = state_;
  InnerParams params =
      innerParams(level, finest ? settings_.step_balance : kCoarseStepBalance);
  // Relaxed iterations on whole-image levels only: the local refinement's
  // short steps keep the plain one.
  params.relaxation = static_cast<float>(settings_.over_relaxation);
  const internal::EnergyTerms terms = energyTerms();
  const Clock::time_point level_start = Clock::now();
  // Dynamic guidance: the level's weights (levels_ owns it) follow n0, and E
  // is the weighted E plus the guidance's correction (docs/method.md).
  internal::DynamicGuidance* guidance = nullptr;
  double correction = 0.0;
  if (settings_.dynamic_guidance > 0.0) {
    guidance = &guidance_;
    guidance->begin(levels_[static_cast<std::size_t>(&level - levels_.data())],
                    levels_[0], internal::guidanceTerms(settings_), threads_);
    correction = guidance->reweight(s.n0, threads_);
  }
  // best: the weighted E at n0, which a step must not exceed; reached: E.
  double best = backend_->energy(level, terms, s.n0, threads_);
  double reached = best + correction;
  const double energy_seconds = secondsSince(level_start);
  // What closing an outer step costs (normalize + energy), for the budget;
  // with the guidance an accepted step also reweights and measures E again,
  // about twice what the level's start took.
  double finish_seconds =
      (guidance != nullptr ? 2.0 : 1.5) * secondsSince(level_start);
  if (finest) {
    report.initial_energy = reached;
    recordEnergy(report, reached);
  }
  s.n = s.n0;
  s.nbar = s.n0;
  // Each level may use the whole iteration cap; coarse levels are cheap.
  // Coarse levels only prepare a start for the next finer one: a few outer
  // steps each (kCoarseOuterSteps) and a looser tolerance.
  int remaining =
      finest ? remaining_inner_
             : std::min(settings_.max_total_inner_iterations,
                        kCoarseOuterSteps * settings_.inner_iterations);
  const double tolerance =
      finest ? settings_.relative_tolerance
             : std::max(settings_.relative_tolerance, kCoarseTolerance);
  double seconds_per_iteration = 0.0;
  for (int outer = 0; outer < settings_.max_outer_iterations && remaining > 0;
       ++outer) {
    const StepIterations step = runStepIterations(
        level, params, std::min(settings_.inner_iterations, remaining),
        finish_seconds, seconds_per_iteration);
    int& counted =
        finest ? report.inner_iterations : report.coarse_inner_iterations;
    counted += step.done;
    // Cancelled: only whole chunks count; the outer step is not closed.
    if (cancelled()) break;
    remaining -= step.done;
    if (finest) report.outer_iterations += 1;
    // Re-linearize: the normalized iterate replaces n0 when E does not rise.
    const Clock::time_point finish_start = Clock::now();
    // A relaxed run's candidate comes from its last plain step (feasible).
    if (params.relaxation != 1.0f) {
      lastPrimalStep(s, params.relaxation, candidate_, threads_);
      internal::normalizeInto(candidate_, candidate_, threads_);
    } else {
      internal::normalizeInto(s.n, candidate_, threads_);
    }
    const double e = backend_->energy(level, terms, candidate_, threads_);
    finish_seconds = secondsSince(finish_start);
    if (finest) {
      // The least a finest level costs: its first energy, a first chunk of 2
      // iterations and one closing step.
      level_seconds_ =
          energy_seconds + 2.0 * seconds_per_iteration + finish_seconds;
    }
    bool converged = false;
    if (e <= best) {
      best = e;
      std::swap(s.n0, candidate_);
      s.n = s.n0;
      s.nbar = s.n0;
      if (guidance != nullptr) {
        // The weights of the new n0, and E there under them.
        const Clock::time_point reweight_start = Clock::now();
        correction = guidance->reweight(s.n0, threads_);
        best = backend_->energy(level, terms, s.n0, threads_);
        finish_seconds += secondsSince(reweight_start);
      }
      const double energy_now = best + correction;
      const double decrease = (reached - energy_now) / std::max(reached, 1e-30);
      reached = energy_now;
      if (finest) recordEnergy(report, energy_now);
      converged = decrease < tolerance;
    } else if (finest) {
      report.rejected_outer_steps += 1;
    }
    if (step.out_of_time) {
      report.budget_exhausted = true;
      break;
    }
    if (converged) {
      if (finest) report.converged = true;
      break;
    }
  }
  if (guidance != nullptr) guidance->end();
  if (finest) remaining_inner_ = remaining;
}

SolverImpl::StepIterations SolverImpl::runStepIterations(
    const PreparedLevel& level, const InnerParams& params, int target,
    double finish_seconds, double& seconds_per_iteration) {
  // Without a budget, whole outer steps; with one, chunks sized so that the
  // next chunk and the closing step still fit (2 iterations to measure
  // first).
  const int first_chunk = deadline_.active() ? 2 : settings_.inner_iterations;
  StepIterations step;
  while (step.done < target) {
    const int k = deadline_.chunkIterations(
        target - step.done, seconds_per_iteration, finish_seconds, first_chunk,
        4 * threads_ * kBlockDepth);
    const Clock::time_point chunk_start = Clock::now();
    // A cancel request stops the iterations inside the chunk (its iterate
    // is then dropped: n0 is the last accepted step).
    if (!backend_->runInner(level, params, state_, k)) {
      cancelled_ = true;
      break;
    }
    seconds_per_iteration = secondsSince(chunk_start) / k;
    step.done += k;
    if (!deadline_.allowsChunk(seconds_per_iteration, finish_seconds)) {
      step.out_of_time = true;
      break;
    }
  }
  return step;
}

void SolverImpl::startWarm(const PreparedLevel& level, SolverState& out,
                           SolveReport& report) {
  internal::IterationState& s = state_;
  const Clock::time_point warm_start = Clock::now();
  // The previous normals (sanitized) and duals, swapped in rather than
  // copied (same sizes: no allocation either way).
  std::swap(s.n0, out.normals);
  internal::sanitizeWarmStart(level, settings_.visibility, s.n0, unknown_,
                              threads_);
  std::swap(s.p_h, out.dual_h);
  std::swap(s.p_v, out.dual_v);
  for (int l = 0; l < level.num_inputs; ++l) {
    std::swap(s.q[l], out.dual_data[l]);
  }
  // Pixels whose warm normal the current inputs contradict (content that
  // changed or moved unlike the warp assumed) count as unknown.
  const bool refine =
      settings_.warm_refine_iterations > 0 && !warm_converging_ && !cancelled();
  if (refine) {
    report.inconsistent_pixels = internal::markInconsistentPixels(
        level, s.n0, settings_.local_radius, unknown_, threads_);
    // The edges of the warm map: seeds of the refinement too (their warm
    // normals kept as its start), since the camera's translation moves them.
    report.edge_pixels =
        internal::markMapEdges(s.n0, unknown_, edge_scratch_map_, threads_);
  }
  if (!refine || cancelled() ||
      std::none_of(unknown_.begin(), unknown_.end(),
                   [](unsigned char u) { return u != 0; })) {
    report.warm_start_seconds = secondsSince(warm_start);
    return;
  }
  refine_.active.build(unknown_, level.width, level.height,
                       settings_.warm_refine_radius);
  // Unknown pixels (1) are filled from their known neighbours (the other
  // seeds, 2, keep their warm normals); then the active pixels are refined.
  // unknown_ now says: known.
  for (unsigned char& u : unknown_) u = u == 1 ? 0 : 1;
  if (!cancelled()) {
    internal::fillUnknownPixels(level, settings_.huber_eps, settings_.penalty,
                                settings_.visibility == VisibilityMode::kSoft,
                                s.n0, unknown_, refine_.active, kFillPasses,
                                edge_scratch_map_, fill_pending_, threads_,
                                &cancel_request_);
  }
  report.warm_start_seconds = secondsSince(warm_start);
  if (!cancelled()) refineActive(level, report);
  if (!cancelled() && settings_.warm_face_steps > 0) {
    // Sized once per size (a stream's first warm frame, unless reserved).
    faces_.reserve(level.width, level.height, threads_);
    correctFaces(level, report);
  }
  report.refine_seconds = secondsSince(warm_start) - report.warm_start_seconds -
                          report.face_seconds;
}

void SolverImpl::correctFaces(const PreparedLevel& level, SolveReport& report) {
  const Clock::time_point start = Clock::now();
  const internal::EnergyTerms terms = energyTerms();
  // One pointer to what E needs: small enough for std::function to hold
  // without a heap allocation (a live frame allocates nothing).
  struct EnergyContext {
    const internal::KernelBackend* backend;
    const PreparedLevel* level;
    const internal::EnergyTerms* terms;
    int threads;
  } const context{backend_, &level, &terms, threads_};
  const EnergyContext* ctx = &context;
  const internal::FaceCorrection::EnergyFunction energy_of =
      [ctx](const PlanarImage& n) {
        return ctx->backend->energy(*ctx->level, *ctx->terms, n, ctx->threads);
      };
  // Under a budget the correction takes only the time the refinement left
  // (what it leaves out does not count as the budget's: budget_exhausted
  // stays the refinement's), or held back when the correction was due: it
  // starts when its set-up and one step fit (their last times with
  // kFaceMargin).
  timeFacesFor(level);
  // A time measured, and the fastest one.
  auto timed = [](double seconds, double& last, double& fastest) {
    last = seconds;
    fastest = fastest > 0.0 ? std::min(fastest, seconds) : seconds;
  };
  // An estimate shrunk on a skipped frame, never below the fastest time.
  auto shrink = [](double& estimate, double fastest) {
    estimate = std::max(fastest, estimate * kFaceEstimateDecay);
  };
  // The time the refinement held back (there was room for it when the
  // refinement began) is the set-up's and the first step's: they run
  // without a check, which the refinement's closing could fail by a few
  // microseconds.
  const bool reserved = face_time_reserved_;
  face_time_reserved_ = false;
  if (!reserved && !deadline_.fits(start, kFaceMargin * (face_begin_seconds_ +
                                                         face_step_seconds_))) {
    // Times of a slow phase or of a first call would keep it out for good;
    // shrunk on each frame it is skipped (down to the fastest seen, so that
    // a run of skipped frames does not let it start where it cannot end in
    // time), they are measured again later.
    shrink(face_begin_seconds_, face_begin_fastest_);
    shrink(face_step_seconds_, face_step_fastest_);
    ++frames_without_face_step_;
    return;
  }
  const Clock::time_point begin_start = Clock::now();
  report.corrected_faces =
      faces_.begin(state_.n0, settings_.warm_face_degrees, energy_of, threads_);
  timed(secondsSince(begin_start), face_begin_seconds_, face_begin_fastest_);
  const double face_energy = faces_.energy();
  // Each step is kept only when E falls.
  for (int k = 0; k < settings_.warm_face_steps && report.corrected_faces > 0;
       ++k) {
    const Clock::time_point step_start = Clock::now();
    if (cancelled()) break;
    if (!(reserved && k == 0) &&
        !deadline_.fits(step_start, kFaceMargin * face_step_seconds_)) {
      if (k == 0) shrink(face_step_seconds_, face_step_fastest_);
      break;
    }
    const bool kept = faces_.step(level, terms.huber_eps, terms.penalty,
                                  settings_.visibility == VisibilityMode::kSoft,
                                  energy_of, state_.n0, threads_);
    report.face_steps_accepted += kept ? 1 : 0;
    report.face_steps += 1;
    // Only a kept step ran the whole line search: the others (no descent
    // direction after the model, or E not lowered) may have ended early, and
    // would set the floor below a whole step's time.
    const double step_seconds = secondsSince(step_start);
    if (kept) {
      timed(step_seconds, face_step_seconds_, face_step_fastest_);
    } else {
      face_step_seconds_ = std::max(step_seconds, face_step_fastest_);
    }
  }
  // Ran: a step, or nothing to correct.
  const bool ran = report.corrected_faces == 0 || report.face_steps > 0;
  frames_without_face_step_ = ran ? 0 : frames_without_face_step_ + 1;
  report.face_energy_decrease =
      report.corrected_faces > 0 ? face_energy - faces_.energy() : 0.0;
  report.face_seconds = secondsSince(start);
}

void SolverImpl::timeFacesFor(const PreparedLevel& level) {
  const std::array<int, 3> timed_for{{level.width, level.height, threads_}};
  if (timed_for != face_timed_for_) {
    // Times of another size or thread count say nothing of these.
    face_timed_for_ = timed_for;
    face_begin_seconds_ = face_step_seconds_ = 0.0;
    face_begin_fastest_ = face_step_fastest_ = 0.0;
  }
  // Before they are timed they stand at kFaceFirstShare of the budget
  // together, a step twice the set-up.
  if (face_begin_seconds_ == 0.0 && deadline_.active()) {
    face_begin_seconds_ =
        kFaceFirstShare * 1e-3 * settings_.time_budget_ms / (3.0 * kFaceMargin);
    face_step_seconds_ = 2.0 * face_begin_seconds_;
  }
}

double SolverImpl::faceReserveSeconds() const {
  const bool due = settings_.warm_face_steps > 0 &&
                   settings_.warm_face_period > 0 && deadline_.active() &&
                   frames_without_face_step_ >= settings_.warm_face_period;
  return due ? kFaceMargin * (face_begin_seconds_ + face_step_seconds_) : 0.0;
}

void SolverImpl::refineActive(const PreparedLevel& level, SolveReport& report) {
  // Short outer steps (kRefineStepIterations). A step is kept when the
  // active pixels' terms of E do not rise, so E does not; a rejected one
  // goes on from its iterate on the same tangent planes.
  const InnerParams params = innerParams(level, kRefineStepBalance);
  const internal::EnergyTerms terms = energyTerms();
  const bool measured = backend_->measuresRefinementThreads();
  const long count = static_cast<long>(refine_.active.pixels.size());
  report.refined_pixels = static_cast<int>(count);
  double best =
      backend_->beginRefinement(level, terms, state_, refine_, threads_);
  int remaining = settings_.warm_refine_iterations;
  double step_seconds = 0.0;  // what the last outer step took
  // The face correction's share when it is due (after it stood out too
  // long), held back from the refinement's steps when the frame has room
  // for it and as much again for the refinement (else the refinement takes
  // the frame, and a later one the correction: a refinement cut to a few
  // iterations costs its frame more than a late correction).
  if (settings_.warm_face_steps > 0) timeFacesFor(level);
  double face_reserve_seconds = faceReserveSeconds();
  if (!deadline_.fits(Clock::now(), kFaceReserveRoom * face_reserve_seconds)) {
    face_reserve_seconds = 0.0;
  }
  face_time_reserved_ = face_reserve_seconds > 0.0;
  // A cancel request ends it before a step, or inside one (the step is then
  // dropped: n0 holds the last accepted one).
  while (remaining > 0 && !cancelled()) {
    const Clock::time_point step_start = Clock::now();
    const int k = std::min(kRefineStepIterations, remaining);
    // One thread or all: whichever the last steps found cheaper (the same
    // result either way).
    const bool adaptive = measured && settings_.adaptive_refine_threads;
    int step_threads = adaptive ? refine_threads_.choose() : threads_;
    // What the step will take: the last step's time, or more if its thread
    // count was measured to cost more.
    auto expectedSeconds = [&](int threads) {
      return measured ? std::max(step_seconds,
                                 refine_threads_.cost(threads) * k * count)
                      : step_seconds;
    };
    double expected_seconds = expectedSeconds(step_threads);
    if (adaptive && step_threads != refine_threads_.cheaper() &&
        !deadline_.allowsStep(step_start, expected_seconds)) {
      // A probe of the dearer count that does not fit: the cheaper count
      // runs the step, and the probe's cost (perhaps a stall's, which only a
      // probe measures again) is lowered.
      refine_threads_.shrink(step_threads);
      step_threads = refine_threads_.cheaper();
      expected_seconds = expectedSeconds(step_threads);
    }
    const bool step_fits = deadline_.allowsStep(step_start, expected_seconds);
    if (!step_fits ||
        !deadline_.fits(step_start, expected_seconds + face_reserve_seconds)) {
      report.budget_exhausted = true;
      // No step this frame on a cost from an earlier one: it may be a
      // stall's, which no later step would measure again.
      if (!step_fits && measured && report.refine_iterations == 0) {
        refine_threads_.shrink(step_threads);
      }
      break;
    }
    // Inner iterations, then the candidate n / |n| at the active pixels and
    // its local terms of E.
    InnerParams step_params = params;
    step_params.num_threads = step_threads;
    if (!backend_->runRefinement(level, step_params, state_, refine_, k)) {
      cancelled_ = true;
      break;
    }
    remaining -= k;
    report.refine_iterations += k;
    if (step_threads < threads_) report.refine_single_thread_iterations += k;
    const double e =
        backend_->candidateEnergy(level, terms, state_, refine_, step_threads);
    const bool accepted = e <= best;
    const double decrease = (best - e) / std::max(best, 1e-30);
    if (accepted) {
      best = e;
      backend_->acceptCandidate(state_, refine_);
    } else {
      backend_->rejectCandidate(state_, refine_);
    }
    // Converged: a small decrease, once at least half of the iterations ran
    // (the first steps after the fill can be slow to start: a short step
    // with little decrease is no sign of convergence there).
    if (accepted && decrease < settings_.relative_tolerance &&
        2 * report.refine_iterations >= settings_.warm_refine_iterations) {
      break;
    }
    step_seconds = secondsSince(step_start);
    if (measured && count > 0) {
      refine_threads_.record(step_threads,
                             step_seconds / (static_cast<double>(k) * count));
    }
  }
  backend_->endRefinement(state_, refine_, threads_);
}

}  // namespace normal_fusion
