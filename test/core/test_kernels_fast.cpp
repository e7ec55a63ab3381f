// The fast backend against the reference: the same iterates after many
// iterations (plain TV, data thresholds, any threads and block depth) and the
// same energy.
#include <gtest/gtest.h>

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

INSTANTIATE_TEST_SUITE_P(
    Backends, FastMatchesReference,
    ::testing::Combine(::testing::Values(1, 2, 3),
                       ::testing::Values(DataPenalty::kL2,
                                         DataPenalty::kSquaredL2),
                       ::testing::Values(false, true)));

}  // namespace
}  // namespace normal_fusion
