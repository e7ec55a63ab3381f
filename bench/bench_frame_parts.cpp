// The fixed cost of a streamed frame, stage by stage: what a live frame of
// bench_streaming's sequence (640x480, scene 0 panning 0.3 degrees per frame,
// two inputs) spends before its iterations. Each stage is called on its own,
// on copies of the stream's state before the live frame, `--repeats` times per
// frame; the table gives the median over all calls, the fastest call (the
// least disturbed by other work on the machine) and the fastest and the
// slowest frame's median. The live frame itself (StreamFuser::fuse) runs
// after the stages, so that the state carried on is the stream's own.
// Not a test: timings depend on the machine and its load.
//
//   bench_frame_parts [--frames 10] [--threads 1] [--repeats 5]
//                     [--width 640 --height 480]
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <string>
#include <vector>

#include "bench_util.h"
#include "eval/synthetic.h"
#include "normal_fusion/detail/dynamic_guidance.h"
#include "normal_fusion/detail/face_correction.h"
#include "normal_fusion/detail/kernel_backend.h"
#include "normal_fusion/detail/noise_estimate.h"
#include "normal_fusion/detail/solver_internal.h"
#include "normal_fusion/solver.h"
#include "normal_fusion/stream_fuser.h"
#include "normal_fusion/warp.h"
#include "normal_fusion/warp_motion.h"

namespace nf = normal_fusion;
namespace in = normal_fusion::internal;

namespace {

struct Options {
  int frames = 10, threads = 1, repeats = 5, width = 640, height = 480;
};

bool parseOptions(int argc, char** argv, Options& o) {
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string key = argv[i];
    const int value = std::atoi(argv[i + 1]);
    if (key == "--frames") {
      o.frames = value;
    } else if (key == "--threads") {
      o.threads = value;
    } else if (key == "--repeats") {
      o.repeats = value;
    } else if (key == "--width") {
      o.width = value;
    } else if (key == "--height") {
      o.height = value;
    } else {
      std::fprintf(stderr, "bench_frame_parts: unknown option %s\n",
                   key.c_str());
      return false;
    }
  }
  return o.frames >= 1 && o.repeats >= 1;
}

/// bench_streaming's frame: the paper's noise and normals of noisy depth.
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

/// The stages, in the order a frame runs them, and their times (ms).
struct Stage {
  const char* name;
  std::vector<double> all;           // every call
  std::vector<double> frame_median;  // per frame
};

class PartsRun {
 public:
  explicit PartsRun(const Options& o) : o_(o) {}
  void run();

 private:
  /// Times `prepare` (untimed) then `work`, o_.repeats times, into stage s.
  void time(std::size_t s, const std::function<void()>& prepare,
            const std::function<void()>& work);
  void frame(const nf::FusionProblem& problem, const nf::ScalarMap& depth_prev,
             const std::array<double, 9>& R_cur_prev,
             const nf::SolverState& state);
  void print() const;

  const Options& o_;
  std::vector<Stage> stages_ = {
      {"warp: rotation (DualWarp::kReset)", {}, {}},
      {"warp: motion through the depth (kReset)", {}, {}},
      {"prepare: edge weights", {}, {}},
      {"prepare: all (edge weights, inputs, local statistics)", {}, {}},
      {"prepare: local statistics of both inputs", {}, {}},
      {"warm start: sanitize", {}, {}},
      {"warm start: inconsistent pixels + map edges", {}, {}},
      {"warm start: active set", {}, {}},
      {"warm start: fill of the unknown pixels", {}, {}},
      {"refinement: gather + energy", {}, {}},
      {"noise estimate of both inputs, mean model, radius 4", {}, {}},
      {"noise estimate of both inputs, plane model, radius 4", {}, {}},
      {"outer step: dynamic guidance reweight", {}, {}},
      {"outer step: energy (fast backend)", {}, {}},
      {"level start: dynamic guidance begin", {}, {}},
      {"warp: rotation, duals rotated (kRotate: a state still converging)",
       {},
       {}},
      {"face correction: faces and E (FaceCorrection::begin)", {}, {}},
      {"face correction: the model (G and M)", {}, {}},
      {"face correction: one step (model, solve, line search)", {}, {}},
      {"live frame (StreamFuser::fuse, budget 33 ms)", {}, {}},
  };
  nf::SolverSettings settings_;
};

void PartsRun::time(std::size_t s, const std::function<void()>& prepare,
                    const std::function<void()>& work) {
  std::vector<double> times;
  for (int r = 0; r < o_.repeats; ++r) {
    prepare();
    const auto start = std::chrono::steady_clock::now();
    work();
    times.push_back(std::chrono::duration<double, std::milli>(
                        std::chrono::steady_clock::now() - start)
                        .count());
  }
  stages_[s].all.insert(stages_[s].all.end(), times.begin(), times.end());
  stages_[s].frame_median.push_back(nf::bench::median(times));
}

// Over 80 lines: one block per stage, each on the previous stage's result.
void PartsRun::frame(const nf::FusionProblem& problem,
                     const nf::ScalarMap& depth_prev,
                     const std::array<double, 9>& R_cur_prev,
                     const nf::SolverState& state) {
  const int threads = o_.threads;
  nf::SolverState work;
  nf::SolverState warp_scratch;
  nf::MotionWarpScratch motion_scratch;
  time(
      0, [&] { work = state; },
      [&] {
        nf::warpStateByRotation(work, problem.K, R_cur_prev, warp_scratch,
                                threads, nf::DualWarp::kReset);
      });
  nf::SolverState rotated;
  time(
      15, [&] { rotated = state; },
      [&] {
        nf::warpStateByRotation(rotated, problem.K, R_cur_prev, warp_scratch,
                                threads, nf::DualWarp::kRotate);
      });
  nf::Pose T_cur_prev;
  T_cur_prev.R = R_cur_prev;
  nf::SolverState moved;
  time(
      1, [&] { moved = state; },
      [&] {
        nf::warpStateByMotion(moved, depth_prev, problem.K, T_cur_prev,
                              motion_scratch, threads, nf::DualWarp::kReset);
      });
  in::EdgeWeightScratch edge_scratch;
  nf::PlanarImage weights;
  time(
      2, [] {},
      [&] {
        in::computeEdgeWeightsInto(problem.image, settings_.edges, weights,
                                   edge_scratch, threads);
      });
  in::PreparedLevel level;
  time(
      3, [] {},
      [&] {
        in::prepareFinestInto(problem, settings_, level, edge_scratch, threads);
      });
  // The statistics again on the prepared inputs (their weights restored
  // first: the density correction scales them in place).
  std::vector<nf::PlanarImage> weights_after = level.data_weight;
  std::vector<nf::PlanarImage> eps = level.data_eps, means = level.data_mean;
  time(
      4, [&] { level.data_weight = weights_after; },
      [&] {
        for (int l = 0; l < level.num_inputs; ++l) {
          in::applyLocalStatistics(settings_, level.data[l], eps[l],
                                   level.data_weight[l], &means[l], threads);
        }
      });
  level.data_weight = weights_after;
  // The warm start's passes on the rotation warp's state.
  nf::PlanarImage normals;
  std::vector<unsigned char> unknown, edge_scratch_map;
  time(
      5, [&] { normals = work.normals; },
      [&] {
        in::sanitizeWarmStart(level, settings_.visibility, normals, unknown,
                              threads);
      });
  const std::vector<unsigned char> sanitized = unknown;
  time(
      6, [&] { unknown = sanitized; },
      [&] {
        in::markInconsistentPixels(level, normals, settings_.local_radius,
                                   unknown, threads);
        in::markMapEdges(normals, unknown, edge_scratch_map, threads);
      });
  in::ActiveSet active;
  active.preallocate(level.width, level.height);
  time(
      7, [] {},
      [&] {
        active.build(unknown, level.width, level.height,
                     settings_.warm_refine_radius);
      });
  std::vector<unsigned char> known;
  std::vector<unsigned char> filled;
  std::vector<int> pending;
  nf::PlanarImage filled_normals;
  time(
      8,
      [&] {
        known = unknown;
        for (unsigned char& u : known) u = u == 1 ? 0 : 1;
        filled_normals = normals;
      },
      [&] {
        in::fillUnknownPixels(level, settings_.huber_eps, settings_.penalty,
                              settings_.visibility == nf::VisibilityMode::kSoft,
                              filled_normals, known, active, 5, filled, pending,
                              threads);
      });
  in::IterationState iteration;
  iteration.resize(level.width, level.height, level.num_inputs);
  iteration.n0 = filled_normals;
  iteration.p_h.fill(0.0f);
  iteration.p_v.fill(0.0f);
  for (nf::PlanarImage& q : iteration.q) q.fill(0.0f);
  in::ActiveBuffers gathered;
  time(
      9, [] {},
      [&] {
        gathered.gather(level, iteration, active, threads);
        gathered.energy(settings_.huber_eps, settings_.penalty, threads);
      });
  // What closing a whole-image outer step adds: the guided weights of the
  // new n0 and the energy under them.
  in::DynamicGuidance guidance;
  time(
      14, [&] { guidance.end(); },
      [&] {
        guidance.begin(level, level, in::guidanceTerms(settings_), threads);
      });
  time(
      12, [] {}, [&] { guidance.reweight(filled_normals, threads); });
  guidance.end();
  time(
      13, [] {},
      [&] {
        in::EnergyTerms terms;
        terms.huber_eps = settings_.huber_eps;
        terms.penalty = settings_.penalty;
        in::kernelBackend(settings_.backend)
            .energy(level, terms, filled_normals, threads);
      });
  // The face correction's parts on the refinement's start.
  in::EnergyTerms terms;
  terms.huber_eps = settings_.huber_eps;
  terms.penalty = settings_.penalty;
  const in::FaceCorrection::EnergyFunction energy_of =
      [&](const nf::PlanarImage& n) {
        return in::kernelBackend(settings_.backend)
            .energy(level, terms, n, threads);
      };
  in::FaceCorrection faces;
  faces.reserve(level.width, level.height, threads);
  time(
      16, [] {},
      [&] {
        faces.begin(filled_normals, settings_.warm_face_degrees, energy_of,
                    threads);
      });
  time(
      17, [] {},
      [&] {
        faces.buildModel(level, terms.huber_eps, terms.penalty, filled_normals,
                         threads);
      });
  nf::PlanarImage stepped;
  time(
      18,
      [&] {
        stepped = filled_normals;
        faces.begin(stepped, settings_.warm_face_degrees, energy_of, threads);
      },
      [&] {
        faces.step(level, terms.huber_eps, terms.penalty,
                   settings_.visibility == nf::VisibilityMode::kSoft, energy_of,
                   stepped, threads);
      });
  for (const bool plane : {false, true}) {
    time(
        plane ? 11 : 10, [] {},
        [&] {
          for (int l = 0; l < level.num_inputs; ++l) {
            in::estimateNoise(level.data[l], settings_.local_radius, 4, threads,
                              plane);
          }
        });
  }
}

void PartsRun::run() {
  const std::vector<nf::synthetic::Frame> sequence =
      nf::synthetic::renderSequence(0, o_.width, o_.height, o_.frames + 1, 0.3);
  settings_.num_threads = o_.threads;
  settings_.time_budget_ms = 33.0;
  nf::StreamSettings stream;
  stream.solver.num_threads = o_.threads;
  stream.solver.relative_tolerance = 1e-6;
  stream.solver.max_total_inner_iterations = 4000;
  stream.solver.max_outer_iterations = 400;
  nf::StreamFuser fuser(stream, "bench_frame_parts");
  nf::StreamResult result;
  nf::FusionProblem first = makeProblem(sequence[0], 0);
  // Frame 0 converged (bench_streaming's start-up), then the live settings.
  fuser.fuse(0, first, nf::FrameRotation::still(),
             std::chrono::steady_clock::now(), &result);
  fuser.endFrame(0.0);
  stream.solver = settings_;
  fuser.setSettings(stream);
  for (int k = 1; k <= o_.frames; ++k) {
    nf::FusionProblem problem = makeProblem(sequence[k], k);
    const nf::ScalarMap depth_prev = sequence[k - 1].depth;
    const std::array<double, 9> R_cur_prev =
        nf::synthetic::relativeRotation(sequence[k].pose, sequence[k - 1].pose);
    frame(problem, depth_prev, R_cur_prev, fuser.state());
    // One live frame per sequence frame (its time into the last stage).
    const auto start = std::chrono::steady_clock::now();
    fuser.fuse(std::llround(k * 1e9 / 30.0), problem,
               nf::FrameRotation::known(R_cur_prev), start, &result);
    const double ms = 1e3 * fuser.endFrame(0.0);
    stages_.back().all.push_back(ms);
    stages_.back().frame_median.push_back(ms);
  }
  print();
}

void PartsRun::print() const {
  std::printf("%s\n", nf::bench::machineLine().c_str());
  std::printf(
      "fixed cost of a streamed frame: %dx%d, scene 0 panning 0.3 deg/frame, "
      "two inputs, %d threads, OMP_WAIT_POLICY %s, %d frames x %d calls per "
      "stage\n\n",
      o_.width, o_.height, o_.threads,
      std::getenv("OMP_WAIT_POLICY") != nullptr ? std::getenv("OMP_WAIT_POLICY")
                                                : "unset",
      o_.frames, o_.repeats);
  std::printf(
      "| stage | median ms | fastest call ms | fastest frame ms | slowest "
      "frame ms |\n"
      "|---|---:|---:|---:|---:|\n");
  for (const Stage& stage : stages_) {
    const auto range = std::minmax_element(stage.frame_median.begin(),
                                           stage.frame_median.end());
    std::printf("| %s | %.2f | %.2f | %.2f | %.2f |\n", stage.name,
                nf::bench::median(stage.all),
                *std::min_element(stage.all.begin(), stage.all.end()),
                *range.first, *range.second);
  }
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  if (!parseOptions(argc, argv, o)) return 2;
  PartsRun run(o);
  run.run();
  return 0;
}
