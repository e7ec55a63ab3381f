// The cold solve against OpenCV's fast global smoother (FGS, ximgproc): on
// the same frames (640x480, the synthetic scenes, two inputs: the paper's
// noise at sigma 0.5 and the normals of a noisy depth map), the median time
// of the default solve, of a schedule of shorter outer steps (10 inner
// iterations, spelled out below), of the default solve relaxed
// (over_relaxation 1.9), and of FGS on the
// inputs' mean at its best setting of peers::settingsGrid(), their ratios, the
// PSNR of each, and the default solve's time to solution (within 1e-3 of the
// energy of a converged solve). A second table sets the default solve
// against the same solve from the filtered cold start (cold_filter_radius =
// --filter-radius): at the default stop, and in a long run of each (the same
// schedule, tolerance 1e-7, 3000 inner iterations) inner iterations and ms to
// within 1e-3 and 1e-4 of E*.
// Solver options on the command line change the default solve only (for
// comparisons; the filtered solve is the default solve with the filtered
// start). Prints tables; not a test.
//
//   bench_cold_solve [--runs 5] [--threads 2] [--width 640 --height 480]
//                    [--scenes 0,1,2] [--filter-radius 8] [solver options]
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <limits>
#include <sstream>
#include <string>
#include <vector>

#include "bench_util.h"
#include "eval/synthetic.h"
#include "normal_fusion/errors.h"
#include "normal_fusion/metrics.h"
#include "normal_fusion/solver.h"
#include "normal_fusion/solver_options.h"
#ifdef NF_HAVE_XIMGPROC
#include "eval/peers.h"
#endif

namespace nf = normal_fusion;

namespace {

struct Options {
  int runs = 5, threads = 2, width = 640, height = 480;
  std::vector<int> scenes{0, 1, 2};
  int filter_radius = 8;        ///< cold_filter_radius of the filtered start
  nf::SolverSettings settings;  ///< the default solve (with any options)
};

std::vector<int> parseList(const std::string& text) {
  std::vector<int> values;
  std::stringstream in(text);
  std::string item;
  while (std::getline(in, item, ',')) values.push_back(std::atoi(item.c_str()));
  return values;
}

bool parseOptions(int argc, char** argv, Options& o) {
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string key = argv[i], value = argv[i + 1];
    if (key == "--runs") {
      o.runs = std::atoi(value.c_str());
    } else if (key == "--threads") {
      o.threads = std::atoi(value.c_str());
    } else if (key == "--width") {
      o.width = std::atoi(value.c_str());
    } else if (key == "--height") {
      o.height = std::atoi(value.c_str());
    } else if (key == "--filter-radius") {
      o.filter_radius = std::atoi(value.c_str());
    } else if (key == "--scenes") {
      o.scenes = parseList(value);
    } else if (nf::cli::isSolverOption(key)) {
      nf::cli::applySolverOption(key, value, o.settings);
    } else {
      std::fprintf(stderr, "bench_cold_solve: unknown option %s\n",
                   key.c_str());
      return false;
    }
  }
  o.settings.num_threads = o.threads;
  o.settings.validate();
  return true;
}

/// Shorter outer steps: 10 inner iterations each, a tolerance that stops
/// them at about the default's accuracy.
nf::SolverSettings shortSteps(int threads) {
  nf::SolverSettings s;
  s.inner_iterations = 10;
  s.max_outer_iterations = 100;
  s.max_total_inner_iterations = 1000;
  s.relative_tolerance = 2e-5;
  s.num_threads = threads;
  return s;
}

/// The default solve (with any options) in the relaxed iteration, rho 1.9
/// (SolverSettings::over_relaxation).
nf::SolverSettings relaxed(const nf::SolverSettings& settings) {
  nf::SolverSettings s = settings;
  s.over_relaxation = 1.9;
  return s;
}

/// The default solve (with any options) from the filtered cold start.
nf::SolverSettings filteredStart(const nf::SolverSettings& settings,
                                 int radius) {
  nf::SolverSettings s = settings;
  s.cold_filter_radius = radius;
  return s;
}

/// A converged solve: its energy is E* of the time to solution.
nf::SolverSettings convergedSettings(int threads) {
  nf::SolverSettings s;
  s.num_threads = threads;
  s.step_balance = 0.125;
  s.relative_tolerance = 1e-7;
  s.max_total_inner_iterations = 6000;
  s.max_outer_iterations = 6000;
  return s;
}

struct Frame {
  nf::FusionProblem problem;
  nf::NormalMap normals_gt;
};

Frame makeFrame(int scene, int width, int height) {
  const nf::synthetic::Frame rendered =
      nf::synthetic::renderScene(scene, width, height);
  Frame frame;
  frame.normals_gt = rendered.normals_gt;
  frame.problem.image = rendered.image;
  frame.problem.K = rendered.K;
  nf::NormalInput noisy, depth;
  noisy.normals =
      nf::synthetic::addPaperNoise(rendered.normals_gt, 0.5, 300 + scene);
  depth.normals =
      nf::synthetic::normalsFromNoisyDepth(rendered, 0.0015, 0.02, 400 + scene);
  frame.problem.inputs = {noisy, depth};
  return frame;
}

struct Timed {
  double ms = 0.0;    ///< median
  double psnr = 0.0;  ///< of the last run
  nf::SolveReport report;
};

Timed timeSolve(const Frame& frame, const nf::SolverSettings& settings,
                int runs) {
  nf::Solver solver(settings);
  Timed t;
  nf::NormalMap out;
  t.ms = nf::bench::median(nf::bench::timesMs(
      runs, [&] { out = solver.solve(frame.problem, &t.report); }));
  t.psnr = nf::psnr(out, frame.normals_gt);
  return t;
}

/// `settings` run long (tolerance 1e-7, at most 3000 inner iterations), once:
/// its energies give the iterations to each target.
Timed longRun(const Frame& frame, nf::SolverSettings settings) {
  settings.relative_tolerance = 1e-7;
  settings.max_total_inner_iterations = 3000;
  settings.max_outer_iterations = 3000;
  Timed t;
  const nf::NormalMap out =
      nf::Solver(settings).solve(frame.problem, &t.report);
  t.psnr = nf::psnr(out, frame.normals_gt);
  return t;
}

/// Milliseconds until the report's energy is within `rel` of `e_star`, -1
/// when never.
double timeToSolution(const nf::SolveReport& r, double e_star, double rel) {
  for (std::size_t k = 0; k < r.energies.size(); ++k) {
    if (r.energies[k] <= e_star * (1.0 + rel)) {
      return 1000.0 * r.energy_seconds[k];
    }
  }
  return -1.0;
}

/// Inner iterations (finest level; accepted step k closes after k outer
/// steps) until the report's energy is within `rel` of `e_star`, -1 when
/// never.
int iterationsToSolution(const nf::SolveReport& r, double e_star, double rel,
                         int inner_per_outer) {
  for (std::size_t k = 0; k < r.energies.size(); ++k) {
    if (r.energies[k] <= e_star * (1.0 + rel)) {
      return static_cast<int>(k) * inner_per_outer;
    }
  }
  return -1;
}

#ifdef NF_HAVE_XIMGPROC
/// The inputs' mean (normalized), what FGS filters.
nf::NormalMap meanOfInputs(const nf::FusionProblem& problem) {
  const nf::NormalMap& first = problem.inputs[0].normals;
  const int W = first.width(), H = first.height();
  nf::NormalMap mean(W, H, 3);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (int i = 0; i < W * H; ++i) {
    float v[3] = {0.0f, 0.0f, 0.0f};
    for (const nf::NormalInput& input : problem.inputs) {
      const float a[3] = {input.normals.plane(0)[i], input.normals.plane(1)[i],
                          input.normals.plane(2)[i]};
      if (!std::isfinite(a[0] + a[1] + a[2])) continue;
      for (int c = 0; c < 3; ++c) v[c] += a[c];
    }
    const float len = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    for (int c = 0; c < 3; ++c) {
      mean.plane(c)[i] = len > 1e-6f ? v[c] / len : nan;
    }
  }
  return mean;
}

/// FGS at its best setting of the grid on this frame, timed.
Timed timeFgs(const Frame& frame, int runs, std::string& label) {
  const nf::NormalMap mean = meanOfInputs(frame.problem);
  nf::peers::PeerSetting best;
  double best_psnr = -1.0;
  for (const nf::peers::PeerSetting& s :
       nf::peers::settingsGrid(nf::peers::PeerFilter::kFastGlobalSmoother)) {
    const double p = nf::psnr(
        nf::peers::applyPeer(mean, frame.problem.image, s), frame.normals_gt);
    if (p > best_psnr) {
      best_psnr = p;
      best = s;
    }
  }
  label = best.label();
  Timed t;
  t.psnr = best_psnr;
  t.ms = nf::bench::median(nf::bench::timesMs(runs, [&] {
    (void)nf::peers::applyPeer(mean, frame.problem.image, best);
  }));
  return t;
}
#endif

}  // namespace

int main(int argc, char** argv) {
  Options o;
  try {
    if (!parseOptions(argc, argv, o)) return 2;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "bench_cold_solve: %s\n", e.what());
    return 2;
  }
  std::printf("%s\n", nf::bench::machineLine().c_str());
  std::printf(
      "cold solve, %dx%d, two inputs (paper noise 0.5, normals of noisy "
      "depth), %d threads, medians of %d runs\n\n",
      o.width, o.height, o.threads, o.runs);
  std::printf(
      "| scene | default ms | PSNR | iterations (coarse) | 10-step ms | "
      "PSNR | FGS ms | PSNR | default / FGS | 10-step / FGS | default / "
      "10-step | "
      "default within 1e-3 ms | 10-step within 1e-3 ms | relaxed ms | PSNR | "
      "iterations | relaxed / FGS | default / relaxed | relaxed within 1e-3 "
      "ms |\n"
      "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
      "---:|---:|---:|---:|---:|\n");
  std::vector<double> ratios_fgs, ratios_short, tts, tts_short;
  std::ostringstream starts;
  starts
      << "\n| scene | start | ms | PSNR | inner its (coarse) | E0 / E* - 1 | "
         "long run: within 1e-3 ms | its | within 1e-4 ms | its | PSNR | "
         "E / E* - 1 |\n"
         "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n";
  for (int scene : o.scenes) {
    const Frame frame = makeFrame(scene, o.width, o.height);
    const Timed now = timeSolve(frame, o.settings, o.runs);
    const Timed short_steps = timeSolve(frame, shortSteps(o.threads), o.runs);
    const Timed relax = timeSolve(frame, relaxed(o.settings), o.runs);
    const Timed filtered =
        timeSolve(frame, filteredStart(o.settings, o.filter_radius), o.runs);
    const Timed long_data = longRun(frame, o.settings);
    const Timed long_filtered =
        longRun(frame, filteredStart(o.settings, o.filter_radius));
    nf::SolveReport converged;
    nf::Solver(convergedSettings(o.threads)).solve(frame.problem, &converged);
    const double e_star = std::min(
        std::min(std::min(converged.final_energy, filtered.report.final_energy),
                 std::min(long_data.report.final_energy,
                          long_filtered.report.final_energy)),
        std::min(
            std::min(now.report.final_energy, short_steps.report.final_energy),
            relax.report.final_energy));
    const Timed* long_runs[2] = {&long_data, &long_filtered};
    const char* labels[2] = {"data", "filtered"};
    const Timed* timed[2] = {&now, &filtered};
    for (int i = 0; i < 2; ++i) {
      const Timed* t = timed[i];
      const nf::SolveReport& r = t->report;
      const nf::SolveReport& lr = long_runs[i]->report;
      char row[400];
      std::snprintf(
          row, sizeof row,
          "| %d | %s | %.1f | %.2f | %d (%d) | %.3e | %.1f | %d | %.1f | %d | "
          "%.2f | %.2e |\n",
          scene, labels[i], t->ms, t->psnr, r.inner_iterations,
          r.coarse_inner_iterations, r.initial_energy / e_star - 1.0,
          timeToSolution(lr, e_star, 1e-3),
          iterationsToSolution(lr, e_star, 1e-3, o.settings.inner_iterations),
          timeToSolution(lr, e_star, 1e-4),
          iterationsToSolution(lr, e_star, 1e-4, o.settings.inner_iterations),
          long_runs[i]->psnr, lr.final_energy / e_star - 1.0);
      starts << row;
    }
    Timed fgs;
    std::string fgs_label = "not built";
#ifdef NF_HAVE_XIMGPROC
    fgs = timeFgs(frame, o.runs, fgs_label);
#endif
    const double tt = timeToSolution(now.report, e_star, 1e-3);
    const double tt_short = timeToSolution(short_steps.report, e_star, 1e-3);
    const double tt_relaxed = timeToSolution(relax.report, e_star, 1e-3);
    std::printf(
        "| %d | %.1f | %.2f | %d (%d) | %.1f | %.2f | %.1f (%s) | %.2f | "
        "%.1fx | %.1fx | %.1fx | %.1f | %.1f | %.1f | %.2f | %d (%d) | %.1fx | "
        "%.2fx | %.1f |\n",
        scene, now.ms, now.psnr, now.report.inner_iterations,
        now.report.coarse_inner_iterations, short_steps.ms, short_steps.psnr,
        fgs.ms, fgs_label.c_str(), fgs.psnr, now.ms / fgs.ms,
        short_steps.ms / fgs.ms, now.ms / short_steps.ms, tt, tt_short,
        relax.ms, relax.psnr, relax.report.inner_iterations,
        relax.report.coarse_inner_iterations, relax.ms / fgs.ms,
        now.ms / relax.ms, tt_relaxed);
    ratios_fgs.push_back(now.ms / fgs.ms);
    ratios_short.push_back(now.ms / short_steps.ms);
    tts.push_back(tt);
    tts_short.push_back(tt_short);
  }
  std::printf(
      "\nmedian over the scenes: default / FGS %.1fx, default / 10-step "
      "%.1fx, time to solution within 1e-3: default %.1f ms, 10-step "
      "%.1f ms (-1: not reached)\n",
      nf::bench::median(ratios_fgs), nf::bench::median(ratios_short),
      nf::bench::median(tts), nf::bench::median(tts_short));
  std::printf(
      "\nthe default solve from the data and from the filtered start "
      "(cold_filter_radius %d), E* as above:\n%s",
      o.filter_radius, starts.str().c_str());
  return 0;
}
