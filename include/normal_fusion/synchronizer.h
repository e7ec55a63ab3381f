// Synchronization of any number of stamped input streams into sets, by stamp
// alone (the order in which topics interleave does not matter), with one
// bounded queue per topic. No ROS dependency: stamps are integer nanoseconds.
//
// Topic 0 is the pivot (the image): every set is formed around one pivot
// message and carries its stamp. The other topics are required (a set needs
// them) or optional (they join a set when they have a message within the
// spread at the moment the required ones are complete; no waiting for them).
//
// Exact mode: a set takes, from each topic, the message whose stamp equals the
// pivot's.
//
// Approximate mode: from each topic, the message nearest in stamp to the pivot
// among those whose own nearest pivot is this one (mutual nearest neighbours,
// so a slower topic pairs with the pivot closest to it and never with an
// earlier one that merely came first); the set is accepted when the spread of
// its stamps (max - min) is at most max_interval. A decision waits until it is
// certain: until the topic has a message at or after the pivot's stamp (unless
// one matches exactly) and, for a message after the pivot, until the next pivot
// shows whether it is nearer. flush() decides what is left at the end of a
// stream as if nothing more were coming.
//
// Each message joins at most one set. Pivots that cannot get a set are
// discarded (counted); each queue keeps at most queue_size messages, dropping
// the oldest (counted). A stamp equal to the newest of its topic is rejected
// as a duplicate; an older one means that time went back (a bag loop or a
// restarted player): every queue drops what is later than it (restartAt).
#pragma once

#include <algorithm>
#include <cstdint>
#include <cstdlib>
#include <deque>
#include <string>
#include <vector>

namespace normal_fusion {

template <typename Message>
class StampSynchronizer {
 public:
  struct Options {
    bool approximate = true;
    int queue_size = 5;                ///< messages kept per topic, >= 1
    std::int64_t max_interval_ns = 0;  ///< largest stamp spread of a set
  };

  /// One synchronized set: the pivot's stamp, one message per topic (a
  /// default-constructed one where an optional topic is absent).
  struct Set {
    std::int64_t stamp_ns = 0;
    std::vector<Message> messages;
    std::vector<bool> present;
  };

  /// A pivot discarded when its set was decided: the first required topic
  /// without a matching message, and that topic's nearest stamp (or kNone).
  struct Discard {
    std::int64_t stamp_ns = 0;
    int missing_topic = -1;
    std::int64_t nearest_ns = 0;
  };

  enum class AddResult {
    kQueued,      ///< queued (sets may be ready: call poll())
    kOutOfOrder,  ///< stamp equal to the topic's newest: dropped
    kTimeReset,   ///< stamp older than the topic's newest: queues reset, queued
  };

  StampSynchronizer(std::vector<bool> required, const Options& options)
      : required_(std::move(required)),
        options_(options),
        queues_(required_.size()),
        newest_(required_.size(), kNone),
        dropped_(required_.size(), 0) {
    required_[0] = true;
    options_.queue_size = std::max(1, options_.queue_size);
  }

  int numTopics() const { return static_cast<int>(queues_.size()); }
  const Options& options() const { return options_; }
  /// Only max_interval may change while running; the rest takes effect too
  /// but does not reorder what is queued.
  void setOptions(const Options& options) {
    options_ = options;
    options_.queue_size = std::max(1, options_.queue_size);
  }

  AddResult add(int topic, std::int64_t stamp_ns, const Message& message) {
    AddResult result = AddResult::kQueued;
    if (newest_[topic] != kNone && stamp_ns <= newest_[topic]) {
      if (stamp_ns == newest_[topic]) return AddResult::kOutOfOrder;
      restartAt(stamp_ns);
      auto& own = queues_[topic];
      while (!own.empty() && own.back().stamp >= stamp_ns) own.pop_back();
      result = AddResult::kTimeReset;
    }
    newest_[topic] = stamp_ns;
    auto& queue = queues_[topic];
    queue.push_back(Entry{stamp_ns, message});
    while (static_cast<int>(queue.size()) > options_.queue_size) {
      queue.pop_front();
      ++dropped_[topic];
      if (topic == 0) ++unmatched_pivots_;
    }
    return result;
  }

  /// The sets that became certain since the last call, oldest first.
  std::vector<Set> poll() { return decide(false); }
  /// At the end of a stream: decides every queued pivot.
  std::vector<Set> flush() { return decide(true); }

  void reset() {
    for (auto& queue : queues_) queue.clear();
    std::fill(newest_.begin(), newest_.end(), kNone);
  }

  /// Time went back to `stamp_ns`: the messages of the old timeline (later
  /// than it by more than max_interval) go; those of the new one that other
  /// topics queued already stay.
  void restartAt(std::int64_t stamp_ns) {
    const std::int64_t keep_until = stamp_ns + options_.max_interval_ns;
    for (std::size_t t = 0; t < queues_.size(); ++t) {
      auto& queue = queues_[t];
      while (!queue.empty() && queue.back().stamp > keep_until) {
        queue.pop_back();
      }
      // Each queue is sorted by stamp, so what is left ends at its newest.
      newest_[t] = queue.empty() ? kNone : queue.back().stamp;
    }
  }

  /// The pivots discarded since the last call (decided failures only, not
  /// queue overflows).
  std::vector<Discard> takeDiscards() {
    std::vector<Discard> out;
    out.swap(discards_);
    return out;
  }

  /// Pivots discarded without a set, and messages dropped per topic because
  /// its queue was full.
  std::uint64_t unmatchedPivots() const { return unmatched_pivots_; }
  const std::vector<std::uint64_t>& droppedPerTopic() const { return dropped_; }
  /// Messages waiting per topic, and the newest stamp queued (or kNone).
  int queued(int topic) const {
    return static_cast<int>(queues_[topic].size());
  }
  std::int64_t newestStamp(int topic) const { return newest_[topic]; }
  static constexpr std::int64_t kNone = INT64_MIN;

 private:
  struct Entry {
    std::int64_t stamp;
    Message message;
  };
  enum class Pick { kFound, kAbsent, kWait };

  /// Which message of `topic` goes with the pivot at stamp t (next_pivot: the
  /// following pivot's stamp or kNone).
  Pick pick(int topic, std::int64_t t, std::int64_t next_pivot, bool at_end,
            int* index) const {
    const auto& queue = queues_[topic];
    const bool required = required_[topic];
    // lo: the last message at or before t; hi: the first one after t.
    int lo = -1, hi = -1;
    for (int i = 0; i < static_cast<int>(queue.size()); ++i) {
      if (queue[i].stamp <= t) {
        lo = i;
      } else {
        hi = i;
        break;
      }
    }
    if (lo >= 0 && queue[lo].stamp == t) {
      *index = lo;
      return Pick::kFound;
    }
    if (!options_.approximate) {
      // Exact: the equal stamp can still come only while nothing later is here.
      if (hi < 0 && required && !at_end) return Pick::kWait;
      return Pick::kAbsent;
    }
    const std::int64_t d_lo = lo >= 0 ? t - queue[lo].stamp : INT64_MAX;
    std::int64_t d_hi = hi >= 0 ? queue[hi].stamp - t : INT64_MAX;
    if (hi < 0 && required && !at_end && d_lo > 0) {
      // A message nearer than lo may still come.
      return Pick::kWait;
    }
    if (hi >= 0 && d_hi < d_lo && d_hi <= options_.max_interval_ns) {
      // hi is nearer; it is ours only if the next pivot is not nearer to it.
      if (next_pivot == kNone) {
        if (required && !at_end) return Pick::kWait;
        if (!at_end) d_hi = INT64_MAX;  // optional: do not wait, skip hi
      } else if (next_pivot - queue[hi].stamp < d_hi) {
        d_hi = INT64_MAX;  // hi belongs to the next pivot
      }
    }
    if (d_hi < d_lo) {
      *index = hi;
      return Pick::kFound;
    }
    if (lo >= 0) {
      *index = lo;
      return Pick::kFound;
    }
    return Pick::kAbsent;
  }

  /// A set being formed: the message chosen per topic (-1: none) and the
  /// range of their stamps.
  struct Choice {
    std::vector<int> chosen;
    std::int64_t lo_stamp, hi_stamp;
  };

  void choose(int topic, int index, Choice& choice) const {
    const std::int64_t s = queues_[topic][index].stamp;
    choice.chosen[topic] = index;
    choice.lo_stamp = std::min(choice.lo_stamp, s);
    choice.hi_stamp = std::max(choice.hi_stamp, s);
  }

  /// The required topics' messages for the pivot at t (they define the set):
  /// kFound, kWait, or kAbsent with the topic to blame in *failed_topic (the
  /// first one without a message, or the one farthest from the pivot when
  /// the spread is too large).
  Pick chooseRequired(std::int64_t t, std::int64_t next_pivot, bool at_end,
                      Choice& choice, int* failed_topic) const {
    const int T = numTopics();
    for (int j = 1; j < T; ++j) {
      if (!required_[j]) continue;
      int index = -1;
      const Pick p = pick(j, t, next_pivot, at_end, &index);
      if (p == Pick::kWait) return Pick::kWait;
      if (p == Pick::kAbsent) {
        *failed_topic = j;
        return Pick::kAbsent;
      }
      choose(j, index, choice);
    }
    if (choice.hi_stamp - choice.lo_stamp <= options_.max_interval_ns) {
      return Pick::kFound;
    }
    std::int64_t worst = -1;
    for (int j = 1; j < T; ++j) {
      if (choice.chosen[j] < 0) continue;
      const std::int64_t d = std::llabs(queues_[j][choice.chosen[j]].stamp - t);
      if (d > worst) {
        worst = d;
        *failed_topic = j;
      }
    }
    return Pick::kAbsent;
  }

  /// Optional topics join when they keep the spread within bounds.
  void chooseOptional(std::int64_t t, std::int64_t next_pivot, bool at_end,
                      Choice& choice) const {
    for (int j = 1; j < numTopics(); ++j) {
      if (required_[j]) continue;
      int index = -1;
      if (pick(j, t, next_pivot, at_end, &index) != Pick::kFound) continue;
      const std::int64_t s = queues_[j][index].stamp;
      if (std::max(choice.hi_stamp, s) - std::min(choice.lo_stamp, s) >
          options_.max_interval_ns) {
        continue;
      }
      choose(j, index, choice);
    }
  }

  /// No set for the pivot at t: discard it and what can no longer match.
  void discardPivot(std::int64_t t, int failed_topic) {
    Discard discard;
    discard.stamp_ns = t;
    discard.missing_topic = failed_topic;
    discard.nearest_ns = nearestStamp(failed_topic, t);
    discards_.push_back(discard);
    ++unmatched_pivots_;
    queues_[0].pop_front();
    pruneOlderThan(t);
  }

  /// The chosen messages as a set; each message joins one set, so it and
  /// everything older leave their queues.
  Set takeSet(std::int64_t t, const Choice& choice) {
    const int T = numTopics();
    Set set;
    set.stamp_ns = t;
    set.messages.resize(T);
    set.present.assign(T, false);
    for (int j = 0; j < T; ++j) {
      const int chosen = choice.chosen[j];
      if (chosen < 0) continue;
      set.messages[j] = queues_[j][chosen].message;
      set.present[j] = true;
      queues_[j].erase(queues_[j].begin(), queues_[j].begin() + chosen + 1);
    }
    pruneOlderThan(t);
    return set;
  }

  std::vector<Set> decide(bool at_end) {
    std::vector<Set> sets;
    auto& pivots = queues_[0];
    while (!pivots.empty()) {
      const std::int64_t t = pivots.front().stamp;
      const std::int64_t next_pivot =
          pivots.size() > 1 ? pivots[1].stamp : kNone;
      Choice choice{std::vector<int>(numTopics(), -1), t, t};
      choice.chosen[0] = 0;
      int failed_topic = -1;
      const Pick required =
          chooseRequired(t, next_pivot, at_end, choice, &failed_topic);
      if (required == Pick::kWait) break;
      if (required == Pick::kAbsent) {
        discardPivot(t, failed_topic);
        continue;
      }
      chooseOptional(t, next_pivot, at_end, choice);
      sets.push_back(takeSet(t, choice));
    }
    return sets;
  }

  std::int64_t nearestStamp(int topic, std::int64_t t) const {
    std::int64_t best = kNone, best_d = INT64_MAX;
    if (topic < 0) return kNone;
    for (const Entry& e : queues_[topic]) {
      const std::int64_t d = std::llabs(e.stamp - t);
      if (d < best_d) {
        best_d = d;
        best = e.stamp;
      }
    }
    return best;
  }

  /// Drops messages that no pivot from stamp t on can take.
  void pruneOlderThan(std::int64_t t) {
    const std::int64_t limit =
        options_.approximate ? t - options_.max_interval_ns : t;
    for (int j = 1; j < numTopics(); ++j) {
      auto& queue = queues_[j];
      while (!queue.empty() && queue.front().stamp < limit) queue.pop_front();
    }
  }

  std::vector<bool> required_;
  Options options_;
  std::vector<std::deque<Entry>> queues_;
  std::vector<std::int64_t> newest_;
  std::vector<std::uint64_t> dropped_;
  std::uint64_t unmatched_pivots_ = 0;
  std::vector<Discard> discards_;
};

}  // namespace normal_fusion
