// Streaming benchmark: a 640x480 synthetic sequence with slow camera motion and
// two inputs (paper noise and depth-camera noise), solved frame after frame,
// warm-started from the previous frame (rotation-compensated) within a
// per-frame time budget that covers the warp of the state and the solve, as
// in the node, against a fully converged cold solve of each frame. Prints a
// table per frame (with the phases of the live frame: warp, preparation, warm
// start, refinement) and the worst case. Not a test: timings depend on the
// machine and its load.
//
// Each frame also gets the energy gap of the live map to the converged cold
// solve, and with --continue N1,N2,... the deficit of the live state solved
// on (whole image, no budget) for N1, N2, ... more inner iterations at most:
// how much whole-image work a frame would need to match the cold solve.
// With --temporal-frames N the live solver's inputs are averaged over time
// (TemporalAverage, its time counted in the frame's budget) while the cold
// solves keep each frame's own inputs.
#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <functional>
#include <limits>
#include <string>
#include <thread>
#include <vector>

#include <sys/resource.h>

#include "eval/synthetic.h"
#include "normal_fusion/metrics.h"
#include "normal_fusion/solver.h"
#include "normal_fusion/temporal.h"
#include "normal_fusion/warp.h"

namespace nf = normal_fusion;

namespace {

nf::FusionProblem makeProblem(const nf::synthetic::Frame& frame, int index) {
  nf::FusionProblem problem;
  problem.image = frame.image;
  problem.K = frame.K;
  nf::NormalInput noisy;
  noisy.normals =
      nf::synthetic::addPaperNoise(frame.normals_gt, 0.4, 1000 + index);
  nf::NormalInput depth;
  depth.normals =
      nf::synthetic::normalsFromNoisyDepth(frame, 0.0015, 0.02, 2000 + index);
  problem.inputs = {noisy, depth};
  return problem;
}

/// Milliseconds since `start`.
double msSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double, std::milli>(
             std::chrono::steady_clock::now() - start)
      .count();
}

/// The share (0..1) of sum_i |a_i - b_i|^2 that the `fraction` of pixels
/// with the largest differences hold: how concentrated the difference is.
double shareOfLargestDifferences(const nf::NormalMap& a, const nf::NormalMap& b,
                                 double fraction) {
  const int n = a.width() * a.height();
  std::vector<double> d2(n);
  double total = 0.0;
  for (int i = 0; i < n; ++i) {
    double e = 0.0;
    for (int c = 0; c < 3; ++c) {
      const double v = a.plane(c)[i] - b.plane(c)[i];
      e += v * v;
    }
    d2[i] = e;
    total += e;
  }
  const int top = std::min(n, static_cast<int>(fraction * n));
  std::nth_element(d2.begin(), d2.begin() + top, d2.end(),
                   std::greater<double>());
  double held = 0.0;
  for (int i = 0; i < top; ++i) held += d2[i];
  return total > 0.0 ? held / total : 0.0;
}

}  // namespace

int main(int argc, char** argv) {
  int frames = 20, width = 640, height = 480, threads = 2, scene = 0;
  double budget_ms = 33.0, degrees_per_frame = 0.3;
  bool warm_start = true;  // --warm 0: every frame cold-started (comparison)
  // --iterations N: N inner iterations per frame and no budget, so that
  // changes to the warm start can be compared without timing noise.
  int iterations = 0;
  // --refine N: the warm start's local refinement iterations (default: the
  // solver's; 0 = off).
  int refine = -1;
  // --still 1: the camera does not move (frame 0 over and over, new noise
  // each frame): what is left is the noise of each frame, not the motion.
  bool still = false;
  // --reset-duals 0|1: the warp resets the duals (1) or rotates them (0);
  // default: reset while the local refinement is on, as the node does.
  int reset_duals = -1;
  // --refine-radius R: the local refinement's dilation (default: the
  // solver's).
  int refine_radius = -1;
  // --busy-threads N: N threads that spin for the whole run, as other work
  // on the machine would (the solver gets the cores that are left over).
  int busy_threads = 0;
  // --adaptive-threads 0|1: the local refinement's thread choice
  // (SolverSettings::adaptive_refine_threads; default on).
  int adaptive_threads = 1;
  // --continue N1,N2,...: see above.
  std::vector<int> continue_caps;
  // --startup converged|live: the start-up frame solved to convergence
  // (default) or with the live settings as a stream's first frame, as the
  // node solves it (under cold_start_budget_ms).
  bool startup_live = false;
  // --cold-start-budget-ms X: SolverSettings::cold_start_budget_ms of the
  // live settings (default: the solver's, none).
  double cold_start_budget_ms = -1.0;
  // --temporal-frames N, --temporal-gate-deg G: the live frames' inputs
  // averaged over time (TemporalSettings; default off). The converged cold
  // solve of each frame keeps the frame's own inputs.
  nf::TemporalSettings temporal;
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string key = argv[i];
    const double value = std::atof(argv[i + 1]);
    if (key == "--frames")
      frames = static_cast<int>(value);
    else if (key == "--width")
      width = static_cast<int>(value);
    else if (key == "--height")
      height = static_cast<int>(value);
    else if (key == "--threads")
      threads = static_cast<int>(value);
    else if (key == "--scene")
      scene = static_cast<int>(value);
    else if (key == "--budget-ms")
      budget_ms = value;
    else if (key == "--degrees-per-frame")
      degrees_per_frame = value;
    else if (key == "--still")
      still = value != 0.0;
    else if (key == "--warm")
      warm_start = value != 0.0;
    else if (key == "--iterations")
      iterations = static_cast<int>(value);
    else if (key == "--refine")
      refine = static_cast<int>(value);
    else if (key == "--refine-radius")
      refine_radius = static_cast<int>(value);
    else if (key == "--adaptive-threads")
      adaptive_threads = value != 0.0 ? 1 : 0;
    else if (key == "--busy-threads")
      busy_threads = static_cast<int>(value);
    else if (key == "--reset-duals")
      reset_duals = value != 0.0 ? 1 : 0;
    else if (key == "--cold-start-budget-ms")
      cold_start_budget_ms = value;
    else if (key == "--temporal-frames")
      temporal.frames = static_cast<int>(value);
    else if (key == "--temporal-gate-deg")
      temporal.gate_degrees = value;
    else if (key == "--startup") {
      const std::string mode = argv[i + 1];
      if (mode != "converged" && mode != "live") {
        std::fprintf(stderr,
                     "bench_streaming: --startup wants converged or live, got "
                     "%s\n",
                     argv[i + 1]);
        return 2;
      }
      startup_live = mode == "live";
    } else if (key == "--continue") {
      for (const char* c = argv[i + 1]; *c != '\0';) {
        char* end = nullptr;
        const long cap = std::strtol(c, &end, 10);
        if (end == c || cap <= 0) {
          std::fprintf(stderr,
                       "bench_streaming: --continue wants positive iteration "
                       "counts separated by commas, got %s\n",
                       argv[i + 1]);
          return 2;
        }
        continue_caps.push_back(static_cast<int>(cap));
        c = *end == ',' ? end + 1 : end;
      }
    } else {
      std::fprintf(stderr, "bench_streaming: unknown option %s\n", key.c_str());
      return 2;
    }
  }
  auto sequence = nf::synthetic::renderSequence(
      scene, width, height, still ? 1 : frames + 1, degrees_per_frame);
  if (still) sequence.resize(frames + 1, sequence[0]);
  nf::SolverSettings live;
  live.num_threads = threads;
  live.time_budget_ms = iterations > 0 ? 0.0 : budget_ms;
  live.max_total_inner_iterations = iterations > 0 ? iterations : 100000;
  if (refine >= 0) live.warm_refine_iterations = refine;
  if (refine_radius >= 0) live.warm_refine_radius = refine_radius;
  live.adaptive_refine_threads = adaptive_threads == 1;
  if (cold_start_budget_ms >= 0.0) {
    live.cold_start_budget_ms = cold_start_budget_ms;
  }
  // As the node does: with the local refinement, the duals are reset.
  if (reset_duals < 0) reset_duals = live.warm_refine_iterations > 0 ? 1 : 0;
  nf::SolverSettings converged;
  converged.num_threads = threads;
  converged.relative_tolerance = 1e-6;
  converged.max_total_inner_iterations = 4000;
  converged.max_outer_iterations = 400;
  nf::SolverSettings startup = converged;
  if (startup_live) startup = live;
  // Solving the live state on: the whole image from it (no refinement), to
  // the converged solve's tolerance or the cap.
  nf::SolverSettings continued = converged;
  continued.warm_refine_iterations = 0;

  std::printf(
      "# streaming: scene %d, %dx%d, 2 inputs, %.2f deg/frame, budget %.1f ms "
      "per frame (warp + solve), "
      "%d inner iterations per frame (0: by the budget), local refinement of "
      "the warm start %d iterations at most, %d threads%s, %d busy threads "
      "beside it, adaptive refinement threads %s, OMP_WAIT_POLICY %s, ",
      scene, width, height, still ? 0.0 : degrees_per_frame,
      live.time_budget_ms, iterations, live.warm_refine_iterations, threads,
      still ? ", camera still" : "", busy_threads,
      adaptive_threads == 1 ? "on" : "off",
      std::getenv("OMP_WAIT_POLICY") != nullptr ? std::getenv("OMP_WAIT_POLICY")
                                                : "unset");
  temporal.validate();
  if (temporal.enabled()) {
    std::printf(
        "live inputs averaged over time (%d frames, gate %.0f deg; its time "
        "counts in the frame's budget and the warp column)\n",
        temporal.frames, temporal.gate_degrees);
  } else {
    std::printf("live inputs: each frame's own\n");
  }
  std::printf(
      "| frame | frame ms | warp ms | solve ms | prepare ms | warm start ms | "
      "refine ms | whole-image its (outer steps / rejected) | refined px | "
      "refine its (on one thread) | warm | PSNR live (dB) "
      "| PSNR converged (dB) | deficit (dB) | PSNR warm start (dB) | PSNR "
      "warped ground truth (dB) | energy gap to converged (%%) |");
  for (int cap : continue_caps) {
    std::printf(" deficit after %d more its (dB) |", cap);
  }
  if (!continue_caps.empty()) {
    std::printf(
        " share of the live map's difference to the last of them in its 20 "
        "%% most different pixels (%%) |");
  }
  std::printf(
      "\n|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|:---:|---:|---:|"
      "---:|---:|---:|---:|");
  for (std::size_t c = 0; c < continue_caps.size(); ++c) std::printf("---:|");
  if (!continue_caps.empty()) std::printf("---:|");
  std::printf("\n");
  std::atomic<bool> stop_busy{false};
  std::vector<std::thread> busy;
  for (int t = 0; t < busy_threads; ++t) {
    busy.emplace_back([&stop_busy] {
      volatile double x = 1.0;
      while (!stop_busy.load(std::memory_order_relaxed)) x = x * 1.0000001;
    });
  }
  nf::Solver live_solver(live);
  nf::TemporalAverage temporal_average;
  nf::Solver reference_solver(converged);
  nf::SolverState state, warp_scratch;
  // The converged cold solves: their inner iterations, and how many stopped
  // on the tolerance rather than on a cap.
  int reference_min_its = std::numeric_limits<int>::max(),
      reference_max_its = 0, references_converged = 0;
  nf::SolveReport report;
  double worst_ms = 0.0, worst_deficit = -1e9, sum_ms = 0.0, sum_deficit = 0.0;
  double worst_gap = -1e9;
  std::vector<double> worst_continued(continue_caps.size(), -1e9),
      sum_continued(continue_caps.size(), 0.0);
  for (int k = 0; k <= frames; ++k) {
    const nf::FusionProblem problem = makeProblem(sequence[k], k);
    // The live solver's problem: the frame's inputs, averaged over time
    // with --temporal-frames (the cold solves keep the frame's own).
    nf::FusionProblem live_problem = problem;
    const std::array<double, 9> R_cur_prev =
        k == 0 ? std::array<double, 9>{1, 0, 0, 0, 1, 0, 0, 0, 1}
               : nf::synthetic::relativeRotation(sequence[k].pose,
                                                 sequence[k - 1].pose);
    const auto average_start = std::chrono::steady_clock::now();
    temporal_average.apply(live_problem.inputs, problem.K,
                           k == 0 ? nullptr : &R_cur_prev, temporal, threads);
    const double average_ms = msSince(average_start);
    if (k == 0) {
      // Start-up frame: solved to convergence before the stream starts (or,
      // with --startup live, as a stream's first frame with the live
      // settings), by the live solver itself, so that its buffers exist once
      // the stream runs (steady state).
      live_solver.setSettings(startup);
      live_solver.solve(live_problem, state, /*warm_start=*/startup_live,
                        report);
      std::printf(
          "# start-up frame: %s, %d inner iterations (%d on coarser levels), "
          "%.0f ms%s\n",
          startup_live ? "live settings, a stream's cold start" : "converged",
          report.inner_iterations, report.coarse_inner_iterations,
          1e3 * report.seconds,
          report.budget_exhausted ? ", stopped by its budget" : "");
      live_solver.setSettings(live);
      warp_scratch.resize(width, height, 2);
      continue;
    }
    const auto warp_start = std::chrono::steady_clock::now();
    // As the node does: with the local refinement, the duals are reset.
    nf::warpStateByRotation(
        state, problem.K, R_cur_prev, warp_scratch, threads,
        reset_duals == 1 ? nf::DualWarp::kReset : nf::DualWarp::kRotate);
    // The inputs' averaging counts as part of the warp.
    const double warp_ms = average_ms + msSince(warp_start);
    // What the warm start predicts (uncovered pixels skipped), and the same
    // warp applied to the previous frame's exact normals: the floor a
    // rotation-only warp leaves (edge blending, and the camera's translation,
    // which it ignores).
    const double psnr_start = nf::psnr(state.normals, sequence[k].normals_gt);
    nf::SolverState exact;
    exact.normals = sequence[k - 1].normals_gt;
    nf::warpStateByRotation(exact, problem.K, R_cur_prev);
    const double psnr_warped_gt =
        nf::psnr(exact.normals, sequence[k].normals_gt);
    // The frame's budget covers the warp and the solve (not the measurements
    // above).
    const auto start = std::chrono::steady_clock::now();
    live_solver.setBudgetStart(
        start - std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                    std::chrono::duration<double, std::milli>(warp_ms)));
    live_solver.solve(live_problem, state, warm_start, report);
    const double solve_ms = msSince(start);
    // A live frame: the warp of the state, then the solve.
    const double ms = warp_ms + solve_ms;
    const double psnr_live = nf::psnr(state.normals, sequence[k].normals_gt);
    nf::SolveReport reference_report;
    const nf::NormalMap best =
        reference_solver.solve(problem, &reference_report);
    reference_min_its =
        std::min(reference_min_its, reference_report.inner_iterations);
    reference_max_its =
        std::max(reference_max_its, reference_report.inner_iterations);
    if (reference_report.converged) ++references_converged;
    const double psnr_best = nf::psnr(best, sequence[k].normals_gt);
    const double deficit = psnr_best - psnr_live;
    worst_ms = std::max(worst_ms, ms);
    worst_deficit = std::max(worst_deficit, deficit);
    sum_ms += ms;
    sum_deficit += deficit;
    // The live map's energy on this frame against the converged solve's.
    const double energy_live =
        nf::computeEnergy(problem, converged, state.normals);
    const double energy_best = nf::computeEnergy(problem, converged, best);
    const double gap = 100.0 * (energy_live - energy_best) / energy_best;
    worst_gap = std::max(worst_gap, gap);
    std::printf(
        "| %d | %.1f | %.1f | %.1f | %.1f | %.1f | %.1f | %d (%d / %d) | %d | "
        "%d (%d) | "
        "%s | "
        "%.2f | %.2f | %.3f | %.2f | %.2f | %.3f |",
        k, ms, warp_ms, solve_ms, 1e3 * report.prepare_seconds,
        1e3 * report.warm_start_seconds, 1e3 * report.refine_seconds,
        report.inner_iterations, report.outer_iterations,
        report.rejected_outer_steps, report.refined_pixels,
        report.refine_iterations, report.refine_single_thread_iterations,
        report.warm_started ? "yes" : "no", psnr_live, psnr_best, deficit,
        psnr_start, psnr_warped_gt, gap);
    nf::SolverState continued_state;
    for (std::size_t c = 0; c < continue_caps.size(); ++c) {
      nf::SolverSettings capped = continued;
      capped.max_total_inner_iterations = continue_caps[c];
      nf::Solver continuing(capped);
      continued_state = state;
      continuing.solve(problem, continued_state, true);
      const double d =
          psnr_best - nf::psnr(continued_state.normals, sequence[k].normals_gt);
      worst_continued[c] = std::max(worst_continued[c], d);
      sum_continued[c] += d;
      std::printf(" %.3f |", d);
    }
    if (!continue_caps.empty()) {
      std::printf(" %.0f |",
                  100.0 * shareOfLargestDifferences(
                              state.normals, continued_state.normals, 0.2));
    }
    std::printf("\n");
    std::fflush(stdout);
  }
  stop_busy = true;
  for (std::thread& t : busy) t.join();
  const double frame_ms = 1000.0 / 30.0;
  std::printf(
      "\nworst frame time (warp + solve) %.1f ms (mean %.1f ms; 30 fps allows "
      "%.1f ms): %s\n",
      worst_ms, sum_ms / frames, frame_ms,
      worst_ms <= frame_ms ? "keeps up" : "does NOT keep up");
  std::printf(
      "worst PSNR deficit against the converged cold solve: %.3f dB (mean "
      "%.3f dB): %s\n",
      worst_deficit, sum_deficit / frames,
      worst_deficit <= 0.2 ? "within 0.2 dB" : "NOT within 0.2 dB");
  std::printf(
      "worst energy gap of the live map to the converged cold solve: %.3f %%\n",
      worst_gap);
  std::printf(
      "converged cold solves: %d - %d inner iterations, %d of %d stopped on "
      "their tolerance (%g), the others on the cap (%d)\n",
      reference_min_its, reference_max_its, references_converged, frames,
      converged.relative_tolerance, converged.max_total_inner_iterations);
  for (std::size_t c = 0; c < continue_caps.size(); ++c) {
    std::printf(
        "live state solved on for %d more inner iterations at most: worst "
        "deficit %.3f dB (mean %.3f dB)\n",
        continue_caps[c], worst_continued[c], sum_continued[c] / frames);
  }
  // Peak resident memory of the whole process (the renders of the sequence,
  // both solvers and their states included).
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  std::printf("peak resident memory of this process: %.1f MiB\n",
              usage.ru_maxrss / 1024.0);
  return 0;
}
