// The fast backend against the reference: the same iterates after many
// iterations (plain TV, data thresholds, any threads and block depth, the
// relaxed iteration) and the same energy.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <tuple>

#include "normal_fusion/detail/solver_internal.h"
#include "solver_kernel_test_util.h"
#include "test_util.h"

namespace normal_fusion {
namespace {

using test::initState;
using test::maxAbsDiff;
using test::preconditionedParams;
using test::randomLevel;

class FastMatchesReference
    : public ::testing::TestWithParam<std::tuple<int, DataPenalty, bool>> {};

TEST_P(FastMatchesReference, SameIteratesAfterManyIterations) {
  const int L = std::get<0>(GetParam());
  const auto level = randomLevel(37, 23, L, 42 + L);
  internal::InnerParams params;
  params.tau = params.sigma = params.sigma_data =
      static_cast<float>(0.99 / std::sqrt(8.0 + L));
  params.huber_eps = 0.05f;
  params.penalty = std::get<1>(GetParam());
  params.soft_visibility = std::get<2>(GetParam());
  params.num_threads = 2;
  internal::IterationState ref, fast;
  initState(level, ref);
  initState(level, fast);
  internal::runInnerReference(level, params, ref, 60);
  internal::runInnerFast(level, params, fast, 60);
  EXPECT_LT(maxAbsDiff({{&ref.n, &fast.n},
                        {&ref.p_h, &fast.p_h},
                        {&ref.p_v, &fast.p_v},
                        {&ref.q[L - 1], &fast.q[L - 1]}}),
            1e-4);
  const double e_ref = internal::energy(level, 0.05, params.penalty, ref.n, 1);
  const double e_fast =
      internal::energy(level, 0.05, params.penalty, fast.n, 1);
  EXPECT_NEAR(e_fast, e_ref, 1e-4 * std::abs(e_ref));
}

/// Plain TV (eps = 0) on the smoothness terms: the fast Huber dual step
/// a w / max(w + sigma eps, |a|) becomes the clamp to w.
TEST(FastMatchesReferencePlainTv, SameIteratesAfterManyIterations) {
  for (int L : {1, 2}) {
    const auto level = randomLevel(37, 23, L, 70 + L, /*data_huber=*/true);
    internal::InnerParams params = preconditionedParams(L, 2);
    params.huber_eps = 0.0f;
    internal::IterationState ref, fast;
    initState(level, ref);
    initState(level, fast);
    internal::runInnerReference(level, params, ref, 60);
    internal::runInnerFast(level, params, fast, 60);
    EXPECT_LT(
        maxAbsDiff(
            {{&ref.n, &fast.n}, {&ref.p_h, &fast.p_h}, {&ref.p_v, &fast.p_v}}),
        1e-4)
        << "L " << L;
    const double e_ref =
        internal::energy(level, 0.0, DataPenalty::kL2, ref.n, 1);
    const double e_fast =
        internal::energyFast(level, 0.0, DataPenalty::kL2, fast.n, 2);
    EXPECT_NEAR(e_fast, e_ref, 1e-4 * std::abs(e_ref)) << "L " << L;
    // The smoothness duals reach the clamp somewhere (|p| = w), so the test
    // sees the eps = 0 case of the step, not only its interior.
    bool clamped = false;
    for (int i = 0; i < 37 * 23 && !clamped; ++i) {
      const float w = level.edge_weight.plane(0)[i];
      const float len = std::sqrt(fast.p_h.plane(0)[i] * fast.p_h.plane(0)[i] +
                                  fast.p_h.plane(1)[i] * fast.p_h.plane(1)[i] +
                                  fast.p_h.plane(2)[i] * fast.p_h.plane(2)[i]);
      clamped = w > 0.0f && std::abs(len - w) < 1e-5f * w;
    }
    EXPECT_TRUE(clamped) << "L " << L;
  }
}

/// The same with per-pixel Huber thresholds on the data terms.
TEST(FastMatchesReferenceDataHuber, SameIteratesAfterManyIterations) {
  for (int L : {1, 2, 3}) {
    const auto level = randomLevel(37, 23, L, 90 + L, /*data_huber=*/true);
    const internal::InnerParams params = preconditionedParams(L, 2);
    internal::IterationState ref, fast;
    initState(level, ref);
    initState(level, fast);
    internal::runInnerReference(level, params, ref, 60);
    internal::runInnerFast(level, params, fast, 60);
    EXPECT_LT(maxAbsDiff({{&ref.n, &fast.n}, {&ref.q[L - 1], &fast.q[L - 1]}}),
              1e-4)
        << "L " << L;
    // The thresholds change the iterates: a run without them differs.
    auto plain = level;
    plain.data_huber = false;
    internal::IterationState other;
    initState(plain, other);
    internal::runInnerReference(plain, params, other, 60);
    EXPECT_GT(maxAbsDiff({{&other.q[0], &ref.q[0]}}), 1e-2) << "L " << L;
    const double e_ref =
        internal::energy(level, 0.05, DataPenalty::kL2, ref.n, 1);
    const double e_fast =
        internal::energyFast(level, 0.05, DataPenalty::kL2, fast.n, 2);
    EXPECT_NEAR(e_fast, e_ref, 1e-4 * std::abs(e_ref));
  }
}

/// The temporal-blocking pipeline gives the same iterates for any thread
/// count, block depth and iteration count (rounds that do not divide evenly,
/// threads with nothing to do in a round).
TEST(FastPipeline, SameIteratesForAnyThreadsDepthAndCount) {
  const auto level = randomLevel(29, 17, 2, 7, /*data_huber=*/true);
  // Diagonal preconditioning steps (different dual steps per term).
  internal::InnerParams params = preconditionedParams(2, 1);
  for (int iterations : {1, 5, 13, 40}) {
    internal::IterationState ref;
    initState(level, ref);
    internal::runInnerReference(level, params, ref, iterations);
    for (int threads : {1, 2, 3}) {
      for (int depth : {1, 4, 32}) {
        params.num_threads = threads;
        params.block_depth = depth;
        internal::IterationState fast;
        initState(level, fast);
        internal::runInnerFast(level, params, fast, iterations);
        const double max_diff =
            maxAbsDiff({{&fast.n, &ref.n}, {&fast.p_v, &ref.p_v}});
        EXPECT_LT(max_diff, 1e-5) << "iterations " << iterations << " threads "
                                  << threads << " depth " << depth;
      }
    }
  }
}

TEST(FastEnergy, MatchesTheReferenceEnergy) {
  for (int L : {1, 3}) {
    for (bool data_huber : {false, true}) {
      const auto level = randomLevel(45, 31, L, 3 + L, data_huber);
      const PlanarImage n = test::randomImage(45, 31, 3, 77);
      for (DataPenalty penalty : {DataPenalty::kL2, DataPenalty::kSquaredL2}) {
        for (double eps : {0.0, 0.05, 0.5}) {
          const double e_ref = internal::energy(level, eps, penalty, n, 1);
          const double e_fast = internal::energyFast(level, eps, penalty, n, 2);
          EXPECT_NEAR(e_fast, e_ref, 1e-5 * e_ref)
              << "L " << L << " eps " << eps << " data_huber " << data_huber;
        }
      }
    }
  }
}

/// The relaxed iteration (relaxation 1.8): the same iterates from both
/// backends for each data penalty, with and without data thresholds and soft
/// visibility, on any thread count and block depth; and not those of the
/// plain iteration.
TEST(FastMatchesReferenceRelaxed, SameIteratesAfterManyIterations) {
  for (DataPenalty penalty : {DataPenalty::kL2, DataPenalty::kSquaredL2}) {
    for (bool data_huber : {false, true}) {
      for (bool soft : {false, true}) {
        const auto level = randomLevel(31, 19, 2, 11, data_huber);
        internal::InnerParams params = preconditionedParams(2, 1);
        params.penalty = penalty;
        params.soft_visibility = soft;
        params.relaxation = 1.8f;
        internal::IterationState ref;
        initState(level, ref);
        internal::runInnerReference(level, params, ref, 60);
        for (int threads : {1, 2, 3}) {
          for (int depth : {1, 6}) {
            params.num_threads = threads;
            params.block_depth = depth;
            internal::IterationState fast;
            initState(level, fast);
            internal::runInnerFast(level, params, fast, 60);
            EXPECT_LT(maxAbsDiff({{&ref.n, &fast.n},
                                  {&ref.nbar, &fast.nbar},
                                  {&ref.p_h, &fast.p_h},
                                  {&ref.p_v, &fast.p_v},
                                  {&ref.q[0], &fast.q[0]},
                                  {&ref.q[1], &fast.q[1]}}),
                      1e-4)
                << "penalty " << toString(penalty) << " data_huber "
                << data_huber << " soft " << soft << " threads " << threads
                << " depth " << depth;
          }
        }
        internal::IterationState plain;
        initState(level, plain);
        params.relaxation = 1.0f;
        internal::runInnerReference(level, params, plain, 60);
        EXPECT_GT(maxAbsDiff({{&plain.n, &ref.n}}), 1e-3)
            << "penalty " << toString(penalty) << " data_huber " << data_huber
            << " soft " << soft;
      }
    }
  }
}

/// Relaxation 1.8 reaches the inner problem's minimum (the energy at the
/// tangent-plane iterate) that the plain iteration converges to, and gets
/// closer to it in the same number of iterations.
TEST(RelaxedIteration, SameMinimumReachedSooner) {
  const auto level = randomLevel(40, 30, 2, 5, /*data_huber=*/true);
  internal::InnerParams params = preconditionedParams(2, 2);
  params.huber_eps = 0.0f;
  auto energyAfter = [&](float rho, int iterations) {
    params.relaxation = rho;
    internal::IterationState s;
    initState(level, s);
    internal::runInnerFast(level, params, s, iterations);
    return internal::energyFast(level, 0.0, DataPenalty::kL2, s.n, 2);
  };
  const double e_star =
      std::min(energyAfter(1.0f, 6000), energyAfter(1.8f, 6000));
  EXPECT_NEAR(energyAfter(1.8f, 6000), e_star, 1e-5 * e_star);
  EXPECT_NEAR(energyAfter(1.0f, 6000), e_star, 1e-5 * e_star);
  const double gap_plain = energyAfter(1.0f, 100) - e_star;
  const double gap_relaxed = energyAfter(1.8f, 100) - e_star;
  EXPECT_LT(gap_relaxed, gap_plain);
}

INSTANTIATE_TEST_SUITE_P(
    Backends, FastMatchesReference,
    ::testing::Combine(::testing::Values(1, 2, 3),
                       ::testing::Values(DataPenalty::kL2,
                                         DataPenalty::kSquaredL2),
                       ::testing::Values(false, true)));

}  // namespace
}  // namespace normal_fusion
