// A live stream's start-up, frame by frame: the node's StreamFuser with the
// live settings of config/live.yaml (a 33 ms frame budget, the cold start
// under cold_start_budget_ms) from its very first set, on a synthetic
// sequence (640x480, scene 0 panning 0.3 degrees per frame, two inputs: the
// paper's noise at sigma 0.4 and normals of noisy depth, rotation warm
// start). Per frame: the frame's time (and of it the input preparation
// and the warp of the state), the sets a 30 Hz camera delivers
// meanwhile that a busy node drops, whether the state is still converging
// (SolverState::converging), the iterations, and the PSNR against a
// converged cold solve of the same frame. The stream's buffers are reserved
// before the first set (StreamFuser::reserve(), as the node does on its first
// camera_info; --reserve 0: not). Prints a table; not a test.
//
//   bench_startup [--frames 30] [--threads 2] [--budget-ms 33]
//                 [--cold-start-budget-ms 33] [--cold-filter-radius 0]
//                 [--reserve 1] [--width 640 --height 480]
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "bench_util.h"
#include "eval/synthetic.h"
#include "normal_fusion/metrics.h"
#include "normal_fusion/solver.h"
#include "normal_fusion/stream_fuser.h"

namespace nf = normal_fusion;

namespace {

struct Options {
  int frames = 30, threads = 2, width = 640, height = 480;
  double budget_ms = 33.0, cold_start_budget_ms = 33.0;
  int cold_filter_radius = 0;
  bool reserve = true;
};

bool parseOptions(int argc, char** argv, Options& o) {
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string key = argv[i];
    const double value = std::atof(argv[i + 1]);
    if (key == "--frames") {
      o.frames = static_cast<int>(value);
    } else if (key == "--threads") {
      o.threads = static_cast<int>(value);
    } else if (key == "--budget-ms") {
      o.budget_ms = value;
    } else if (key == "--cold-start-budget-ms") {
      o.cold_start_budget_ms = value;
    } else if (key == "--cold-filter-radius") {
      o.cold_filter_radius = static_cast<int>(value);
    } else if (key == "--reserve") {
      o.reserve = value != 0.0;
    } else if (key == "--width") {
      o.width = static_cast<int>(value);
    } else if (key == "--height") {
      o.height = static_cast<int>(value);
    } else {
      std::fprintf(stderr, "bench_startup: unknown option %s\n", key.c_str());
      return false;
    }
  }
  return o.frames >= 1;
}

nf::FusionProblem makeProblem(const nf::synthetic::Frame& frame, int k) {
  nf::FusionProblem problem;
  problem.image = frame.image;
  problem.K = frame.K;
  nf::NormalInput noisy, depth;
  noisy.normals = nf::synthetic::addPaperNoise(frame.normals_gt, 0.4, 1000 + k);
  depth.normals =
      nf::synthetic::normalsFromNoisyDepth(frame, 0.0015, 0.02, 2000 + k);
  problem.inputs = {noisy, depth};
  return problem;
}

/// config/live.yaml over the defaults.
nf::SolverSettings liveSettings(const Options& o) {
  nf::SolverSettings s;
  s.num_threads = o.threads;
  s.time_budget_ms = o.budget_ms;
  s.cold_start_budget_ms = o.cold_start_budget_ms;
  s.cold_filter_radius = o.cold_filter_radius;
  s.relative_tolerance = 1e-6;
  s.max_total_inner_iterations = 4000;
  s.max_outer_iterations = 400;
  return s;
}

/// The converged cold solve each frame is compared with.
nf::SolverSettings convergedSettings(int threads) {
  nf::SolverSettings s;
  s.num_threads = threads;
  s.relative_tolerance = 1e-6;
  s.max_total_inner_iterations = 4000;
  s.max_outer_iterations = 400;
  return s;
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  if (!parseOptions(argc, argv, o)) return 2;
  const std::vector<nf::synthetic::Frame> sequence =
      nf::synthetic::renderSequence(0, o.width, o.height, o.frames);
  nf::StreamSettings stream;
  stream.solver = liveSettings(o);
  nf::StreamFuser fuser(stream, "bench_startup");
  nf::Solver reference(convergedSettings(o.threads));
  const double period_ms = 1000.0 / 30.0;
  // As the node does on its first camera_info, before the first set.
  std::string reserved = "no";
  if (o.reserve) {
    char text[64];
    const double seconds = fuser.reserve(o.width, o.height, 2);
    std::snprintf(text, sizeof text, "%.1f ms, %.1f MB", 1e3 * seconds,
                  1e-6 * static_cast<double>(fuser.bytesHeld()));
    reserved = text;
  }
  std::printf("%s\n", nf::bench::machineLine().c_str());
  std::printf(
      "start-up of a live stream: %dx%d, scene 0 panning 0.3 deg/frame, two "
      "inputs, %d threads, budget %.1f ms, cold start budget %.1f ms, cold "
      "filter radius %d, sets every %.1f ms; buffers reserved before the "
      "first set: %s\n\n",
      o.width, o.height, o.threads, o.budget_ms, o.cold_start_budget_ms,
      o.cold_filter_radius, period_ms, reserved.c_str());
  std::printf(
      "| frame | frame ms | prepare ms | warp ms | sets dropped meanwhile | "
      "converging | whole-image its (rejected steps) | refine its | PSNR live "
      "| PSNR converged | deficit (dB) |\n"
      "|---:|---:|---:|---:|---:|:---:|---:|---:|---:|---:|---:|\n");
  int dropped = 0, over_budget = 0, converged_at = -1;
  double sum_deficit = 0.0, worst_deficit = -1e9, first_ms = 0.0;
  for (int k = 0; k < o.frames; ++k) {
    nf::FusionProblem problem = makeProblem(sequence[k], k);
    const nf::FusionProblem original = problem;
    const nf::FrameRotation rotation =
        k == 0 ? nf::FrameRotation::still()
               : nf::FrameRotation::known(nf::synthetic::relativeRotation(
                     sequence[k].pose, sequence[k - 1].pose));
    nf::StreamResult result;
    fuser.fuse(std::llround(k * 1e9 / 30.0), problem, rotation,
               std::chrono::steady_clock::now(), &result);
    const double ms = 1e3 * fuser.endFrame(0.0);
    const nf::SolveReport& r = fuser.lastReport();
    if (k == 0) first_ms = ms;
    // The sets that arrive while this frame is busy, past the next one
    // (which waits), are dropped by a node that keeps one set pending.
    const int missed = std::max(0, static_cast<int>(ms / period_ms));
    dropped += missed;
    if (ms > o.budget_ms) ++over_budget;
    const double psnr_live =
        nf::psnr(fuser.fusedNormals(), sequence[k].normals_gt);
    const double psnr_best =
        nf::psnr(reference.solve(original), sequence[k].normals_gt);
    const double deficit = psnr_best - psnr_live;
    if (converged_at < 0 && deficit <= 0.1) converged_at = k;
    if (k > 0) {
      sum_deficit += deficit;
      worst_deficit = std::max(worst_deficit, deficit);
    }
    std::printf(
        "| %d | %.1f | %.1f | %.1f | %d | %s | %d (%d) | %d | %.2f | %.2f | "
        "%.3f |\n",
        k, ms, 1e3 * r.prepare_seconds, 1e3 * result.warp_seconds, missed,
        r.still_converging ? "yes" : "no", r.inner_iterations,
        r.rejected_outer_steps, r.refine_iterations, psnr_live, psnr_best,
        deficit);
    std::fflush(stdout);
  }
  std::printf(
      "\nfirst output after %.1f ms; sets dropped %d; frames over the budget "
      "%d of %d; first frame within 0.1 dB of its converged solve: %d; "
      "deficit over frames 1 - %d: mean %.3f dB, worst %.3f dB\n",
      first_ms, dropped, over_budget, o.frames, converged_at, o.frames - 1,
      o.frames > 1 ? sum_deficit / (o.frames - 1) : 0.0, worst_deficit);
  return 0;
}
