// Memory of the solver at 640x480 with L = 2: the peak resident size of a
// process that only builds one frame's problem and solves it frame after
// frame (warm-started), and the solver's own share (peak after minus before
// the first solve). Prints a table.
#include <sys/resource.h>

#include <cstdio>

#include "eval/synthetic.h"
#include "normal_fusion/solver.h"

namespace nf = normal_fusion;

namespace {
double peakMiB() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return usage.ru_maxrss / 1024.0;
}
}  // namespace

int main() {
  const int width = 640, height = 480;
  const nf::synthetic::Frame frame =
      nf::synthetic::renderScene(0, width, height);
  nf::FusionProblem problem;
  problem.image = frame.image;
  problem.K = frame.K;
  for (int l = 0; l < 2; ++l) {
    nf::NormalInput input;
    input.normals = nf::synthetic::addPaperNoise(frame.normals_gt, 0.4, 10 + l);
    problem.inputs.push_back(input);
  }
  const double before = peakMiB();
  nf::SolverSettings settings;
  settings.max_total_inner_iterations = 100;
  nf::Solver solver(settings);
  nf::SolverState state;
  nf::SolveReport report;
  for (int k = 0; k < 5; ++k) solver.solve(problem, state, k > 0, report);
  const double after = peakMiB();
  const double pixels = static_cast<double>(width) * height;
  std::printf("| 640x480, L = 2 | MiB |\n|---|---:|\n");
  std::printf("| peak resident size, whole process | %.1f |\n", after);
  std::printf(
      "| before the first solve (problem, renderer, runtime) | %.1f |\n",
      before);
  std::printf(
      "| the solver: levels, iteration state, warm-start state | %.1f |\n",
      after - before);
  std::printf("| per pixel | %.0f bytes |\n",
              (after - before) * 1024.0 * 1024.0 / pixels);
  return 0;
}
