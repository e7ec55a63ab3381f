// The solver's Deadline (what may still start under a time budget) and the
// kernel backends behind their common interface.
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <vector>

#include "normal_fusion/detail/deadline.h"
#include "normal_fusion/detail/kernel_backend.h"
#include "normal_fusion/detail/solver_levels.h"
#include "test_util.h"

namespace normal_fusion {
namespace {

using internal::Deadline;
using Clock = Deadline::Clock;

TEST(Deadline, WithoutABudgetEverythingMayStart) {
  Deadline deadline;
  deadline.start(Clock::now(), 0.0);
  EXPECT_FALSE(deadline.active());
  EXPECT_TRUE(deadline.allowsStep(Clock::now(), 1e9));
  EXPECT_TRUE(deadline.allowsLevel(1e9));
  EXPECT_TRUE(deadline.allowsChunk(1e9, 1e9));
  // The first chunk is whole; a measured speed changes nothing.
  EXPECT_EQ(deadline.chunkIterations(50, 0.0, 0.0, 50, 24), 50);
  EXPECT_EQ(deadline.chunkIterations(30, 1e3, 1e3, 50, 24), 30);
}

TEST(Deadline, MarginAndReserveDecideWhatStarts) {
  Deadline deadline;
  const Clock::time_point now = Clock::now();
  deadline.start(now, 1000.0 * 1000.0);  // 1000 s
  ASSERT_TRUE(deadline.active());
  EXPECT_GT(deadline.secondsLeft(), 990.0);
  EXPECT_LE(deadline.secondsLeft(), 1000.0);
  // A step needs kMargin times its expected cost.
  EXPECT_TRUE(deadline.allowsStep(now, 600.0));
  EXPECT_FALSE(deadline.allowsStep(now, 700.0));
  EXPECT_TRUE(deadline.allowsLevel(600.0));
  EXPECT_FALSE(deadline.allowsLevel(700.0));
  // A chunk and the reserve that closes the outer step.
  EXPECT_TRUE(deadline.allowsChunk(400.0, 500.0));
  EXPECT_FALSE(deadline.allowsChunk(600.0, 500.0));
}

TEST(Deadline, ChunksFitWhatIsLeft) {
  Deadline deadline;
  deadline.start(Clock::now(), 1000.0 * 1000.0);
  // Not measured yet: the first chunk.
  EXPECT_EQ(deadline.chunkIterations(50, 0.0, 0.0, 2, 1000), 2);
  // 100 s per iteration, 1000 s left (less a little): 9 iterations; with a
  // 500 s reserve 4.
  EXPECT_EQ(deadline.chunkIterations(50, 100.0, 0.0, 2, 1000), 9);
  EXPECT_EQ(deadline.chunkIterations(50, 100.0, 500.0, 2, 1000), 4);
  // No more than wanted, nor than the cap.
  EXPECT_EQ(deadline.chunkIterations(3, 1.0, 0.0, 2, 1000), 3);
  EXPECT_EQ(deadline.chunkIterations(50, 1.0, 0.0, 2, 24), 24);
}

TEST(Deadline, APassedDeadlineAllowsOneIterationAndNoStep) {
  Deadline deadline;
  deadline.start(Clock::now() - std::chrono::seconds(1), 500.0);
  EXPECT_LT(deadline.secondsLeft(), 0.0);
  EXPECT_FALSE(deadline.allowsStep(Clock::now(), 0.0));
  EXPECT_FALSE(deadline.allowsChunk(0.0, 0.0));
  EXPECT_FALSE(deadline.allowsLevel(0.0));
  EXPECT_EQ(deadline.chunkIterations(50, 1e-3, 0.0, 2, 24), 1);
}

TEST(KernelBackend, TheSettingPicksTheBackend) {
  EXPECT_EQ(&internal::kernelBackend(SolverBackend::kReference),
            &internal::referenceBackend());
  EXPECT_EQ(&internal::kernelBackend(SolverBackend::kFast),
            &internal::fastBackend());
  // Only the fast backend's refinement may run on fewer threads.
  EXPECT_FALSE(internal::referenceBackend().measuresRefinementThreads());
  EXPECT_TRUE(internal::fastBackend().measuresRefinementThreads());
}

/// A prepared two-plane problem with noise and its cold start.
struct Prepared {
  internal::PreparedLevel level;
  internal::IterationState state;
};

Prepared prepareNoisyScene(const SolverSettings& settings) {
  const int W = 40, H = 30;
  NormalMap gt;
  FusionProblem problem = test::twoPlaneScene(W, H, &gt);
  NormalInput input;
  input.normals = test::noisy(gt, 0.2, 3);
  problem.inputs = {input};
  Prepared p;
  p.level = internal::prepareFinest(problem, settings);
  p.level.problem_image = nullptr;  // the problem goes out of scope
  p.state.resize(W, H, p.level.num_inputs);
  internal::initializeCold(p.level, settings.visibility, p.state.n0, 1);
  p.state.n = p.state.n0;
  p.state.nbar = p.state.n0;
  p.state.p_h.fill(0.0f);
  p.state.p_v.fill(0.0f);
  for (PlanarImage& q : p.state.q) q.fill(0.0f);
  return p;
}

internal::InnerParams innerParams(const SolverSettings& settings, int L) {
  internal::InnerParams params;
  params.tau = static_cast<float>(1.0 / (4.0 + L));
  params.sigma = 0.5f;
  params.sigma_data = 1.0f;
  params.huber_eps = static_cast<float>(settings.huber_eps);
  params.penalty = settings.penalty;
  params.soft_visibility = settings.visibility == VisibilityMode::kSoft;
  params.num_threads = 2;
  return params;
}

TEST(KernelBackend, BothBackendsLowerTheEnergyAlike) {
  SolverSettings settings;
  const internal::EnergyTerms terms{settings.huber_eps, settings.penalty};
  std::vector<double> energies;
  for (const internal::KernelBackend* backend :
       {&internal::referenceBackend(), &internal::fastBackend()}) {
    Prepared p = prepareNoisyScene(settings);
    const double start = backend->energy(p.level, terms, p.state.n0, 1);
    ASSERT_TRUE(backend->runInner(
        p.level, innerParams(settings, p.level.num_inputs), p.state, 30));
    PlanarImage candidate;
    internal::normalizeInto(p.state.n, candidate, 1);
    const double e = backend->energy(p.level, terms, candidate, 1);
    EXPECT_LT(e, start);
    energies.push_back(e);
  }
  EXPECT_NEAR(energies[1], energies[0], 1e-4 * energies[0]);
}

TEST(KernelBackend, RefinementStepsAgreeAndARejectKeepsTheIterate) {
  SolverSettings settings;
  const internal::EnergyTerms terms{settings.huber_eps, settings.penalty};
  std::vector<double> candidates;
  std::vector<PlanarImage> results;
  for (const internal::KernelBackend* backend :
       {&internal::referenceBackend(), &internal::fastBackend()}) {
    Prepared p = prepareNoisyScene(settings);
    const int W = p.level.width, H = p.level.height;
    internal::RefinementBuffers refine;
    std::vector<unsigned char> seed(static_cast<std::size_t>(W) * H, 0);
    for (int y = 10; y < 20; ++y) {
      for (int x = 12; x < 28; ++x) seed[y * W + x] = 1;
    }
    refine.active.build(seed, W, H, 1);
    const internal::InnerParams params =
        innerParams(settings, p.level.num_inputs);
    const double begin =
        backend->beginRefinement(p.level, terms, p.state, refine, 2);
    ASSERT_TRUE(backend->runRefinement(p.level, params, p.state, refine, 5));
    const double first =
        backend->candidateEnergy(p.level, terms, p.state, refine, 2);
    EXPECT_LT(first, begin);
    // Rejected, the next step goes on from the iterate: its candidate is
    // that of 10 iterations in a row.
    backend->rejectCandidate(p.state, refine);
    ASSERT_TRUE(backend->runRefinement(p.level, params, p.state, refine, 5));
    candidates.push_back(
        backend->candidateEnergy(p.level, terms, p.state, refine, 2));
    backend->acceptCandidate(p.state, refine);
    backend->endRefinement(p.state, refine, 2);
    results.push_back(p.state.n0);
    // The same 10 iterations without the rejected candidate between them.
    Prepared straight = prepareNoisyScene(settings);
    internal::RefinementBuffers refine_straight;
    refine_straight.active.build(seed, W, H, 1);
    backend->beginRefinement(straight.level, terms, straight.state,
                             refine_straight, 2);
    ASSERT_TRUE(backend->runRefinement(straight.level, params, straight.state,
                                       refine_straight, 10));
    EXPECT_EQ(backend->candidateEnergy(straight.level, terms, straight.state,
                                       refine_straight, 2),
              candidates.back());
  }
  EXPECT_NEAR(candidates[1], candidates[0], 1e-4 * candidates[0]);
  double max_diff = 0.0;
  for (std::size_t i = 0; i < results[0].pixelCount() * 3; ++i) {
    max_diff =
        std::max(max_diff, static_cast<double>(std::abs(results[0].data()[i] -
                                                        results[1].data()[i])));
  }
  EXPECT_LT(max_diff, 1e-3);
}

}  // namespace
}  // namespace normal_fusion
