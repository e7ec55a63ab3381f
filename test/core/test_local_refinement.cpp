// The local refinement's parts: the active set, active iterations against
// the whole-image ones and across thread counts, the active energy, the
// thread chooser, map edges and the filling of unknown pixels.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

#include "normal_fusion/detail/solver_internal.h"
#include "solver_kernel_test_util.h"
#include "test_util.h"

namespace normal_fusion {
namespace {

using test::initState;
using test::maxAbsDiff;
using test::preconditionedParams;
using test::randomLevel;

/// Seeds of a local refinement: each pixel with probability `density`.
std::vector<unsigned char> randomSeeds(int W, int H, double density,
                                       std::uint64_t seed) {
  const PlanarImage u = test::randomImage(W, H, 1, seed);
  std::vector<unsigned char> seeds(static_cast<std::size_t>(W) * H);
  for (std::size_t i = 0; i < seeds.size(); ++i) {
    seeds[i] = std::abs(u.data()[i]) < density ? 1 : 0;
  }
  return seeds;
}

TEST(ActiveSet, DilatesTheSeedsAndListsEachTouchingLinkOnce) {
  const int W = 23, H = 17;
  const auto seeds = randomSeeds(W, H, 0.04, 5);
  internal::ActiveSet active;
  for (int radius : {0, 1, 2}) {
    active.build(seeds, W, H, radius);
    // The mask against a brute-force dilation.
    std::vector<int> expected_pixels;
    for (int y = 0; y < H; ++y) {
      for (int x = 0; x < W; ++x) {
        bool near = false;
        for (int v = y - radius; v <= y + radius; ++v) {
          for (int u = x - radius; u <= x + radius; ++u) {
            near = near || (u >= 0 && v >= 0 && u < W && v < H &&
                            seeds[v * W + u] != 0);
          }
        }
        ASSERT_EQ(active.mask[y * W + x], near ? 1 : 0)
            << x << "," << y << " r " << radius;
        if (near) expected_pixels.push_back(y * W + x);
      }
    }
    EXPECT_EQ(active.pixels, expected_pixels);
    // Links with an active end, each once, in order.
    std::vector<int> expected_h, expected_v;
    for (int y = 0; y < H; ++y) {
      for (int x = 0; x < W; ++x) {
        const int i = y * W + x;
        if (x + 1 < W && (active.mask[i] || active.mask[i + 1]))
          expected_h.push_back(i);
        if (y + 1 < H && (active.mask[i] || active.mask[i + W]))
          expected_v.push_back(i);
      }
    }
    EXPECT_EQ(active.links_h, expected_h) << "r " << radius;
    EXPECT_EQ(active.links_v, expected_v) << "r " << radius;
  }
  // Radius 2 reaches further than 0.
  active.build(seeds, W, H, 0);
  const std::size_t seeds_only = active.pixels.size();
  active.build(seeds, W, H, 2);
  EXPECT_GT(active.pixels.size(), 3 * seeds_only);
}

/// With every pixel active, the active iteration is the whole-image one.
TEST(ActiveIterations, AllActiveEqualsTheWholeImageIteration) {
  const int W = 21, H = 13, L = 2;
  const auto level = randomLevel(W, H, L, 61, /*data_huber=*/true);
  const internal::InnerParams params = preconditionedParams(L, 1);
  internal::ActiveSet active;
  active.build(std::vector<unsigned char>(W * H, 1), W, H, 0);
  ASSERT_EQ(active.pixels.size(), static_cast<std::size_t>(W * H));
  internal::IterationState whole, local;
  initState(level, whole);
  initState(level, local);
  internal::runInnerReference(level, params, whole, 40);
  internal::runInnerActive(level, params, local, active, 40);
  EXPECT_LT(maxAbsDiff({{&whole.n, &local.n},
                        {&whole.nbar, &local.nbar},
                        {&whole.p_h, &local.p_h},
                        {&whole.p_v, &local.p_v},
                        {&whole.q[1], &local.q[1]}}),
            1e-6);
}

/// The gathered fast path against the reference active iteration, and the
/// pixels outside the set untouched.
TEST(ActiveIterations, FastMatchesReferenceAndLeavesOtherPixelsAlone) {
  const int W = 41, H = 29;
  for (int L : {1, 2, 3}) {
    for (DataPenalty penalty : {DataPenalty::kL2, DataPenalty::kSquaredL2}) {
      const auto level = randomLevel(W, H, L, 70 + L, /*data_huber=*/true);
      internal::InnerParams params = preconditionedParams(L, 2);
      params.penalty = penalty;
      internal::ActiveSet active;
      active.build(randomSeeds(W, H, 0.03, 80 + L), W, H, 1);
      internal::IterationState start, ref, fast;
      for (internal::IterationState* s : {&start, &ref, &fast}) {
        initState(level, *s);
        // Nonzero duals everywhere, as a warm start carries them.
        s->p_h = test::randomImage(W, H, 3, 90, 0.01f);
        s->p_v = test::randomImage(W, H, 3, 91, 0.01f);
      }
      internal::runInnerActive(level, params, ref, active, 50);
      internal::ActiveBuffers buffers;
      buffers.gather(level, fast, active);
      internal::runInnerActiveFast(level, params, buffers, 50);
      buffers.scatter(fast);
      double n_diff = 0.0;
      for (int k = 0; k < buffers.num_active; ++k) {
        const int i = active.pixels[k];
        for (int c = 0; c < 3; ++c) {
          n_diff = std::max(n_diff, static_cast<double>(std::abs(
                                        buffers.n[c][k] - ref.n.plane(c)[i])));
        }
      }
      EXPECT_LT(n_diff, 1e-4) << "L " << L;
      EXPECT_LT(maxAbsDiff({{&ref.p_h, &fast.p_h},
                            {&ref.p_v, &fast.p_v},
                            {&ref.q[L - 1], &fast.q[L - 1]}}),
                1e-4)
          << "L " << L;
      // The iterations did move the active pixels, and nothing else.
      double moved = 0.0;
      for (int y = 0; y < H; ++y) {
        for (int x = 0; x < W; ++x) {
          const int i = y * W + x;
          for (int c = 0; c < 3; ++c) {
            const float d = std::abs(ref.n.plane(c)[i] - start.n.plane(c)[i]);
            if (active.mask[i]) {
              moved = std::max(moved, static_cast<double>(d));
            } else {
              ASSERT_EQ(d, 0.0f) << x << "," << y;
              ASSERT_EQ(ref.q[0].plane(c)[i], start.q[0].plane(c)[i]);
              // A link between two inactive pixels keeps its dual.
              if (x + 1 < W && !active.mask[i + 1]) {
                ASSERT_EQ(ref.p_h.plane(c)[i], start.p_h.plane(c)[i]);
              }
            }
          }
        }
      }
      EXPECT_GT(moved, 1e-2);
    }
  }
}

/// The active terms of E change exactly as E does when only active pixels
/// change, and the gathered energy is the same sum.
TEST(ActiveEnergy, ChangesAsTheWholeEnergy) {
  const int W = 33, H = 21, L = 2;
  const auto level = randomLevel(W, H, L, 17, /*data_huber=*/true);
  internal::ActiveSet active;
  active.build(randomSeeds(W, H, 0.05, 18), W, H, 1);
  internal::IterationState s;
  initState(level, s);
  PlanarImage changed = s.n0;
  const PlanarImage noise = test::randomImage(W, H, 3, 19);
  for (int i : active.pixels) {
    float v[3];
    for (int c = 0; c < 3; ++c) v[c] = changed.plane(c)[i] + noise.plane(c)[i];
    const float len = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    for (int c = 0; c < 3; ++c) changed.plane(c)[i] = v[c] / len;
  }
  for (DataPenalty penalty : {DataPenalty::kL2, DataPenalty::kSquaredL2}) {
    for (double eps : {0.0, 0.05}) {
      const double whole = internal::energy(level, eps, penalty, changed, 1) -
                           internal::energy(level, eps, penalty, s.n0, 1);
      const double local =
          internal::energyActive(level, eps, penalty, changed, active, 2) -
          internal::energyActive(level, eps, penalty, s.n0, active, 2);
      EXPECT_NEAR(local, whole, 1e-9 * (1.0 + std::abs(whole)));
      EXPECT_GT(std::abs(whole), 1.0);
      // Gathered at n0 = changed: the same terms (float sums).
      internal::IterationState at_changed;
      initState(level, at_changed);
      at_changed.n0 = changed;
      internal::ActiveBuffers buffers;
      buffers.gather(level, at_changed, active);
      const double expected =
          internal::energyActive(level, eps, penalty, changed, active, 1);
      EXPECT_NEAR(buffers.energy(eps, penalty), expected, 1e-5 * expected);
    }
  }
}

/// The gathered refinement gives the same bits on 1, 2 and 3 threads, its
/// energy included: the premise of RefineThreadChooser, which switches the
/// count between steps. The set is large enough for every thread to work.
TEST(ActiveIterations, SameBitsForAnyThreadCount) {
  const int W = 160, H = 120, L = 2;
  const auto level = randomLevel(W, H, L, 31, /*data_huber=*/true);
  internal::ActiveSet active;
  active.build(randomSeeds(W, H, 0.15, 32), W, H, 1);
  internal::IterationState start;
  initState(level, start);
  start.p_h = test::randomImage(W, H, 3, 33, 0.01f);
  start.p_v = test::randomImage(W, H, 3, 34, 0.01f);
  std::vector<internal::ActiveBuffers> runs(3);
  std::vector<double> energies;
  for (int threads = 1; threads <= 3; ++threads) {
    internal::ActiveBuffers& b = runs[threads - 1];
    b.gather(level, start, active, threads);
    ASSERT_GT(b.num_active, 3 * 4096) << "too small to use every thread";
    internal::InnerParams params = preconditionedParams(L, threads);
    // Steps on alternating counts end where steps on one count do.
    for (int step = 0; step < 4; ++step) {
      params.num_threads = step % 2 == 0 ? threads : 1;
      internal::runInnerActiveFast(level, params, b, 5);
    }
    b.normalizeCandidate();
    energies.push_back(b.energy(0.05, DataPenalty::kL2, threads));
  }
  for (int t = 1; t < 3; ++t) {
    EXPECT_EQ(energies[t], energies[0]) << t + 1 << " threads";
    for (int ch = 0; ch < 3; ++ch) {
      EXPECT_EQ(runs[t].node_n[ch], runs[0].node_n[ch]) << t + 1 << " threads";
      EXPECT_EQ(runs[t].p[ch], runs[0].p[ch]) << t + 1 << " threads";
    }
    EXPECT_EQ(runs[t].q, runs[0].q) << t + 1 << " threads";
  }
  // And the steps did move the pixels.
  double moved = 0.0;
  for (int k = 0; k < runs[0].num_active; ++k) {
    moved = std::max(moved, static_cast<double>(std::abs(runs[0].node_n[0][k] -
                                                         runs[0].n0[0][k])));
  }
  EXPECT_GT(moved, 1e-2);
}

/// The refinement's thread count: each count measured first, then the
/// cheaper one, the other re-measured every kProbeInterval steps; a change
/// of load turns the choice.
TEST(RefineThreadChooser, RunsTheCheaperCountAndProbesTheOther) {
  using Chooser = internal::RefineThreadChooser;
  Chooser chooser;
  chooser.reset(1);
  for (int step = 0; step < 20; ++step) EXPECT_EQ(chooser.choose(), 1);

  chooser.reset(2);
  EXPECT_EQ(chooser.choose(), 2);  // nothing measured: all threads first
  chooser.record(2, 8e-9);
  EXPECT_EQ(chooser.choose(), 1);  // then one
  chooser.record(1, 12e-9);
  EXPECT_EQ(chooser.cost(1), 12e-9);
  EXPECT_EQ(chooser.cost(2), 8e-9);
  // Two threads cheaper: two, and one every kProbeInterval-th step.
  int ones = 0;
  for (int step = 0; step < 4 * Chooser::kProbeInterval; ++step) {
    const int threads = chooser.choose();
    chooser.record(threads, threads == 1 ? 12e-9 : 8e-9);
    ones += threads == 1 ? 1 : 0;
  }
  EXPECT_EQ(ones, 4);
  // The machine gets loaded: two threads now cost 20e-9, one still 12e-9.
  // The next step on two threads measures it, and one thread runs from then
  // on (two probed every kProbeInterval-th step).
  int first_one = -1, twos = 0;
  for (int step = 0; step < 4 * Chooser::kProbeInterval; ++step) {
    const int threads = chooser.choose();
    chooser.record(threads, threads == 1 ? 12e-9 : 20e-9);
    if (threads == 1 && first_one < 0) first_one = step;
    if (first_one >= 0 && threads == 2) ++twos;
  }
  EXPECT_LE(first_one, 1);
  EXPECT_GE(twos, 3);
  EXPECT_LE(twos, 4);
  // Unusable measurements are ignored.
  chooser.record(1, std::numeric_limits<double>::quiet_NaN());
  chooser.record(1, 0.0);
  chooser.record(1, -1.0);
  int ones_after = 0;
  for (int step = 0; step < Chooser::kProbeInterval; ++step) {
    ones_after += chooser.choose() == 1 ? 1 : 0;
  }
  EXPECT_EQ(ones_after, Chooser::kProbeInterval - 1);
}

/// A cost measured in a stall is not kept for good: each frame that takes no
/// step on it lowers it, until a step runs and measures it again.
TEST(RefineThreadChooser, ShrinksACostThatRefusesEveryStep) {
  internal::RefineThreadChooser chooser;
  chooser.reset(1);
  chooser.record(1, 10e-9);
  chooser.record(1, 10e-6);  // a step descheduled for a while
  // A 5-iteration step of 10 000 pixels, 1 ms left in the frame: refused
  // while the cost stays that high.
  auto fits = [&] { return 5 * 10000 * chooser.cost(1) <= 1e-3; };
  EXPECT_FALSE(fits());
  int frames = 0;
  while (!fits() && frames < 100) {
    chooser.shrink(1);
    ++frames;
  }
  EXPECT_LE(frames, 10);
  EXPECT_NEAR(chooser.cost(1),
              10e-6 * std::pow(internal::RefineThreadChooser::kShrink, frames),
              1e-12);
  // The next measurement replaces it.
  chooser.record(1, 12e-9);
  EXPECT_EQ(chooser.cost(1), 12e-9);
  // Each count separately; the cheaper count follows the costs (all
  // threads until both are measured).
  chooser.reset(2);
  EXPECT_EQ(chooser.cheaper(), 2);
  chooser.record(1, 12e-9);
  EXPECT_EQ(chooser.cheaper(), 2);
  chooser.record(2, 20e-9);
  EXPECT_EQ(chooser.cheaper(), 1);
  chooser.shrink(2);
  EXPECT_EQ(chooser.cost(1), 12e-9);
  EXPECT_NEAR(chooser.cost(2), 20e-9 * internal::RefineThreadChooser::kShrink,
              1e-18);
  EXPECT_EQ(chooser.cheaper(), 2);
}

/// Map edges: the pixels on both sides of a crease, not those next to an
/// unknown pixel only, and never an unknown one.
TEST(MarkMapEdges, MarksBothSidesOfACrease) {
  const int W = 12, H = 5;
  PlanarImage n(W, H, 3);
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const float s = x < 6 ? 0.6f : -0.6f;  // 74 degrees apart
      n.at(0, y, x) = s;
      n.at(2, y, x) = -0.8f;
    }
  }
  std::vector<unsigned char> unknown(W * H, 0), scratch;
  unknown[2 * W + 1] = 1;  // an unknown pixel away from the crease
  const int marked = internal::markMapEdges(n, unknown, scratch, 2);
  EXPECT_EQ(marked, 2 * H);
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const int expected = (y == 2 && x == 1) ? 1 : (x == 5 || x == 6) ? 2 : 0;
      EXPECT_EQ(unknown[y * W + x], expected) << x << "," << y;
    }
  }
}

/// Unknown pixels between two planes take the side their data supports.
TEST(FillUnknownPixels, TakesTheNeighbourThatFitsTheData) {
  const int W = 20, H = 8;
  internal::PreparedLevel level;
  level.width = W;
  level.height = H;
  level.num_inputs = 1;
  level.K = CameraIntrinsics(20, 20, W / 2.0, H / 2.0);
  level.K_inv = level.K.inverse();
  level.edge_weight = PlanarImage(W, H, 2, 1.0f);
  const float a[3] = {0.6f, 0.0f, -0.8f}, b[3] = {-0.6f, 0.0f, -0.8f};
  PlanarImage f(W, H, 3), n(W, H, 3);
  std::vector<unsigned char> known(W * H, 1), unknown(W * H, 0);
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const float* side = x < 10 ? a : b;
      for (int c = 0; c < 3; ++c) {
        f.at(c, y, x) = side[c];
        n.at(c, y, x) = x >= 7 && x < 13 ? 0.0f : side[c];
      }
      if (x >= 7 && x < 13) {
        known[y * W + x] = 0;
        unknown[y * W + x] = 1;
      }
    }
  }
  level.data = {f};
  level.data_weight = {PlanarImage(W, H, 1, 0.5f)};
  level.data_eps = {PlanarImage(W, H, 1, 0.0f)};
  internal::ActiveSet active;
  active.build(unknown, W, H, 0);
  std::vector<unsigned char> scratch;
  std::vector<int> pending;
  internal::fillUnknownPixels(level, 0.0, DataPenalty::kL2, true, n, known,
                              active, 16, scratch, pending, 2);
  for (int y = 0; y < H; ++y) {
    for (int x = 7; x < 13; ++x) {
      const float* side = x < 10 ? a : b;
      for (int c = 0; c < 3; ++c) {
        ASSERT_NEAR(n.at(c, y, x), side[c], 1e-6) << x << "," << y;
      }
      EXPECT_EQ(known[y * W + x], 1);
    }
  }
}

}  // namespace
}  // namespace normal_fusion
