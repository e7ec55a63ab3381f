// The wall-clock budget of one solve (SolverSettings::time_budget_ms): when
// it ends, what is left, and whether another piece of work may start.
#pragma once

#include <algorithm>
#include <chrono>

namespace normal_fusion {
namespace internal {

/// A solve's deadline, or none (every question then answers "go on").
class Deadline {
 public:
  using Clock = std::chrono::steady_clock;
  /// Safety factor on the predicted cost of the next step near the end (the
  /// machine's speed varies from step to step).
  static constexpr double kMargin = 1.5;

  /// The solve ends by `budget_ms` after `from` (0 = no deadline).
  void start(Clock::time_point from, double budget_ms) {
    active_ = budget_ms > 0.0;
    end_ = from + std::chrono::duration_cast<Clock::duration>(
                      std::chrono::duration<double, std::milli>(budget_ms));
  }
  bool active() const { return active_; }

  /// Seconds from now to the deadline (negative once it passed).
  double secondsLeft() const {
    return std::chrono::duration<double>(end_ - Clock::now()).count();
  }

  /// A step expected to take `expected_seconds` (times kMargin) may begin at
  /// `step_start`: it ends by the deadline.
  bool allowsStep(Clock::time_point step_start, double expected_seconds) const {
    return !active_ ||
           step_start + toDuration(kMargin * expected_seconds) <= end_;
  }

  /// Work of `seconds` begun at `start` ends by the deadline (without
  /// kMargin: for work that brings its own).
  bool fits(Clock::time_point start, double seconds) const {
    return !active_ || start + toDuration(seconds) <= end_;
  }

  /// A whole level whose least cost is `level_seconds` (0: not known yet)
  /// fits in what is left, with kMargin.
  bool allowsLevel(double level_seconds) const {
    return !active_ || secondsLeft() >= kMargin * level_seconds;
  }

  /// Another chunk of `seconds` of iterations, and then the `reserve_seconds`
  /// that close the outer step, end before the deadline when begun now.
  bool allowsChunk(double seconds, double reserve_seconds) const {
    return !active_ ||
           Clock::now() + toDuration(seconds + reserve_seconds) < end_;
  }

  /// Iterations of the next chunk: `wanted`, or fewer so that they (at
  /// `seconds_per_iteration`, 0: not measured yet) and `reserve_seconds`
  /// still fit, at least 1 and at most `cap`.
  int chunkIterations(int wanted, double seconds_per_iteration,
                      double reserve_seconds, int first_chunk, int cap) const {
    int k = std::min(first_chunk, wanted);
    if (!active_ || seconds_per_iteration <= 0.0) return k;
    const double left = secondsLeft() - reserve_seconds;
    k = std::max(
        1, std::min(wanted, static_cast<int>(left / seconds_per_iteration)));
    return std::min(k, cap);
  }

 private:
  static Clock::duration toDuration(double seconds) {
    return std::chrono::duration_cast<Clock::duration>(
        std::chrono::duration<double>(seconds));
  }

  bool active_ = false;
  Clock::time_point end_;
};

}  // namespace internal
}  // namespace normal_fusion
