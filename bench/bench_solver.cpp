// Speed of the solver (Google Benchmark). Figures:
//  - BM_InnerIterations/<backend>/<L>/<threads>: pixel-iterations per second at
//    640x480 (counter "pixel_iter_per_s"), inner iterations only.
//  - BM_PaperWorkload/<threads>: the paper's workload, 640x480, L = 1, 1000
//    inner iterations in total (20 outer x 50 inner), wall time of one solve.
// Run: bench_solver --benchmark_min_time=2 (see docs/performance.md for
// recorded figures).
#include <benchmark/benchmark.h>

#include <cmath>

#include "bench_util.h"
#include "normal_fusion/detail/solver_internal.h"
#include "normal_fusion/solver.h"

namespace nf = normal_fusion;

namespace {

constexpr int kWidth = 640;
constexpr int kHeight = 480;

/// Inner iterations alone: args = {backend (0 fast, 1 reference), L, threads}.
void BM_InnerIterations(benchmark::State& state) {
  const bool reference = state.range(0) == 1;
  const int L = static_cast<int>(state.range(1));
  const int threads = static_cast<int>(state.range(2));
  nf::SolverSettings settings;
  const nf::FusionProblem problem =
      nf::bench::paperNoiseProblem(kWidth, kHeight, L);
  const nf::internal::PreparedLevel level =
      nf::internal::prepareFinest(problem, settings);
  nf::internal::InnerParams params;
  params.tau = params.sigma = params.sigma_data =
      static_cast<float>(0.99 / std::sqrt(8.0 + L));
  params.huber_eps = static_cast<float>(settings.huber_eps);
  params.penalty = settings.penalty;
  params.soft_visibility = true;
  params.num_threads = threads;
  nf::internal::IterationState s;
  s.resize(kWidth, kHeight, L);
  s.n0 = level.data[0];
  s.n = s.n0;
  s.nbar = s.n0;
  s.p_h.fill(0.0f);
  s.p_v.fill(0.0f);
  for (auto& q : s.q) q.fill(0.0f);
  const int per_call = 10;
  for (auto _ : state) {
    if (reference) {
      nf::internal::runInnerReference(level, params, s, per_call);
    } else {
      nf::internal::runInnerFast(level, params, s, per_call);
    }
  }
  const double pixel_iterations =
      static_cast<double>(state.iterations()) * per_call * kWidth * kHeight;
  state.counters["pixel_iter_per_s"] =
      benchmark::Counter(pixel_iterations, benchmark::Counter::kIsRate);
  state.SetLabel(std::string(reference ? "reference" : "fast") + " L=" +
                 std::to_string(L) + " threads=" + std::to_string(threads) +
                 " (10 iterations per call)");
}

/// The paper's workload: 640x480, L = 1, 1000 inner iterations in total.
void BM_PaperWorkload(benchmark::State& state) {
  const int threads = static_cast<int>(state.range(0));
  nf::SolverSettings settings;
  settings.num_threads = threads;
  settings.inner_iterations = 50;
  settings.max_outer_iterations = 20;
  settings.max_total_inner_iterations = 1000;
  settings.relative_tolerance = 0.0;
  settings.pyramid_levels = 1;
  const nf::FusionProblem problem =
      nf::bench::paperNoiseProblem(kWidth, kHeight, 1);
  nf::Solver solver(settings);
  nf::SolverState solver_state;
  for (auto _ : state) {
    const nf::SolveReport report = solver.solve(problem, solver_state, false);
    if (report.inner_iterations != 1000)
      state.SkipWithError("expected 1000 iterations");
  }
  state.SetLabel("640x480 L=1 1000 inner iterations threads=" +
                 std::to_string(threads));
}

}  // namespace

BENCHMARK(BM_InnerIterations)
    ->ArgNames({"reference", "L", "threads"})
    ->Args({0, 1, 1})
    ->Args({0, 1, 2})
    ->Args({0, 2, 1})
    ->Args({0, 2, 2})
    ->Args({1, 1, 1})
    ->Args({1, 2, 1})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK(BM_PaperWorkload)
    ->ArgNames({"threads"})
    ->Arg(1)
    ->Arg(2)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->Iterations(3);

BENCHMARK_MAIN();
