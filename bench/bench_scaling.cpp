// How time per frame and memory scale with the image size and the number of
// inputs: one table, with the cost model of one inner iteration (bytes moved
// and flops per pixel-iteration, docs/performance.md) beside each measurement.
// A "frame" is a cold solve of a fixed number of inner iterations (edge
// weights, data thresholds and the iterations), so that every row does the
// same work per pixel; medians of the repetitions.
//
// Run: bench_scaling [--iterations N] [--repetitions R] [--threads T]
#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include "bench_util.h"
#include "normal_fusion/solver.h"

namespace nf = normal_fusion;

namespace {

struct Options {
  int iterations = 30;
  int repetitions = 3;
  int threads = 0;  ///< 0 = all hardware threads
};

struct Size {
  int width, height;
};

/// Bytes one fused pass moves per pixel and inner iteration with L inputs:
/// (12 + 3L) floats of state read and written, (5 + 5L) floats read.
double modelBytesPerPixelIteration(int L) { return (29.0 + 11.0 * L) * 4.0; }

/// Flops per pixel and inner iteration: about 100 for L = 1, 15 per extra
/// input.
double modelFlopsPerPixelIteration(int L) { return 85.0 + 15.0 * L; }

Options parseOptions(int argc, char** argv) {
  Options options;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    const bool has_value = i + 1 < argc;
    if (arg == "--iterations" && has_value) {
      options.iterations = std::atoi(argv[++i]);
    } else if (arg == "--repetitions" && has_value) {
      options.repetitions = std::atoi(argv[++i]);
    } else if (arg == "--threads" && has_value) {
      options.threads = std::atoi(argv[++i]);
    } else {
      std::fprintf(stderr,
                   "usage: bench_scaling [--iterations N] [--repetitions R] "
                   "[--threads T]\n");
      std::exit(2);
    }
  }
  if (options.iterations < 1 || options.repetitions < 1 ||
      options.threads < 0) {
    std::fprintf(stderr, "bench_scaling: iterations and repetitions >= 1\n");
    std::exit(2);
  }
  return options;
}

struct Row {
  double frame_ms = 0.0;
  double ns_per_pixel_iteration = 0.0;
  double memory_mib = 0.0;
  int iterations = 0;
};

Row measure(const Options& options, const Size& size, int num_inputs) {
  nf::SolverSettings settings;
  settings.num_threads = options.threads;
  settings.inner_iterations = options.iterations;
  settings.max_outer_iterations = 1;
  settings.max_total_inner_iterations = options.iterations;
  settings.relative_tolerance = 0.0;
  settings.pyramid_levels = 0;
  const nf::FusionProblem problem =
      nf::bench::paperNoiseProblem(size.width, size.height, num_inputs);
  nf::Solver solver(settings);
  nf::SolverState state;
  nf::SolveReport report;
  Row row;
  row.frame_ms = nf::bench::median(nf::bench::timesMs(options.repetitions, [&] {
    solver.solve(problem, state, false, report);
  }));
  row.iterations = report.inner_iterations;
  const double pixels = static_cast<double>(size.width) * size.height;
  row.ns_per_pixel_iteration =
      row.frame_ms * 1e6 / (pixels * std::max(1, row.iterations));
  row.memory_mib =
      static_cast<double>(solver.bytesHeld() + state.bytesHeld()) / (1 << 20);
  return row;
}

}  // namespace

int main(int argc, char** argv) {
  const Options options = parseOptions(argc, argv);
  const std::vector<Size> sizes = {
      {320, 240}, {640, 480}, {1280, 720}, {1920, 1080}};
  const std::vector<int> input_counts = {1, 2, 4, 8};
  std::printf(
      "# bench_scaling: cold solve of %d inner iterations (edge weights, data "
      "thresholds, iterations), median of %d, threads %s\n",
      options.iterations, options.repetitions,
      options.threads == 0 ? "all" : std::to_string(options.threads).c_str());
  std::printf(
      "| size | inputs | frame ms | ns / pixel-iteration | model B / "
      "pixel-iteration | model flops / pixel-iteration | GB/s at the model | "
      "GFLOP/s at the model | memory MiB | bytes / pixel |\n");
  std::printf("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n");
  for (const Size& size : sizes) {
    for (int L : input_counts) {
      const Row row = measure(options, size, L);
      if (row.iterations != options.iterations) {
        std::fprintf(stderr, "bench_scaling: %dx%d L=%d ran %d iterations\n",
                     size.width, size.height, L, row.iterations);
        return 1;
      }
      const double bytes = modelBytesPerPixelIteration(L);
      const double flops = modelFlopsPerPixelIteration(L);
      const double pixels = static_cast<double>(size.width) * size.height;
      std::printf(
          "| %dx%d | %d | %.1f | %.2f | %.0f | %.0f | %.1f | %.1f | %.1f | "
          "%.0f |\n",
          size.width, size.height, L, row.frame_ms, row.ns_per_pixel_iteration,
          bytes, flops, bytes / row.ns_per_pixel_iteration,
          flops / row.ns_per_pixel_iteration, row.memory_mib,
          row.memory_mib * (1 << 20) / pixels);
      std::fflush(stdout);
    }
  }
  return 0;
}
