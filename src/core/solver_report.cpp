// The solver's bookkeeping: the report of a solve, and the memory of the
// buffers it keeps from frame to frame (what they hold, when a much smaller
// image gives it back, what a cold start sizes for the warm starts).
#include <limits>
#include <utility>

#include "solver_impl.h"

namespace normal_fusion {

namespace {

/// Seconds from `t` to now.
double secondsSince(SolverImpl::Clock::time_point t) {
  return std::chrono::duration<double>(SolverImpl::Clock::now() - t).count();
}

}  // namespace

void SolverImpl::resetReport(SolveReport& report) const {
  std::vector<double> energies, energy_seconds;
  energies.swap(report.energies);
  energy_seconds.swap(report.energy_seconds);
  report = SolveReport();
  energies.clear();
  energy_seconds.clear();
  report.energies.swap(energies);
  report.energy_seconds.swap(energy_seconds);
  report.energies.reserve(settings_.max_outer_iterations + 1);
  report.energy_seconds.reserve(settings_.max_outer_iterations + 1);
}

void SolverImpl::recordEnergy(SolveReport& report, double energy) const {
  report.energies.push_back(energy);
  report.energy_seconds.push_back(secondsSince(solve_start_));
}

void SolverImpl::finishCancelledBeforeStart(SolveReport& report,
                                            Clock::time_point start) const {
  report.cancelled = true;
  report.initial_energy = report.final_energy =
      std::numeric_limits<double>::quiet_NaN();
  report.prepare_seconds = report.seconds = secondsSince(start);
}

void SolverImpl::finishReport(SolveReport& report,
                              Clock::time_point start) const {
  if (report.energies.empty()) {
    report.initial_energy = report.final_energy =
        std::numeric_limits<double>::quiet_NaN();
  } else {
    report.final_energy = report.energies.back();
  }
  report.cancelled = cancelled_;
  report.seconds = secondsSince(start);
}

std::size_t SolverImpl::bytesHeld() const {
  std::size_t bytes =
      state_.bytesHeld() + candidate_.bytesHeld() + coarse_result_.bytesHeld() +
      edge_scratch_.bytesHeld() + refine_.active.bytesHeld() +
      refine_.gathered.bytesHeld() + internal::bytesHeld(edge_scratch_map_) +
      internal::bytesHeld(fill_pending_) + internal::bytesHeld(unknown_) +
      internal::bytesHeld(refine_.iterate_saved) + coarse_p_h_.bytesHeld() +
      coarse_p_v_.bytesHeld() + cold_filter_.bytesHeld() + faces_.bytesHeld();
  for (const PlanarImage& q : coarse_q_) bytes += q.bytesHeld();
  for (const internal::PreparedLevel& level : levels_) {
    bytes += level.bytesHeld();
  }
  bytes += guidance_.bytesHeld();
  return bytes;
}

void SolverImpl::fitBuffers(int W, int H) {
  const std::size_t N = static_cast<std::size_t>(W) * H;
  state_.fit(W, H, threads_);
  internal::releaseIfOversized(candidate_, 3 * N);
  internal::releaseIfOversized(coarse_result_, 3 * N);
  internal::releaseIfOversized(coarse_p_h_, 3 * N);
  internal::releaseIfOversized(coarse_p_v_, 3 * N);
  internal::releaseIfOversized(cold_filter_, 5 * N);
  for (PlanarImage& q : coarse_q_) internal::releaseIfOversized(q, 3 * N);
  for (std::vector<float>* v :
       {&edge_scratch_.mag_h, &edge_scratch_.mag_v, &edge_scratch_.plane,
        &edge_scratch_.blurred, &edge_scratch_.blur}) {
    internal::releaseIfOversized(*v, N);
  }
  internal::releaseIfOversized(unknown_, N);
  internal::releaseIfOversized(edge_scratch_map_, N);
  internal::releaseIfOversized(fill_pending_, N);
  internal::releaseIfOversized(refine_.iterate_saved, 3 * N);
  faces_.fit(W, H);
  // The refinement's buffers hold room for up to every pixel of the image
  // they were sized for (ActiveSet: its mask, one entry per pixel).
  if (N < refine_.active.mask.capacity() / 4) {
    refine_.active = internal::ActiveSet();
  }
  if (N < refine_.gathered.node_of.capacity() / 4) {
    refine_.gathered = internal::ActiveBuffers();
  }
}

void SolverImpl::releaseUnusedLevels(int used) {
  int w = levels_[0].width, h = levels_[0].height;
  for (int li = 1; li < static_cast<int>(levels_.size()); ++li) {
    w = (w + 1) / 2;
    h = (h + 1) / 2;
    if (li < used) continue;
    const long pixels =
        static_cast<long>(levels_[li].width) * levels_[li].height;
    if (pixels / 4 > static_cast<long>(w) * h) {
      levels_[li] = internal::PreparedLevel();
    }
  }
}

void SolverImpl::preallocateRefinement(int W, int H, int num_inputs,
                                       int active_pixels, bool with_faces) {
  refine_.active.preallocate(W, H);
  refine_.gathered.preallocate(W, H, num_inputs, active_pixels);
  unknown_.resize(static_cast<std::size_t>(W) * H);
  edge_scratch_map_.resize(static_cast<std::size_t>(W) * H);
  fill_pending_.reserve(static_cast<std::size_t>(W) * H);
  if (with_faces && settings_.warm_face_steps > 0) {
    faces_.reserve(W, H, threads_);
  }
}

}  // namespace normal_fusion
