// Cancellation: Solver::requestCancel() from another thread ends a long
// solve promptly, at any stage (input preparation, coarse levels, the finest
// level's outer loop, a warm start's local refinement), with both backends,
// and leaves a usable state; a request made before solve() stops it at once
// and holds until clearCancel().
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <string>
#include <thread>

#include "normal_fusion/detail/solver_internal.h"
#include "normal_fusion/solver.h"
#include "test_util.h"

namespace normal_fusion {
namespace {

using Clock = std::chrono::steady_clock;

/// What the tests allow between the request and solve()'s return: a
/// deadline, not a benchmark (measured: a few ms to tens of ms).
constexpr double kDeadlineSeconds = 0.5;

double secondsBetween(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double>(b - a).count();
}

/// The cylinder scene, W x H, with two noisy inputs and a hole in both (a
/// cold start then runs on the pyramid, as the automatic setting picks it).
FusionProblem cylinderWithHole(int W, int H) {
  NormalMap gt;
  FusionProblem problem = test::cylinderScene(W, H, &gt);
  for (std::uint64_t l = 0; l < 2; ++l) {
    NormalInput input;
    input.normals = test::noisy(gt, 0.3, 5 + l);
    problem.inputs.push_back(input);
  }
  for (int y = H / 4; y < H / 2; ++y) {
    for (int x = W / 4; x < W / 2; ++x) {
      for (NormalInput& input : problem.inputs) {
        input.normals.at(2, y, x) = NAN;
      }
    }
  }
  return problem;
}

/// The state is of the problem's size, its normals finite and of unit
/// length, its duals finite.
void expectUsable(const SolverState& state, const FusionProblem& problem) {
  const int W = problem.image.width(), H = problem.image.height();
  const int L = static_cast<int>(problem.inputs.size());
  ASSERT_TRUE(state.compatible(W, H, L));
  long bad_normals = 0, bad_duals = 0;
  for (std::size_t i = 0; i < state.normals.pixelCount(); ++i) {
    const float x = state.normals.plane(0)[i], y = state.normals.plane(1)[i],
                z = state.normals.plane(2)[i];
    const float len = std::sqrt(x * x + y * y + z * z);
    bad_normals += std::isfinite(len) && std::abs(len - 1.0f) < 1e-3f ? 0 : 1;
    for (const PlanarImage* dual : {&state.dual_h, &state.dual_v}) {
      for (int c = 0; c < 3; ++c) {
        bad_duals += std::isfinite(dual->plane(c)[i]) ? 0 : 1;
      }
    }
    for (const PlanarImage& q : state.dual_data) {
      for (int c = 0; c < 3; ++c)
        bad_duals += std::isfinite(q.plane(c)[i]) ? 0 : 1;
    }
  }
  EXPECT_EQ(bad_normals, 0);
  EXPECT_EQ(bad_duals, 0);
}

/// Solves with a cancel requested from another thread `delay` seconds after
/// the call; returns the seconds from the request to the return.
double solveCancelledAfter(Solver& solver, const FusionProblem& problem,
                           SolverState& state, bool warm, double delay,
                           SolveReport& report) {
  Clock::time_point requested;
  std::thread canceller([&] {
    std::this_thread::sleep_for(std::chrono::duration<double>(delay));
    requested = Clock::now();
    solver.requestCancel();
  });
  solver.solve(problem, state, warm, report);
  const Clock::time_point returned = Clock::now();
  canceller.join();
  solver.clearCancel();
  return secondsBetween(requested, returned);
}

/// Where a cancelled solve stopped, for the log.
const char* stage(const SolveReport& r) {
  if (r.refine_iterations > 0) return "local refinement";
  if (r.inner_iterations > 0 || !r.energies.empty()) return "finest level";
  if (r.coarse_inner_iterations > 0) return "coarser level";
  return "before the iterations";
}

/// Cold solves that would take many seconds (the default settings, with
/// outer steps of 200 inner iterations: about 2 s each at 1920x1440 on two
/// threads, so the deadline holds only if the iterations themselves stop),
/// cancelled at several points: each returns within the deadline of the
/// request, marked cancelled, with a usable state. Fast backend at
/// 1920x1440; the reference backend, about 30 times slower per iteration
/// (0.29 s at 1920x1440 on one thread, so one iteration would nearly fill
/// the deadline), at 960x720.
TEST(Cancel, ColdSolveEndsPromptlyOnRequest) {
  for (SolverBackend backend :
       {SolverBackend::kFast, SolverBackend::kReference}) {
    const bool fast = backend == SolverBackend::kFast;
    const FusionProblem problem =
        fast ? cylinderWithHole(1920, 1440) : cylinderWithHole(960, 720);
    for (int pyramid : {0, 1}) {
      SolverSettings settings;
      settings.backend = backend;
      settings.num_threads = 2;
      settings.pyramid_levels = pyramid;  // 0: automatic (5 levels here)
      settings.inner_iterations = 200;
      settings.max_total_inner_iterations = 4000;
      Solver solver(settings);
      for (double delay : {0.02, 0.2, 0.6}) {
        SolverState state;
        SolveReport report;
        const double latency =
            solveCancelledAfter(solver, problem, state, false, delay, report);
        std::printf(
            "%s, %d pyramid levels, cancelled after %.2f s (%s): returned "
            "%.1f ms after the request\n",
            toString(backend).c_str(), report.pyramid_levels, delay,
            stage(report), 1e3 * latency);
        EXPECT_TRUE(report.cancelled);
        EXPECT_LT(latency, kDeadlineSeconds)
            << toString(backend) << ", delay " << delay;
        EXPECT_FALSE(report.converged);
        EXPECT_LT(report.inner_iterations, settings.max_total_inner_iterations);
        if (state.normals.empty()) {
          // Cancelled before the finest level: the state is unchanged.
          EXPECT_TRUE(std::isnan(report.final_energy));
          EXPECT_EQ(report.inner_iterations, 0);
        } else {
          expectUsable(state, problem);
        }
      }
    }
  }
}

/// A warm start whose local refinement would run for minutes (half the
/// image unknown, 10^5 iterations, no tolerance), cancelled while it runs:
/// returns within the deadline, with the refinement's accepted steps in a
/// usable state. Both backends; the reference at 960x720.
TEST(Cancel, LocalRefinementEndsPromptlyOnRequest) {
  for (SolverBackend backend :
       {SolverBackend::kFast, SolverBackend::kReference}) {
    const bool fast = backend == SolverBackend::kFast;
    const FusionProblem problem =
        fast ? cylinderWithHole(1920, 1440) : cylinderWithHole(960, 720);
    const int W = problem.image.width(), H = problem.image.height();
    SolverSettings settings;
    settings.backend = backend;
    settings.num_threads = 2;
    settings.pyramid_levels = 1;
    settings.max_total_inner_iterations = 1;
    settings.inner_iterations = 1;
    // A compatible state, its left half unknown (as a warp leaves a strip).
    SolverState start;
    Solver(settings).solve(problem, start, false);
    for (int y = 0; y < H; ++y) {
      for (int x = 0; x < W / 2; ++x) start.normals.at(0, y, x) = NAN;
    }
    // How long a warm frame with 5 refinement iterations takes (preparation,
    // warm start, refinement, 1 whole-image iteration): the request comes
    // 0.2 s after that, inside the long refinement.
    settings.warm_refine_iterations = 5;
    Solver solver(settings);
    SolverState probe = start;
    const SolveReport first = solver.solve(problem, probe, true);
    ASSERT_TRUE(first.warm_started);
    ASSERT_GT(first.refined_pixels, W * H / 2);
    settings.warm_refine_iterations = 100000;
    settings.relative_tolerance = 0.0;
    solver.setSettings(settings);
    SolverState state = start;
    SolveReport report;
    const double delay = first.seconds + 0.2;
    const double latency =
        solveCancelledAfter(solver, problem, state, true, delay, report);
    std::printf(
        "%s, warm start with %d pixels to refine, cancelled after %.2f s "
        "(%s, %d iterations): returned %.1f ms after the request\n",
        toString(backend).c_str(), report.refined_pixels, delay, stage(report),
        report.refine_iterations, 1e3 * latency);
    EXPECT_TRUE(report.cancelled);
    EXPECT_TRUE(report.warm_started);
    EXPECT_GT(report.refine_iterations, 0);
    EXPECT_LT(report.refine_iterations, settings.warm_refine_iterations);
    EXPECT_LT(latency, kDeadlineSeconds) << toString(backend);
    expectUsable(state, problem);
  }
}

/// The four iteration kernels (fast and reference, whole image and local
/// refinement) on their own, at 640x480 with two threads: with the request
/// clear they compute the same bits as without one; set before the call,
/// they return false at once with nothing changed; set by another thread
/// during a run of about 3 s worth of iterations, they return false within
/// the deadline of the request. Long because the four kernels share one
/// prepared level and state, and each check reads best beside the others.
TEST(Cancel, KernelsStopOnTheRequest) {
  const FusionProblem problem = cylinderWithHole(640, 480);
  const int W = 640, H = 480, L = 2;
  const internal::PreparedLevel level =
      internal::prepareFinest(problem, SolverSettings());
  internal::InnerParams params;
  params.tau = 1.0f / (4 + L);
  params.sigma = 0.5f;
  params.sigma_data = 1.0f;
  params.soft_visibility = true;
  params.num_threads = 2;
  // The state: n0 = n = nbar = the first input where it has one, else
  // facing the camera; duals 0. The local refinement: the left half.
  internal::IterationState start;
  start.resize(W, H, L);
  for (std::size_t i = 0; i < start.n0.pixelCount(); ++i) {
    const bool known = level.data_weight[0].plane(0)[i] > 0.0f;
    for (int c = 0; c < 3; ++c) {
      start.n0.plane(c)[i] =
          known ? level.data[0].plane(c)[i] : (c == 2 ? -1.0f : 0.0f);
    }
  }
  start.n = start.nbar = start.n0;
  for (PlanarImage* dual : {&start.p_h, &start.p_v, &start.q[0], &start.q[1]}) {
    dual->fill(0.0f);
  }
  std::vector<unsigned char> seed(static_cast<std::size_t>(W) * H, 0);
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W / 2; ++x) seed[y * W + x] = 1;
  }
  internal::ActiveSet active;
  active.build(seed, W, H, 1);

  enum Kernel { kFast, kReference, kActiveReference, kActiveFast };
  const char* names[] = {"runInnerFast", "runInnerReference", "runInnerActive",
                         "runInnerActiveFast"};
  for (Kernel kernel : {kFast, kReference, kActiveReference, kActiveFast}) {
    // Runs `iterations` of the kernel on a copy of the start with the
    // given request flag (null: none); its n (gathered back for the fast
    // refinement) and p_h come out.
    auto run = [&](int iterations, const std::atomic<bool>* cancel,
                   internal::IterationState& s) {
      s.n0 = start.n0;
      s.n = start.n;
      s.nbar = start.nbar;
      s.p_h = start.p_h;
      s.p_v = start.p_v;
      s.q = start.q;
      internal::InnerParams p = params;
      p.cancel = cancel;
      bool ran = false;
      switch (kernel) {
        case kFast:
          ran = internal::runInnerFast(level, p, s, iterations);
          break;
        case kReference:
          ran = internal::runInnerReference(level, p, s, iterations);
          break;
        case kActiveReference:
          ran = internal::runInnerActive(level, p, s, active, iterations);
          break;
        case kActiveFast: {
          internal::ActiveBuffers b;
          b.gather(level, s, active, 2);
          ran = internal::runInnerActiveFast(level, p, b, iterations);
          b.scatter(s, 2);
          for (int k = 0; k < b.num_active; ++k) {
            for (int c = 0; c < 3; ++c)
              s.n.plane(c)[b.node_pixel[k]] = b.n[c][k];
          }
          break;
        }
      }
      return ran;
    };
    auto same = [](const PlanarImage& a, const PlanarImage& b) {
      return std::memcmp(a.data(), b.data(),
                         a.pixelCount() * a.channels() * sizeof(float)) == 0;
    };
    // Clear: the same bits as without a flag (and the time per iteration).
    std::atomic<bool> flag{false};
    internal::IterationState plain, checked;
    ASSERT_TRUE(run(12, nullptr, plain));
    const Clock::time_point before = Clock::now();
    ASSERT_TRUE(run(12, &flag, checked)) << names[kernel];
    const double per_iteration = secondsBetween(before, Clock::now()) / 12;
    EXPECT_TRUE(same(plain.n, checked.n)) << names[kernel];
    EXPECT_TRUE(same(plain.p_h, checked.p_h)) << names[kernel];
    // Set before: nothing runs.
    flag.store(true);
    internal::IterationState stopped;
    EXPECT_FALSE(run(12, &flag, stopped)) << names[kernel];
    EXPECT_TRUE(same(stopped.n, start.n)) << names[kernel];
    EXPECT_TRUE(same(stopped.p_h, start.p_h)) << names[kernel];
    // Set during a long run (about 3 s of iterations).
    flag.store(false);
    const int iterations =
        static_cast<int>(std::ceil(3.0 / std::max(per_iteration, 1e-5)));
    Clock::time_point requested;
    std::thread canceller([&] {
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
      requested = Clock::now();
      flag.store(true);
    });
    internal::IterationState interrupted;
    const bool ran = run(iterations, &flag, interrupted);
    const Clock::time_point returned = Clock::now();
    canceller.join();
    const double latency = secondsBetween(requested, returned);
    std::printf(
        "%s: %.2f ms per iteration, %d iterations asked, stopped %.1f ms "
        "after the request\n",
        names[kernel], 1e3 * per_iteration, iterations, 1e3 * latency);
    EXPECT_FALSE(ran) << names[kernel];
    EXPECT_LT(latency, kDeadlineSeconds) << names[kernel];
  }
}

/// A request made before solve() stops it at once (the state untouched, not
/// even the problem validated), and every later solve until clearCancel();
/// after that a solve runs as on a solver never cancelled (the same bits).
TEST(Cancel, RequestBeforeSolveStopsItAtOnceUntilCleared) {
  const FusionProblem problem = cylinderWithHole(160, 120);
  SolverSettings settings;
  settings.num_threads = 2;
  settings.max_total_inner_iterations = 100;
  SolverState expected;
  const SolveReport uncancelled = Solver(settings).solve(problem, expected);
  EXPECT_FALSE(uncancelled.cancelled);

  Solver solver(settings);
  EXPECT_FALSE(solver.cancelRequested());
  solver.requestCancel();
  EXPECT_TRUE(solver.cancelRequested());
  SolverState state;
  for (int attempt = 0; attempt < 2; ++attempt) {
    const Clock::time_point before = Clock::now();
    const SolveReport report = solver.solve(problem, state, false);
    EXPECT_LT(secondsBetween(before, Clock::now()), 0.05);
    EXPECT_TRUE(report.cancelled);
    EXPECT_EQ(report.inner_iterations + report.coarse_inner_iterations, 0);
    EXPECT_TRUE(std::isnan(report.final_energy));
    EXPECT_TRUE(state.normals.empty());  // untouched
    EXPECT_TRUE(solver.cancelRequested());
  }
  // A warm state given to a cancelled solve stays as it was.
  SolverState warm = expected;
  EXPECT_TRUE(solver.solve(problem, warm, true).cancelled);
  EXPECT_EQ(0, std::memcmp(warm.normals.data(), expected.normals.data(),
                           3 * warm.normals.pixelCount() * sizeof(float)));
  // Not validated: a bad problem is not even looked at.
  EXPECT_TRUE(solver.solve(FusionProblem(), state, false).cancelled);

  solver.clearCancel();
  EXPECT_FALSE(solver.cancelRequested());
  const SolveReport report = solver.solve(problem, state, false);
  EXPECT_FALSE(report.cancelled);
  EXPECT_EQ(report.inner_iterations, uncancelled.inner_iterations);
  EXPECT_EQ(report.final_energy, uncancelled.final_energy);
  ASSERT_TRUE(state.compatible(160, 120, 2));
  EXPECT_EQ(0, std::memcmp(state.normals.data(), expected.normals.data(),
                           3 * state.normals.pixelCount() * sizeof(float)));
}

/// After a solve cancelled in its iterations, the same solver's next solve
/// (request cleared) gives the bits of a solver never cancelled, and the
/// cancelled state warm-starts a solve.
TEST(Cancel, CancelledSolveLeavesNoTraceInTheNext) {
  const FusionProblem problem = cylinderWithHole(640, 480);
  SolverSettings settings;
  settings.num_threads = 2;
  settings.max_total_inner_iterations = 3000;
  settings.relative_tolerance = 0.0;
  Solver solver(settings);
  SolverState cancelled_state;
  SolveReport report;
  // The request must land inside the finest level (one before it leaves the
  // state empty, as documented): on a loaded machine the preparation and
  // the coarser levels can outlast the first delay, so it doubles until then.
  for (double delay = 0.3; delay < 5.0; delay *= 2.0) {
    cancelled_state.clear();
    solveCancelledAfter(solver, problem, cancelled_state, false, delay, report);
    ASSERT_TRUE(report.cancelled);
    if (!cancelled_state.normals.empty()) break;
  }
  ASSERT_FALSE(cancelled_state.normals.empty());
  expectUsable(cancelled_state, problem);

  settings.max_total_inner_iterations = 60;
  solver.setSettings(settings);
  SolverState state, expected;
  Solver(settings).solve(problem, expected, false);
  EXPECT_FALSE(solver.solve(problem, state, false).cancelled);
  EXPECT_EQ(0, std::memcmp(state.normals.data(), expected.normals.data(),
                           3 * state.normals.pixelCount() * sizeof(float)));
  const SolveReport warm = solver.solve(problem, cancelled_state, true);
  EXPECT_TRUE(warm.warm_started);
  EXPECT_FALSE(warm.cancelled);
  expectUsable(cancelled_state, problem);
}

/// Requests made and withdrawn over and over while a multithreaded solve
/// runs (the fast backend's threads wait for each other in their sweeps):
/// the solve still ends, cancelled or not, with a usable state.
TEST(Cancel, RequestsWithdrawnDuringASolveDoNotHangIt) {
  const FusionProblem problem = cylinderWithHole(320, 240);
  for (SolverBackend backend :
       {SolverBackend::kFast, SolverBackend::kReference}) {
    SolverSettings settings;
    settings.backend = backend;
    settings.num_threads = 2;
    settings.max_total_inner_iterations = 100;
    Solver solver(settings);
    SolverState state;
    solver.solve(problem, state, false);
    std::atomic<bool> done{false};
    std::thread toggler([&] {
      while (!done.load()) {
        solver.requestCancel();
        std::this_thread::sleep_for(std::chrono::microseconds(200));
        solver.clearCancel();
        std::this_thread::sleep_for(std::chrono::microseconds(300));
      }
    });
    int cancelled = 0;
    for (int frame = 0; frame < 20; ++frame) {
      cancelled += solver.solve(problem, state, frame % 2 == 1).cancelled;
      expectUsable(state, problem);
    }
    done.store(true);
    toggler.join();
    std::printf("%s: %d of 20 solves cancelled\n", toString(backend).c_str(),
                cancelled);
  }
}

}  // namespace
}  // namespace normal_fusion
