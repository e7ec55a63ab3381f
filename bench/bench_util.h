// What the table-printing benchmarks share: the machine line printed with
// every table, timing of repeated calls, and the solver's benchmark problem.
#pragma once

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <fstream>
#include <functional>
#include <string>
#include <vector>

#include "eval/synthetic.h"
#include "normal_fusion/solver.h"

namespace normal_fusion {
namespace bench {

/// The CPU model of /proc/cpuinfo ("unknown" when it has none).
inline std::string cpuModel() {
  std::ifstream in("/proc/cpuinfo");
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind("model name", 0) == 0) {
      const std::size_t colon = line.find(':');
      if (colon != std::string::npos) return line.substr(colon + 2);
    }
  }
  return "unknown";
}

/// The three load averages of /proc/loadavg.
inline std::string loadAverage() {
  std::ifstream in("/proc/loadavg");
  std::string a, b, c;
  in >> a >> b >> c;
  return a + " " + b + " " + c;
}

/// "machine: MODEL, nproc N, load average A B C", the line every table
/// starts with.
inline std::string machineLine() {
  return "machine: " + cpuModel() + ", nproc " +
         std::to_string(sysconf(_SC_NPROCESSORS_ONLN)) + ", load average " +
         loadAverage();
}

inline double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

/// Milliseconds of each of `runs` calls of `work`, after one warm-up call
/// (which sizes the buffers).
inline std::vector<double> timesMs(int runs,
                                   const std::function<void()>& work) {
  work();
  std::vector<double> times;
  for (int k = 0; k < runs; ++k) {
    const auto start = std::chrono::steady_clock::now();
    work();
    times.push_back(std::chrono::duration<double, std::milli>(
                        std::chrono::steady_clock::now() - start)
                        .count());
  }
  return times;
}

/// Synthetic scene 0 at width x height with `num_inputs` inputs of the
/// paper's noise at sigma 0.4 (seeds 100, 101, ...).
inline FusionProblem paperNoiseProblem(int width, int height, int num_inputs) {
  const synthetic::Frame frame = synthetic::renderScene(0, width, height);
  FusionProblem problem;
  problem.image = frame.image;
  problem.K = frame.K;
  for (int l = 0; l < num_inputs; ++l) {
    NormalInput input;
    input.normals = synthetic::addPaperNoise(frame.normals_gt, 0.4, 100 + l);
    problem.inputs.push_back(input);
  }
  return problem;
}

}  // namespace bench
}  // namespace normal_fusion
