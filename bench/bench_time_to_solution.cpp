// Time to solution: wall time for a cold start to bring the energy within
// 1e-3 (relative) of a fully converged solve, and within a tenth of that, on
// the synthetic scenes at sigma = 0.4, for several schedules (plain
// Chambolle-Pock, other splits of inner and outer iterations, diagonal
// preconditioning, the pyramid, the balance of the steps between the normals
// and the duals, the relaxed iteration, the filtered cold start). Prints
// tables; --select 0,4,14 runs only those schedules (E* then comes from them).
// Not a test: timings depend on the machine and its load.
#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <sstream>
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
  double over_relaxation = 1.0;
  int cold_filter_radius = 0;  ///< SolverSettings::cold_filter_radius
};

struct Options {
  int width = 640, height = 480, threads = 2;
  double sigma = 0.4, tolerance = 1e-3;
  std::vector<int> select;  ///< schedules to run, empty = all
};

/// Reads `--key value` pairs into `o`; false (after a message) on an unknown
/// key.
bool parseOptions(int argc, char** argv, Options& o) {
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string key = argv[i];
    const double value = std::atof(argv[i + 1]);
    if (key == "--select") {
      std::stringstream list(argv[i + 1]);
      for (std::string item; std::getline(list, item, ',');) {
        o.select.push_back(std::atoi(item.c_str()));
      }
    } else if (key == "--width")
      o.width = static_cast<int>(value);
    else if (key == "--height")
      o.height = static_cast<int>(value);
    else if (key == "--threads")
      o.threads = static_cast<int>(value);
    else if (key == "--sigma")
      o.sigma = value;
    else if (key == "--tolerance")
      o.tolerance = value;
    else {
      std::fprintf(stderr, "bench_time_to_solution: unknown option %s\n",
                   key.c_str());
      return false;
    }
  }
  return true;
}

std::vector<Schedule> schedules() {
  return {
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
      {"preconditioned, 50 inner, balance 0.25 (the old default)", 50, true, 1,
       0.25},
      {"preconditioned, 10 inner, balance 0.25 (default)", 10, true, 1, 0.25},
      {"preconditioned, 50 inner, balance 0.125", 50, true, 1, 0.125},
      {"preconditioned, 20 inner, balance 0.25", 20, true, 1, 0.25},
      {"preconditioned, 50 inner, balance 0.25, relaxation 1.5", 50, true, 1,
       0.25, 1.5},
      {"preconditioned, 50 inner, balance 0.25, relaxation 1.8", 50, true, 1,
       0.25, 1.8},
      {"preconditioned, 50 inner, balance 0.25, relaxation 1.9", 50, true, 1,
       0.25, 1.9},
      {"preconditioned, 20 inner, balance 0.25, relaxation 1.9", 20, true, 1,
       0.25, 1.9},
      {"preconditioned, 10 inner, balance 0.25, relaxation 1.9", 10, true, 1,
       0.25, 1.9},
      {"preconditioned, 50 inner, balance 0.125, relaxation 1.9", 50, true, 1,
       0.125, 1.9},
      {"preconditioned, 50 inner, balance 0.5, relaxation 1.9", 50, true, 1,
       0.5, 1.9},
      {"preconditioned, 50 inner, balance 0.25, filtered start 8", 50, true, 1,
       0.25, 1.0, 8},
      {"preconditioned, 10 inner, balance 0.25, filtered start 8", 10, true, 1,
       0.25, 1.0, 8},
  };
}

nf::FusionProblem sceneProblem(int scene, const Options& o) {
  const nf::synthetic::Frame frame =
      nf::synthetic::renderScene(scene, o.width, o.height);
  nf::FusionProblem problem;
  problem.image = frame.image;
  problem.K = frame.K;
  nf::NormalInput input;
  input.normals =
      nf::synthetic::addPaperNoise(frame.normals_gt, o.sigma, 40 + scene);
  problem.inputs = {input};
  return problem;
}

/// Long runs (4000 inner iterations) of every schedule; E* is the lowest
/// energy of them.
std::vector<nf::SolveReport> longRuns(const nf::FusionProblem& problem,
                                      const std::vector<Schedule>& all,
                                      int threads) {
  std::vector<nf::SolveReport> reports(all.size());
  for (std::size_t i = 0; i < all.size(); ++i) {
    nf::SolverSettings settings;
    settings.num_threads = threads;
    settings.inner_iterations = all[i].inner_iterations;
    settings.preconditioning = all[i].preconditioning;
    settings.pyramid_levels = all[i].pyramid_levels;
    settings.step_balance = all[i].step_balance;
    settings.over_relaxation = all[i].over_relaxation;
    settings.cold_filter_radius = all[i].cold_filter_radius;
    settings.relative_tolerance = 1e-7;
    settings.max_total_inner_iterations = 4000;
    settings.max_outer_iterations = 4000;
    nf::Solver solver(settings);
    solver.solve(problem, &reports[i]);
  }
  return reports;
}

/// Summed time to each target per schedule, and whether every scene reached
/// it: [target][schedule].
struct Totals {
  std::vector<std::vector<double>> ms;
  std::vector<std::vector<bool>> all_reached;
};

/// Prints a scene's rows and adds its times to `totals`.
void printScene(int scene, const std::vector<Schedule>& all,
                const std::vector<nf::SolveReport>& reports,
                const std::vector<double>& targets, Totals& totals) {
  double e_star = std::numeric_limits<double>::infinity();
  for (const nf::SolveReport& r : reports) {
    e_star = std::min(e_star, r.final_energy);
  }
  for (std::size_t i = 0; i < all.size(); ++i) {
    const nf::SolveReport& r = reports[i];
    std::printf("| %d | %s |", scene, all[i].name.c_str());
    for (std::size_t t = 0; t < targets.size(); ++t) {
      double reached_ms = -1.0;
      int reached_its = -1;
      for (std::size_t k = 0; k < r.energies.size(); ++k) {
        if (r.energies[k] <= e_star * (1.0 + targets[t])) {
          reached_ms = 1000.0 * r.energy_seconds[k];
          // Accepted step k closes after k outer steps of the schedule.
          reached_its = static_cast<int>(k) * all[i].inner_iterations;
          break;
        }
      }
      if (reached_ms < 0) totals.all_reached[t][i] = false;
      totals.ms[t][i] += reached_ms;
      if (reached_ms < 0) {
        std::printf(" not reached | - |");
      } else {
        std::printf(" %.0f | %d |", reached_ms, reached_its);
      }
    }
    std::printf(" %.2e |\n", r.final_energy / e_star - 1.0);
  }
}

void printMeans(const std::vector<Schedule>& all,
                const std::vector<double>& targets, const Totals& totals) {
  for (std::size_t t = 0; t < targets.size(); ++t) {
    std::printf(
        "\n| schedule | mean time to within %g of E* (ms) | speed-up over "
        "plain CP |\n|---|---:|---:|\n",
        targets[t]);
    for (std::size_t i = 0; i < all.size(); ++i) {
      if (!totals.all_reached[t][i]) {
        std::printf("| %s | not reached on every scene | - |\n",
                    all[i].name.c_str());
        continue;
      }
      if (!totals.all_reached[t][0]) {
        std::printf("| %s | %.0f | - |\n", all[i].name.c_str(),
                    totals.ms[t][i] / nf::synthetic::kNumScenes);
        continue;
      }
      std::printf("| %s | %.0f | %.2f |\n", all[i].name.c_str(),
                  totals.ms[t][i] / nf::synthetic::kNumScenes,
                  totals.ms[t][0] / totals.ms[t][i]);
    }
  }
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  if (!parseOptions(argc, argv, o)) return 2;
  std::vector<Schedule> all = schedules();
  if (!o.select.empty()) {
    std::vector<Schedule> chosen;
    for (int i : o.select) {
      if (i < 0 || i >= static_cast<int>(all.size())) {
        std::fprintf(stderr, "bench_time_to_solution: no schedule %d\n", i);
        return 2;
      }
      chosen.push_back(all[static_cast<std::size_t>(i)]);
    }
    all = chosen;
  }
  // The targets: E <= E* (1 + t) for t = tolerance and tolerance / 10.
  const std::vector<double> targets = {o.tolerance, o.tolerance / 10.0};
  std::printf(
      "# time to solution: %dx%d, sigma %.2f, %d threads, target E <= E* (1 + "
      "%g)\n",
      o.width, o.height, o.sigma, o.threads, o.tolerance);
  std::printf(
      "| scene | schedule | time to %g (ms) | inner its | time to %g (ms) | "
      "inner its | E / E* - 1 after 4000 its |\n",
      targets[0], targets[1]);
  std::printf("|---:|---|---:|---:|---:|---:|---:|\n");
  Totals totals{std::vector<std::vector<double>>(
                    targets.size(), std::vector<double>(all.size(), 0.0)),
                std::vector<std::vector<bool>>(
                    targets.size(), std::vector<bool>(all.size(), true))};
  for (int scene = 0; scene < nf::synthetic::kNumScenes; ++scene) {
    const nf::FusionProblem problem = sceneProblem(scene, o);
    printScene(scene, all, longRuns(problem, all, o.threads), targets, totals);
    std::fflush(stdout);
  }
  printMeans(all, targets, totals);
  return 0;
}
