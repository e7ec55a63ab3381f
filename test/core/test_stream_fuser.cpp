// Tests of StreamFuser, the stream policy the node runs: when the previous
// result warm-starts a frame, when the stream restarts, the inputs' averages
// over time, the duals of the rotation warp and the frame budget's reserves.
#include "normal_fusion/stream_fuser.h"

#include <gtest/gtest.h>

#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <optional>
#include <string>
#include <vector>

#include "eval/synthetic.h"
#include "normal_fusion/errors.h"
#include "normal_fusion/metrics.h"

namespace normal_fusion {
namespace {

constexpr std::int64_t kSecond = 1000000000;

std::int64_t nanoseconds(double seconds) { return std::llround(seconds * 1e9); }

/// The frame's two inputs: paper noise and noisy depth (new noise per seed).
FusionProblem problemFor(const synthetic::Frame& frame, int seed) {
  FusionProblem problem;
  problem.image = frame.image;
  problem.K = frame.K;
  NormalInput noisy, depth;
  noisy.normals = synthetic::addPaperNoise(frame.normals_gt, 0.4, 100 + seed);
  depth.normals =
      synthetic::normalsFromNoisyDepth(frame, 0.01, 0.02, 200 + seed);
  problem.inputs = {noisy, depth};
  return problem;
}

StreamSettings streamSettings() {
  StreamSettings settings;
  settings.solver.num_threads = 2;
  settings.solver.max_total_inner_iterations = 300;  // short: a fast test
  return settings;
}

/// Fuses `frame` at `seconds` with the camera taken as still.
StreamResult fuseAt(StreamFuser& fuser, const synthetic::Frame& frame,
                    double seconds, int seed = 1,
                    const FrameRotation& rotation = FrameRotation::still()) {
  FusionProblem problem = problemFor(frame, seed);
  StreamResult result;
  fuser.fuse(nanoseconds(seconds), problem, rotation,
             std::chrono::steady_clock::now(), &result);
  fuser.endFrame(0.0);
  return result;
}

bool sameBits(const NormalMap& a, const NormalMap& b) {
  return a.width() == b.width() && a.height() == b.height() &&
         std::memcmp(a.plane(0), b.plane(0),
                     3 * a.pixelCount() * sizeof(float)) == 0;
}

TEST(StreamFuser, AGoodFrameWarmStartsTheNext) {
  const synthetic::Frame frame = synthetic::renderScene(0, 64, 48);
  StreamFuser fuser(streamSettings());
  StreamResult result = fuseAt(fuser, frame, 1.0);
  EXPECT_FALSE(fuser.lastReport().warm_started);
  EXPECT_TRUE(result.stream_started);
  EXPECT_EQ(result.restart_reason, "no previous frame");
  EXPECT_NE(result.note.find("cold start"), std::string::npos) << result.note;
  EXPECT_EQ(fuser.previousStampNs(), kSecond);
  result = fuseAt(fuser, frame, 1.033, 2);
  EXPECT_TRUE(fuser.lastReport().warm_started);
  EXPECT_FALSE(result.stream_started);
  EXPECT_TRUE(result.note.empty()) << result.note;
  EXPECT_TRUE(result.warning.empty()) << result.warning;
  EXPECT_EQ(fuser.framesFused(), 2u);
  // Warm starts off: every frame a one-shot cold start, no stream restart.
  StreamSettings cold_settings = streamSettings();
  cold_settings.warm_start = false;
  StreamFuser cold(cold_settings);
  for (double seconds : {1.0, 1.033}) {
    result = fuseAt(cold, frame, seconds);
    EXPECT_FALSE(cold.lastReport().warm_started);
    EXPECT_FALSE(result.stream_started);
  }
}

TEST(StreamFuser, AGapTimeGoingBackAnotherKOrSizeRestartTheStream) {
  StreamSettings settings = streamSettings();
  settings.warm_start_max_gap = 0.2;
  const synthetic::Frame frame = synthetic::renderScene(0, 64, 48);
  StreamFuser fuser(settings);
  fuseAt(fuser, frame, 1.0);
  fuseAt(fuser, frame, 1.1);
  EXPECT_TRUE(fuser.lastReport().warm_started);
  StreamResult result = fuseAt(fuser, frame, 3.0);
  EXPECT_FALSE(fuser.lastReport().warm_started) << "gap above the maximum";
  EXPECT_TRUE(result.stream_started);
  EXPECT_NE(result.restart_reason.find("exceeds warm_start_max_gap"),
            std::string::npos)
      << result.restart_reason;
  // Time going backwards resets the stream, with a warning.
  std::string reason;
  EXPECT_FALSE(
      fuser.continuesStream(nanoseconds(0.5), frame.K, 64, 48, 2, &reason));
  result = fuseAt(fuser, frame, 0.5);
  EXPECT_FALSE(fuser.lastReport().warm_started);
  EXPECT_TRUE(result.stream_started);
  EXPECT_NE(result.warning.find("time went backwards"), std::string::npos);
  // Another K.
  synthetic::Frame zoomed = frame;
  zoomed.K.K[0] *= 1.1;
  EXPECT_FALSE(
      fuser.continuesStream(nanoseconds(0.6), zoomed.K, 64, 48, 2, &reason));
  EXPECT_EQ(reason, "K changed");
  result = fuseAt(fuser, zoomed, 0.6);
  EXPECT_FALSE(fuser.lastReport().warm_started);
  EXPECT_EQ(result.restart_reason, "K changed");
  // Another size.
  const synthetic::Frame smaller = synthetic::renderScene(0, 32, 24);
  result = fuseAt(fuser, smaller, 0.7);
  EXPECT_FALSE(fuser.lastReport().warm_started);
  EXPECT_EQ(result.restart_reason, "the image size changed");
  // And the same size again continues.
  EXPECT_TRUE(
      fuser.continuesStream(nanoseconds(0.8), smaller.K, 32, 24, 2, &reason));
  fuseAt(fuser, smaller, 0.8);
  EXPECT_TRUE(fuser.lastReport().warm_started);
  // An explicit reset.
  fuser.reset();
  result = fuseAt(fuser, smaller, 0.9);
  EXPECT_FALSE(fuser.lastReport().warm_started);
  EXPECT_EQ(result.restart_reason, "no previous frame");
}

/// The stamp gap that the previous frame's own processing opened does not
/// end the stream: with warm_start_max_gap 0, a frame 0.5 ms after one that
/// took longer than that (2000 iterations) still warm-starts.
TEST(StreamFuser, TheGapOfTheProcessingItselfDoesNotEndTheStream) {
  StreamSettings settings = streamSettings();
  settings.warm_start_max_gap = 0.0;
  settings.solver.max_total_inner_iterations = 2000;
  settings.solver.inner_iterations = 50;
  settings.solver.max_outer_iterations = 100;
  settings.solver.relative_tolerance = 0.0;
  const synthetic::Frame frame = synthetic::renderScene(0, 64, 48);
  StreamFuser fuser(settings);
  fuseAt(fuser, frame, 1.0);
  ASSERT_EQ(fuser.lastReport().inner_iterations, 2000);
  fuseAt(fuser, frame, 1.0005);
  EXPECT_TRUE(fuser.lastReport().warm_started);
  const StreamResult result = fuseAt(fuser, frame, 101.0);
  EXPECT_FALSE(fuser.lastReport().warm_started);
  EXPECT_NE(result.restart_reason.find("exceeds warm_start_max_gap"),
            std::string::npos);
}

/// A still camera's noisy frames averaged give a better map than the same
/// stream without; the averages restart with the stream, after being turned
/// off, and on an unknown rotation (which also cold-starts the frame).
TEST(StreamFuser, TemporalAveragingFollowsTheStream) {
  const synthetic::Frame frame = synthetic::renderScene(0, 96, 72);
  // The data weight at which the 1 dB margin was set: a larger lambda
  // improves the single frames (0.3 dB at 0.55) and not the averaged ones,
  // which narrows the margin without saying anything about the averaging.
  StreamSettings plain_settings = streamSettings();
  plain_settings.solver.lambda = 0.5;
  StreamSettings averaged_settings = plain_settings;
  averaged_settings.temporal.frames = 8;
  StreamFuser plain(plain_settings), averaged(averaged_settings);
  for (int k = 0; k < 8; ++k) {
    const double seconds = 1.0 + 0.033 * k;
    EXPECT_FALSE(fuseAt(plain, frame, seconds, 40 + k).inputs_averaged);
    const StreamResult result = fuseAt(averaged, frame, seconds, 40 + k);
    EXPECT_EQ(result.inputs_averaged, k > 0) << "frame " << k;
    EXPECT_GT(result.average_seconds, 0.0);
  }
  const double p_plain = psnr(plain.fusedNormals(), frame.normals_gt);
  const double p_averaged = psnr(averaged.fusedNormals(), frame.normals_gt);
  EXPECT_GT(p_averaged, p_plain + 1.0)
      << "plain " << p_plain << " dB, averaged " << p_averaged << " dB";
  // Off for a frame and on again: the old averages are not used.
  StreamSettings off = averaged_settings;
  off.temporal.frames = 0;
  averaged.setSettings(off);
  EXPECT_FALSE(fuseAt(averaged, frame, 1.3, 58).inputs_averaged);
  averaged.setSettings(averaged_settings);
  EXPECT_FALSE(fuseAt(averaged, frame, 1.333, 59).inputs_averaged);
  EXPECT_TRUE(averaged.lastReport().warm_started);
  EXPECT_TRUE(fuseAt(averaged, frame, 1.366, 60).inputs_averaged);
  // A known rotation carries them; an unknown one restarts them.
  const std::array<double, 9> identity{1, 0, 0, 0, 1, 0, 0, 0, 1};
  StreamResult result =
      fuseAt(averaged, frame, 1.4, 61, FrameRotation::known(identity));
  EXPECT_TRUE(result.inputs_averaged);
  EXPECT_TRUE(result.rotated);
  EXPECT_TRUE(averaged.lastReport().warm_started);
  result = fuseAt(averaged, frame, 1.433, 62,
                  FrameRotation::unknown("no transform"));
  EXPECT_TRUE(result.rotation_failed);
  EXPECT_EQ(result.rotation_unknown, "no transform");
  EXPECT_EQ(result.rotation_consequence,
            "cold start, input averages restarted");
  EXPECT_FALSE(result.inputs_averaged);
  EXPECT_FALSE(averaged.lastReport().warm_started);
  EXPECT_FALSE(result.stream_started) << "a one-frame failure";
  // A matrix that is not a rotation is refused likewise.
  result = fuseAt(averaged, frame, 1.466, 63,
                  FrameRotation::known({2, 0, 0, 0, 1, 0, 0, 0, 1}));
  EXPECT_TRUE(result.rotation_failed);
  EXPECT_NE(result.rotation_unknown.find("not a rotation"), std::string::npos);
  EXPECT_FALSE(averaged.lastReport().warm_started);
  // A gap ends the stream: the averages restart with the warm start.
  result = fuseAt(averaged, frame, 9.0, 64);
  EXPECT_FALSE(result.inputs_averaged);
  EXPECT_TRUE(result.stream_started);
}

/// The rotation warp resets the duals while the local refinement is on and
/// rotates them without it, unless the settings say otherwise.
TEST(StreamFuser, TheDualsAreResetWithTheLocalRefinement) {
  const auto frames = synthetic::renderSequence(0, 64, 48, 3, 1.0);
  const auto fused = [&](int refine, std::optional<DualWarp> dual_warp) {
    StreamSettings settings = streamSettings();
    settings.solver.time_budget_ms = 0.0;  // by the iterations: bits repeat
    settings.solver.max_total_inner_iterations = 100;
    settings.solver.warm_refine_iterations = refine;
    settings.dual_warp = dual_warp;
    StreamFuser fuser(settings);
    for (int k = 0; k < 3; ++k) {
      const FrameRotation rotation =
          k == 0 ? FrameRotation::still()
                 : FrameRotation::known(synthetic::relativeRotation(
                       frames[k].pose, frames[k - 1].pose));
      const StreamResult result =
          fuseAt(fuser, frames[k], frames[k].stamp, k, rotation);
      EXPECT_EQ(result.rotated, k > 0);
    }
    return fuser.fusedNormals();
  };
  const int refine = StreamSettings().solver.warm_refine_iterations;
  ASSERT_GT(refine, 0);
  const NormalMap by_default = fused(refine, std::nullopt);
  EXPECT_TRUE(sameBits(by_default, fused(refine, DualWarp::kReset)));
  EXPECT_FALSE(sameBits(by_default, fused(refine, DualWarp::kRotate)));
  const NormalMap unrefined = fused(0, std::nullopt);
  EXPECT_TRUE(sameBits(unrefined, fused(0, DualWarp::kRotate)));
  EXPECT_FALSE(sameBits(unrefined, fused(0, DualWarp::kReset)));
}

/// reserve() sizes the buffers of the stream's first frames: they then
/// allocate nothing, and fuse bit for bit what an unreserved stream fuses.
TEST(StreamFuser, AReservedStreamAllocatesNothingAndFusesTheSame) {
  const int W = 160, H = 120;
  const auto frames = synthetic::renderSequence(0, W, H, 4, 1.0);
  StreamSettings settings = streamSettings();
  settings.solver.time_budget_ms = 0.0;  // by the iterations: bits repeat
  settings.temporal.frames = 4;          // the averages' buffers too
  StreamFuser reserved(settings), plain(settings);
  EXPECT_GT(reserved.reserve(W, H, 2, true), 0.0);
  const std::size_t bytes_reserved = reserved.bytesHeld();
  EXPECT_GT(bytes_reserved, 0u);
  EXPECT_EQ(plain.bytesHeld(), 0u);
  for (int k = 0; k < 4; ++k) {
    const FrameRotation rotation =
        k == 0 ? FrameRotation::still()
               : FrameRotation::knownMotion(synthetic::relativePose(
                     frames[k].pose, frames[k - 1].pose));
    StreamResult result_reserved, result_plain;
    for (auto* run : {&reserved, &plain}) {
      FusionProblem problem = problemFor(frames[k], k);
      run->fuse(nanoseconds(frames[k].stamp), problem, rotation,
                std::chrono::steady_clock::now(),
                run == &reserved ? &result_reserved : &result_plain,
                &frames[k].depth);
      run->endFrame(0.0);
    }
    // The reserved stream starts with its first real frame, as the other.
    EXPECT_EQ(result_reserved.stream_started, k == 0);
    EXPECT_EQ(result_reserved.motion_warped, k > 0);
    EXPECT_EQ(result_reserved.inputs_averaged, k > 0);
    EXPECT_EQ(reserved.lastReport().warm_started, k > 0);
    EXPECT_TRUE(sameBits(reserved.fusedNormals(), plain.fusedNormals()))
        << "frame " << k;
    EXPECT_EQ(reserved.bytesHeld(), bytes_reserved) << "frame " << k;
  }
  EXPECT_LE(plain.bytesHeld(), bytes_reserved);
  EXPECT_THROW(reserved.reserve(1, H, 2), InputError);
  EXPECT_THROW(reserved.reserve(W, H, 0), InputError);
  Solver solver;
  EXPECT_THROW(solver.reserveRefinement(0, H, 2, 10), InputError);
  EXPECT_THROW(solver.reserveRefinement(W, H, 0, 10), InputError);
  solver.reserveRefinement(W, H, 2, -5);  // none: sizes for no pixel
  EXPECT_GT(solver.bytesHeld(), 0u);
}

TEST(StreamFuser, AFailedSolveResetsTheStream) {
  const synthetic::Frame frame = synthetic::renderScene(0, 64, 48);
  StreamFuser fuser(streamSettings());
  fuseAt(fuser, frame, 1.0);
  fuseAt(fuser, frame, 1.033);
  ASSERT_TRUE(fuser.lastReport().warm_started);
  FusionProblem empty = problemFor(frame, 3);
  for (NormalInput& input : empty.inputs) input.normals.fill(NAN);
  StreamResult result;
  EXPECT_THROW(fuser.fuse(nanoseconds(1.066), empty, FrameRotation::still(),
                          std::chrono::steady_clock::now(), &result),
               InputError);
  result = fuseAt(fuser, frame, 1.1);
  EXPECT_FALSE(fuser.lastReport().warm_started);
  EXPECT_EQ(result.restart_reason, "no previous frame");
  EXPECT_EQ(fuser.framesFused(), 3u);
}

/// What the frame budget sets aside for overruns: a reserve that grows after
/// warm frames over the budget (not the stream's cold start) and shrinks
/// after frames within it.
TEST(StreamFuser, TheBudgetReserveTracksOverruns) {
  StreamSettings settings = streamSettings();
  settings.solver.time_budget_ms = 1e-3;  // every frame overruns it
  settings.solver.pyramid_levels = 1;
  const synthetic::Frame frame = synthetic::renderScene(0, 64, 48);
  StreamFuser fuser(settings);
  std::vector<double> reserves;
  double seconds = 1.0;
  for (int k = 0; k < 4; ++k) {
    reserves.push_back(
        fuseAt(fuser, frame, seconds += 0.03).budget_reserve_seconds);
  }
  EXPECT_EQ(reserves[0], 0.0);
  EXPECT_EQ(reserves[1], 0.0);
  EXPECT_EQ(reserves[2], 0.5e-6);
  EXPECT_EQ(reserves[3], 0.5e-6);
  settings.solver.time_budget_ms = 1000.0;
  fuser.setSettings(settings);
  std::vector<double> after;
  for (int k = 0; k < 3; ++k) {
    fuseAt(fuser, frame, seconds += 0.03);
    after.push_back(fuser.overrunReserveSeconds());
  }
  EXPECT_EQ(after[0], 0.0);
  EXPECT_EQ(after[2], 0.0);
}

/// Under a translation the warm start follows the full motion through the
/// previous frame's depth: with a single inner iteration and no local
/// refinement the fused map is about the warm start itself, much nearer the
/// truth than the rotation warp's.
TEST(StreamFuser, WithDepthTheWarmStartFollowsTheTranslation) {
  // 10 cm forward and 5 cm to the right.
  const auto frames =
      synthetic::renderTranslation(0, 96, 72, 2, {{0.05, 0.0, 0.1}});
  const Pose T_cur_prev =
      synthetic::relativePose(frames[1].pose, frames[0].pose);
  const auto warm_start_psnr = [&](const FrameRotation& rotation,
                                   bool with_depth, StreamResult* result) {
    StreamSettings settings = streamSettings();
    settings.solver.time_budget_ms = 0.0;
    StreamFuser fuser(settings);
    FusionProblem first = problemFor(frames[0], 1);
    fuser.fuse(0, first, FrameRotation::still(),
               std::chrono::steady_clock::now(), result,
               with_depth ? &frames[0].depth : nullptr);
    EXPECT_EQ(fuser.hasPreviousDepth(), with_depth);
    settings.solver.max_total_inner_iterations = 1;
    settings.solver.warm_refine_iterations = 0;
    fuser.setSettings(settings);
    FusionProblem second = problemFor(frames[1], 2);
    fuser.fuse(nanoseconds(frames[1].stamp), second, rotation,
               std::chrono::steady_clock::now(), result, &frames[1].depth);
    EXPECT_TRUE(fuser.lastReport().warm_started);
    return psnr(fuser.fusedNormals(), frames[1].normals_gt);
  };
  StreamResult by_motion, by_rotation, no_depth;
  const double motion_db =
      warm_start_psnr(FrameRotation::knownMotion(T_cur_prev), true, &by_motion);
  const double rotation_db =
      warm_start_psnr(FrameRotation::known(T_cur_prev.R), true, &by_rotation);
  const double no_depth_db =
      warm_start_psnr(FrameRotation::knownMotion(T_cur_prev), false, &no_depth);
  EXPECT_TRUE(by_motion.rotated && by_motion.motion_warped);
  EXPECT_TRUE(by_rotation.rotated && !by_rotation.motion_warped);
  // Without the previous depth: the rotation alone, bit for bit.
  EXPECT_TRUE(no_depth.rotated && !no_depth.motion_warped);
  EXPECT_EQ(no_depth_db, rotation_db);
  EXPECT_GT(motion_db, rotation_db + 4.0)
      << motion_db << " dB against " << rotation_db << " dB";
}

/// A depth of another size than the image is not kept: the next frame's warm
/// start follows the rotation alone.
TEST(StreamFuser, ADepthOfAnotherSizeIsNotKept) {
  const synthetic::Frame frame = synthetic::renderScene(0, 64, 48);
  StreamFuser fuser(streamSettings());
  FusionProblem problem = problemFor(frame, 1);
  StreamResult result;
  const ScalarMap small(32, 24, 1, 1.0f);
  fuser.fuse(0, problem, FrameRotation::still(),
             std::chrono::steady_clock::now(), &result, &small);
  EXPECT_FALSE(fuser.hasPreviousDepth());
  fuser.fuse(nanoseconds(0.033), problem, FrameRotation::still(),
             std::chrono::steady_clock::now(), &result, &frame.depth);
  EXPECT_TRUE(fuser.hasPreviousDepth());
  fuser.reset();
  EXPECT_FALSE(fuser.hasPreviousDepth());
}

}  // namespace
}  // namespace normal_fusion
