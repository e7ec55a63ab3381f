// Tests of StampSynchronizer: sets by stamp alone, exact and approximate,
// optional topics, duplicates, time going back and bounded queues.
#include "normal_fusion/synchronizer.h"

#include <gtest/gtest.h>

#include <cstdint>
#include <random>
#include <vector>

namespace normal_fusion {
namespace {

using Sync = StampSynchronizer<int>;
constexpr std::int64_t kMs = 1000000;

Sync::Options syncOptions(bool approximate, std::int64_t max_interval_ms,
                          int queue = 10) {
  Sync::Options options;
  options.approximate = approximate;
  options.queue_size = queue;
  options.max_interval_ns = max_interval_ms * kMs;
  return options;
}

/// (topic, stamp in ms, payload) in arrival order.
struct Arrival {
  int topic;
  std::int64_t stamp_ms;
  int payload;
};

std::vector<Sync::Set> run(Sync& sync, const std::vector<Arrival>& arrivals,
                           bool flush = false) {
  std::vector<Sync::Set> sets;
  for (const Arrival& a : arrivals) {
    sync.add(a.topic, a.stamp_ms * kMs, a.payload);
    for (auto& s : sync.poll()) sets.push_back(std::move(s));
  }
  if (flush) {
    for (auto& s : sync.flush()) sets.push_back(std::move(s));
  }
  return sets;
}

TEST(Synchronizer, ExactStampsFormSetsInAnyArrivalOrder) {
  std::vector<Arrival> arrivals;
  for (int k = 0; k < 5; ++k) {
    for (int topic = 0; topic < 3; ++topic) {
      arrivals.push_back({topic, 100 + 33 * k, 10 * k + topic});
    }
  }
  std::mt19937 rng(3);
  for (bool approximate : {false, true}) {
    for (int trial = 0; trial < 20; ++trial) {
      // Shuffle across topics, keeping each topic's own order.
      std::vector<Arrival> shuffled;
      std::vector<std::size_t> next(3, 0);
      std::vector<std::vector<Arrival>> per_topic(3);
      for (const Arrival& a : arrivals) per_topic[a.topic].push_back(a);
      while (shuffled.size() < arrivals.size()) {
        const int t = static_cast<int>(rng() % 3);
        if (next[t] < per_topic[t].size()) {
          shuffled.push_back(per_topic[t][next[t]++]);
        }
      }
      Sync sync({true, true, true}, syncOptions(approximate, 10));
      const auto sets = run(sync, shuffled);
      ASSERT_EQ(sets.size(), 5u);
      for (int k = 0; k < 5; ++k) {
        EXPECT_EQ(sets[k].stamp_ns, (100 + 33 * k) * kMs);
        for (int topic = 0; topic < 3; ++topic) {
          EXPECT_EQ(sets[k].messages[topic], 10 * k + topic);
        }
      }
    }
  }
}

TEST(Synchronizer, ApproximateTakesTheMutuallyNearestWithinTheSpread) {
  // Pivots every 33 ms; topic 1 with a 4 ms offset; topic 2 at a third of
  // the rate, with stamps 1 ms after every third pivot.
  std::vector<Arrival> arrivals;
  for (int k = 0; k < 9; ++k) {
    arrivals.push_back({1, 4 + 33 * k, 100 + k});
    if (k % 3 == 2) arrivals.push_back({2, 1 + 33 * k, 200 + k});
    arrivals.push_back({0, 33 * k, k});
  }
  Sync sync({true, true, true}, syncOptions(true, 10));
  const auto sets = run(sync, arrivals, true);
  ASSERT_EQ(sets.size(), 3u);
  for (int s = 0; s < 3; ++s) {
    const int k = 3 * s + 2;
    EXPECT_EQ(sets[s].messages[0], k);
    EXPECT_EQ(sets[s].messages[1], 100 + k);
    EXPECT_EQ(sets[s].messages[2], 200 + k);
  }
  EXPECT_EQ(sync.unmatchedPivots(), 6u);
  // With exact sync nothing matches these stamps.
  Sync exact({true, true, true}, syncOptions(false, 10));
  EXPECT_TRUE(run(exact, arrivals, true).empty());
}

TEST(Synchronizer, ALaterMessageWaitsForTheNextPivot) {
  Sync sync({true, true}, syncOptions(true, 20));
  // Pivot at 100, topic 1 at 112: the next pivot (at 120) is nearer to it.
  EXPECT_TRUE(run(sync, {{0, 100, 1}, {1, 112, 11}}).empty());
  // The second pivot takes it once no nearer message can come.
  EXPECT_TRUE(run(sync, {{0, 120, 2}}).empty());
  const auto sets = run(sync, {{1, 145, 12}});
  ASSERT_EQ(sets.size(), 1u);
  EXPECT_EQ(sets[0].messages[0], 2);
  EXPECT_EQ(sets[0].messages[1], 11);
  EXPECT_EQ(sync.unmatchedPivots(), 1u);
}

TEST(Synchronizer, SpreadBoundRejectsDistantStamps) {
  Sync sync({true, true}, syncOptions(true, 5));
  const auto sets = run(sync, {{0, 100, 1}, {1, 110, 11}, {0, 200, 2}}, true);
  EXPECT_TRUE(sets.empty());
  EXPECT_EQ(sync.unmatchedPivots(), 2u);
}

TEST(Synchronizer, OptionalTopicsJoinWhenPresent) {
  Sync sync({true, true, false}, syncOptions(true, 10));
  const auto sets =
      run(sync,
          {{1, 100, 11}, {2, 100, 21}, {0, 100, 1}, {1, 133, 12}, {0, 133, 2}});
  ASSERT_EQ(sets.size(), 2u);
  EXPECT_TRUE(sets[0].present[2]);
  EXPECT_EQ(sets[0].messages[2], 21);
  EXPECT_FALSE(sets[1].present[2]);
}

TEST(Synchronizer, ADuplicateIsRejectedAndAnyStepBackRestarts) {
  Sync sync({true, true}, syncOptions(true, 10));
  EXPECT_EQ(sync.add(0, 5000 * kMs, 1), Sync::AddResult::kQueued);
  EXPECT_EQ(sync.add(0, 5000 * kMs, 3), Sync::AddResult::kOutOfOrder);
  EXPECT_EQ(sync.queued(0), 1);
  // A bag of less than a second played again: 0.6 s back restarts too. The
  // old timeline's messages go.
  EXPECT_EQ(sync.add(1, 5000 * kMs, 11), Sync::AddResult::kQueued);
  EXPECT_EQ(sync.add(0, 4400 * kMs, 2), Sync::AddResult::kTimeReset);
  EXPECT_EQ(sync.queued(0), 1);
  EXPECT_EQ(sync.queued(1), 0);
  EXPECT_EQ(sync.add(1, 4400 * kMs, 12), Sync::AddResult::kQueued);
  ASSERT_EQ(sync.poll().size(), 1u);
  // The new timeline's messages that other topics queued first stay: here
  // topic 1 goes back first, then the pivot follows within the spread.
  EXPECT_EQ(sync.add(0, 4433 * kMs, 6), Sync::AddResult::kQueued);
  EXPECT_EQ(sync.add(1, 10 * kMs, 14), Sync::AddResult::kTimeReset);
  EXPECT_EQ(sync.queued(0), 0);
  EXPECT_EQ(sync.add(0, 10 * kMs, 4), Sync::AddResult::kQueued);
  EXPECT_EQ(sync.queued(1), 1);
  const auto sets = sync.poll();
  ASSERT_EQ(sets.size(), 1u);
  EXPECT_EQ(sets[0].messages[0], 4);
  EXPECT_EQ(sets[0].messages[1], 14);
  // Then the new timeline runs on: the next pivot forms its set.
  EXPECT_EQ(sync.add(0, 43 * kMs, 5), Sync::AddResult::kQueued);
  EXPECT_EQ(sync.add(1, 43 * kMs, 15), Sync::AddResult::kQueued);
  ASSERT_EQ(sync.poll().size(), 1u);
}

TEST(Synchronizer, QueuesAreBounded) {
  Sync sync({true, true}, syncOptions(false, 0, 3));
  for (int k = 0; k < 10; ++k) sync.add(0, (100 + k) * kMs, k);
  EXPECT_EQ(sync.queued(0), 3);
  EXPECT_EQ(sync.unmatchedPivots(), 7u);
  sync.add(1, 109 * kMs, 19);
  const auto sets = sync.poll();
  ASSERT_EQ(sets.size(), 1u);
  EXPECT_EQ(sets[0].messages[0], 9);
}

}  // namespace
}  // namespace normal_fusion
