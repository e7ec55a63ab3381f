// Time to solution: wall time for a cold start to bring the energy within
// 1e-3 (relative) of a fully converged solve, and within a tenth of that, on
// the synthetic scenes at sigma = 0.4, for several schedules (plain
// Chambolle-Pock, other splits of inner and outer iterations, diagonal
// preconditioning, the pyramid, the balance of the steps between the normals
// and the duals). Prints tables. Not a test: timings depend on the machine
// and its load.
#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <string>
#include <vector>

#include "eval/synthetic.h"
#include "normal_fusion/solver.h"

namespace nf = normal_fusion;

namespace {

struct Schedule {
  std::string name;
  int inner_iterations;
  bool preconditioning;
  int pyramid_levels;
  double step_balance;
};

}  // namespace

int main(int argc, char** argv) {
  int width = 640, height = 480, threads = 2;
  double sigma = 0.4, tolerance = 1e-3;
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string key = argv[i];
    const double value = std::atof(argv[i + 1]);
    if (key == "--width")
      width = static_cast<int>(value);
    else if (key == "--height")
      height = static_cast<int>(value);
    else if (key == "--threads")
      threads = static_cast<int>(value);
    else if (key == "--sigma")
      sigma = value;
    else if (key == "--tolerance")
      tolerance = value;
    else {
      std::fprintf(stderr, "bench_time_to_solution: unknown option %s\n",
                   key.c_str());
      return 2;
    }
  }
  const std::vector<Schedule> schedules = {
      {"plain CP, 50 inner per outer", 50, false, 1, 1.0},
      {"plain CP, 10 inner per outer", 10, false, 1, 1.0},
      {"plain CP, 20 inner per outer", 20, false, 1, 1.0},
      {"plain CP, 100 inner per outer", 100, false, 1, 1.0},
      {"preconditioned, 50 inner", 50, true, 1, 1.0},
      {"preconditioned, 20 inner", 20, true, 1, 1.0},
      {"plain CP, 20 inner, 3-level pyramid", 20, false, 3, 1.0},
      {"preconditioned, 20 inner, 3-level pyramid", 20, true, 3, 1.0},
      {"plain CP, 50 inner, balance 0.25", 50, false, 1, 0.25},
      {"preconditioned, 50 inner, balance 0.5", 50, true, 1, 0.5},
      {"preconditioned, 50 inner, balance 0.25 (default)", 50, true, 1, 0.25},
      {"preconditioned, 50 inner, balance 0.125", 50, true, 1, 0.125},
      {"preconditioned, 20 inner, balance 0.25", 20, true, 1, 0.25},
  };
  // The targets: E <= E* (1 + t) for t = tolerance and tolerance / 10.
  const std::vector<double> targets = {tolerance, tolerance / 10.0};
  std::printf(
      "# time to solution: %dx%d, sigma %.2f, %d threads, target E <= E* (1 + "
      "%g)\n",
      width, height, sigma, threads, tolerance);
  std::printf(
      "| scene | schedule | time to %g (ms) | inner its | time to %g (ms) | "
      "inner its | E / E* - 1 after 4000 its |\n",
      targets[0], targets[1]);
  std::printf("|---:|---|---:|---:|---:|---:|---:|\n");
  // [target][schedule]: summed time, and whether every scene reached it.
  std::vector<std::vector<double>> total_ms(
      targets.size(), std::vector<double>(schedules.size(), 0.0));
  std::vector<std::vector<bool>> all_reached(
      targets.size(), std::vector<bool>(schedules.size(), true));
  for (int scene = 0; scene < nf::synthetic::kNumScenes; ++scene) {
    const nf::synthetic::Frame frame =
        nf::synthetic::renderScene(scene, width, height);
    nf::FusionProblem problem;
    problem.image = frame.image;
    problem.K = frame.K;
    nf::NormalInput input;
    input.normals =
        nf::synthetic::addPaperNoise(frame.normals_gt, sigma, 40 + scene);
    problem.inputs = {input};
    // E*: the lowest energy of long runs (4000 inner iterations) of every
    // schedule.
    std::vector<nf::SolveReport> reports(schedules.size());
    double e_star = std::numeric_limits<double>::infinity();
    for (std::size_t i = 0; i < schedules.size(); ++i) {
      nf::SolverSettings settings;
      settings.num_threads = threads;
      settings.inner_iterations = schedules[i].inner_iterations;
      settings.preconditioning = schedules[i].preconditioning;
      settings.pyramid_levels = schedules[i].pyramid_levels;
      settings.step_balance = schedules[i].step_balance;
      settings.relative_tolerance = 1e-7;
      settings.max_total_inner_iterations = 4000;
      settings.max_outer_iterations = 4000;
      nf::Solver solver(settings);
      solver.solve(problem, &reports[i]);
      e_star = std::min(e_star, reports[i].final_energy);
    }
    for (std::size_t i = 0; i < schedules.size(); ++i) {
      const nf::SolveReport& r = reports[i];
      std::printf("| %d | %s |", scene, schedules[i].name.c_str());
      for (std::size_t t = 0; t < targets.size(); ++t) {
        double reached_ms = -1.0;
        int reached_its = -1;
        for (std::size_t k = 0; k < r.energies.size(); ++k) {
          if (r.energies[k] <= e_star * (1.0 + targets[t])) {
            reached_ms = 1000.0 * r.energy_seconds[k];
            // Accepted step k closes after k outer steps of the schedule.
            reached_its = static_cast<int>(k) * schedules[i].inner_iterations;
            break;
          }
        }
        if (reached_ms < 0) all_reached[t][i] = false;
        total_ms[t][i] += reached_ms;
        if (reached_ms < 0) {
          std::printf(" not reached | - |");
        } else {
          std::printf(" %.0f | %d |", reached_ms, reached_its);
        }
      }
      std::printf(" %.2e |\n", r.final_energy / e_star - 1.0);
    }
    std::fflush(stdout);
  }
  for (std::size_t t = 0; t < targets.size(); ++t) {
    std::printf(
        "\n| schedule | mean time to within %g of E* (ms) | speed-up over "
        "plain CP |\n|---|---:|---:|\n",
        targets[t]);
    for (std::size_t i = 0; i < schedules.size(); ++i) {
      if (!all_reached[t][i]) {
        std::printf("| %s | not reached on every scene | - |\n",
                    schedules[i].name.c_str());
        continue;
      }
      if (!all_reached[t][0]) {
        std::printf("| %s | %.0f | - |\n", schedules[i].name.c_str(),
                    total_ms[t][i] / nf::synthetic::kNumScenes);
        continue;
      }
      std::printf("| %s | %.0f | %.2f |\n", schedules[i].name.c_str(),
                  total_ms[t][i] / nf::synthetic::kNumScenes,
                  total_ms[t][0] / total_ms[t][i]);
    }
  }
  return 0;
}
