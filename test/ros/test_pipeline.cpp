// Tests of the per-set pipeline (the nodelet's and fuse_bag's shared core)
// without a master: accuracy, upsampling, warm start and budgets, rotation
// lookup in tf2, temporal averaging, absent and bad inputs.
#include <gtest/gtest.h>

#include <tf2/buffer_core.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "eval/synthetic.h"
#include "normal_fusion/errors.h"
#include "normal_fusion/metrics.h"
#include "normal_fusion/ros/pipeline.h"
#include "ros_test_util.h"

namespace normal_fusion {
namespace node {
namespace {

using test::cameraInfoMessage;
using test::imageMessage;
using test::makeHeader;
using test::normalsMessage;

struct SceneFixture {
  explicit SceneFixture(int num_inputs = 2) {
    settings.num_inputs = num_inputs;
    settings.solver.num_threads = 2;
  }

  InputSet setFor(const test::NoisyFrame& f, double stamp,
                  bool second_input = true) const {
    const std_msgs::Header header = makeHeader(stamp);
    InputSet set;
    set.image = imageMessage(f.frame.image, header);
    set.camera_info = cameraInfoMessage(f.frame.K, f.frame.image.width(),
                                        f.frame.image.height(), header);
    set.normals.push_back(normalsMessage(f.noisy, header));
    if (settings.num_inputs > 1) {
      set.normals.push_back(second_input ? normalsMessage(f.from_depth, header)
                                         : nullptr);
    }
    set.confidence.resize(set.normals.size());
    return set;
  }

  NodeSettings settings;
};

TEST(Pipeline, FusedMapBeatsEveryInputInPsnr) {
  SceneFixture fixture;
  const test::NoisyFrame f =
      test::noisyFrame(synthetic::renderScene(0, 96, 72), 7);
  FusionPipeline pipeline(fixture.settings, TopicNames::defaults(2));
  PipelineOutput out;
  pipeline.process(fixture.setFor(f, 5.0), nullptr, true, &out);
  ASSERT_TRUE(out.fused && out.fused_vis && out.stats);
  EXPECT_EQ(out.fused->header.stamp, ros::Time(5.0));
  EXPECT_EQ(out.stats->header.stamp, ros::Time(5.0));
  EXPECT_EQ(out.fused->encoding, "32FC3");
  EXPECT_EQ(out.fused_vis->encoding, "rgb8");
  const NormalMap fused = test::normalsFromImage(*out.fused);
  const double p_fused = psnr(fused, f.frame.normals_gt);
  const double p_noisy = psnr(f.noisy, f.frame.normals_gt);
  const double p_depth = psnr(f.from_depth, f.frame.normals_gt);
  EXPECT_GT(p_fused, p_noisy + 3.0);
  EXPECT_GT(p_fused, p_depth);
  EXPECT_FALSE(out.stats->warm_started);
  EXPECT_EQ(out.stats->inputs_present, (std::vector<std::uint8_t>{1, 1}));
  EXPECT_GT(out.stats->inner_iterations, 0u);
  EXPECT_LE(out.stats->final_energy, out.stats->initial_energy);
}

TEST(Pipeline, LowerResolutionInputIsUpsampled) {
  SceneFixture fixture;
  const synthetic::Frame frame = synthetic::renderScene(1, 96, 72);
  const synthetic::Frame half = synthetic::renderScene(1, 48, 36);
  test::NoisyFrame f = test::noisyFrame(frame, 3);
  FusionPipeline pipeline(fixture.settings, TopicNames::defaults(2));
  InputSet set = fixture.setFor(f, 1.0);
  set.normals[1] = normalsMessage(half.normals_gt, makeHeader(1.0));
  PipelineOutput out;
  pipeline.process(set, nullptr, false, &out);
  EXPECT_EQ(out.fused->width, 96u);
  EXPECT_FALSE(out.fused_vis);
  // Another aspect ratio is an error naming the topic.
  const synthetic::Frame wide = synthetic::renderScene(1, 48, 20);
  set = fixture.setFor(f, 1.1);
  set.normals[1] = normalsMessage(wide.normals_gt, makeHeader(1.1));
  try {
    pipeline.process(set, nullptr, false, &out);
    FAIL() << "expected an InputError";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("normals_1"), std::string::npos);
  }
}

// The node runs anytime (a per-frame budget). With a budget of 100 inner
// iterations, the warm-started chain reaches, on each frame, an energy that a
// cold start of that frame needs many more iterations to reach.
TEST(Pipeline, WarmStartCutsTheIterationsOnASlowSequence) {
  const auto frames = synthetic::renderSequence(2, 96, 72, 6, 0.3, 30.0);
  constexpr int kBudget = 100;
  SceneFixture warm_fixture, cold_fixture;
  warm_fixture.settings.solver.max_total_inner_iterations = kBudget;
  warm_fixture.settings.solver.relative_tolerance = 0.0;
  cold_fixture.settings.warm_start = false;
  cold_fixture.settings.solver.relative_tolerance = 0.0;
  cold_fixture.settings.solver.max_total_inner_iterations = 10 * kBudget;
  cold_fixture.settings.solver.max_outer_iterations = 1000;
  FusionPipeline warm(warm_fixture.settings, TopicNames::defaults(2));
  FusionPipeline cold(cold_fixture.settings, TopicNames::defaults(2));
  const int per_step = warm_fixture.settings.solver.inner_iterations;
  double cold_iterations = 0.0, warm_iterations = 0.0;
  PipelineOutput out;
  for (std::size_t k = 0; k < frames.size(); ++k) {
    const test::NoisyFrame f = test::noisyFrame(frames[k], 11 + k);
    const double stamp = 10.0 + frames[k].stamp;
    warm.process(warm_fixture.setFor(f, stamp), nullptr, false, &out);
    EXPECT_EQ(out.stats->warm_started, k > 0);
    const double warm_energy = out.stats->final_energy;
    const int warm_used =
        out.stats->inner_iterations + out.stats->coarse_inner_iterations;
    EXPECT_LE(warm_used, kBudget);
    cold.process(cold_fixture.setFor(f, stamp), nullptr, false, &out);
    EXPECT_FALSE(out.stats->warm_started);
    if (k == 0) continue;
    // Inner iterations the cold start needs to reach the warm start's energy.
    const std::vector<double>& trace = cold.lastReport().energies;
    std::size_t step = 0;
    while (step < trace.size() && trace[step] > warm_energy) ++step;
    ASSERT_LT(step, trace.size()) << "cold never reached the warm energy";
    cold_iterations += static_cast<double>(step) * per_step;
    warm_iterations += warm_used;
  }
  EXPECT_GT(cold_iterations, 1.3 * warm_iterations)
      << "cold " << cold_iterations << ", warm " << warm_iterations;
}

/// What the frame budget sets aside: the encoding's time, and a reserve that
/// grows after frames over the budget and shrinks after frames within it.
TEST(Pipeline, TheBudgetReservesTheEncodingAndTracksOverruns) {
  SceneFixture fixture;
  fixture.settings.solver.time_budget_ms = 1e-3;  // every frame overruns it
  fixture.settings.solver.pyramid_levels = 1;
  const test::NoisyFrame f =
      test::noisyFrame(synthetic::renderScene(0, 64, 48), 5);
  FusionPipeline pipeline(fixture.settings, TopicNames::defaults(2));
  PipelineOutput out;
  double stamp = 1.0;
  std::vector<double> reserves;
  for (int k = 0; k < 4; ++k) {
    pipeline.process(fixture.setFor(f, stamp += 0.03), nullptr, false, &out);
    EXPECT_GT(out.stats->encode_time, 0.0);
    EXPECT_GE(out.stats->frame_time,
              out.stats->solve_time + out.stats->encode_time);
    reserves.push_back(out.stats->budget_reserve);
  }
  // Each frame reports the reserve it was given. The first frame (the
  // stream's cold start) does not count; a warm frame over the budget adds
  // 0.98 ms, up to half the budget.
  EXPECT_EQ(reserves[0], 0.0);
  EXPECT_EQ(reserves[1], 0.0);
  EXPECT_EQ(reserves[2], 0.5e-6);
  EXPECT_EQ(reserves[3], 0.5e-6);
  // A generous budget: every frame within it, the reserve shrinks by 0.02 ms
  // a frame, down to 0.
  NodeSettings generous = fixture.settings;
  generous.solver.time_budget_ms = 1000.0;
  pipeline.setSettings(generous);
  std::vector<double> after;
  for (int k = 0; k < 3; ++k) {
    pipeline.process(fixture.setFor(f, stamp += 0.03), nullptr, false, &out);
    after.push_back(out.stats->budget_reserve);
  }
  EXPECT_EQ(after[0], 0.5e-6);
  EXPECT_EQ(after[1], 0.0);
  EXPECT_EQ(after[2], 0.0);
}

/// Under a frame budget too short for anything, a stream's first frame (and
/// its restart after time went backwards) is solved under
/// cold_start_budget_ms (none: the iteration caps) and says so in a note;
/// the warm frames in between keep the frame budget. With warm starts off
/// every frame is a one-shot cold start under the frame budget.
TEST(Pipeline, StreamStartIsSolvedUnderTheColdStartBudget) {
  SceneFixture fixture;
  fixture.settings.solver.time_budget_ms = 1e-3;
  fixture.settings.solver.max_total_inner_iterations = 60;
  fixture.settings.solver.relative_tolerance = 0.0;
  fixture.settings.solver.pyramid_levels = 1;
  const test::NoisyFrame f =
      test::noisyFrame(synthetic::renderScene(0, 64, 48), 5);
  FusionPipeline pipeline(fixture.settings, TopicNames::defaults(2));
  PipelineOutput out;
  pipeline.process(fixture.setFor(f, 1.0), nullptr, false, &out);
  EXPECT_FALSE(out.stats->warm_started);
  EXPECT_FALSE(out.stats->budget_exhausted);
  EXPECT_TRUE(out.stats->cold_start_budget_used);
  EXPECT_EQ(out.stats->inner_iterations, 60);
  EXPECT_NE(out.note.find("cold start"), std::string::npos) << out.note;
  EXPECT_NE(out.note.find("cold_start_budget_ms"), std::string::npos)
      << out.note;
  pipeline.process(fixture.setFor(f, 1.1), nullptr, false, &out);
  EXPECT_TRUE(out.stats->warm_started);
  EXPECT_TRUE(out.stats->budget_exhausted);
  EXPECT_FALSE(out.stats->cold_start_budget_used);
  EXPECT_TRUE(out.note.empty()) << out.note;
  // The phases of the solve: each measured, together within it.
  EXPECT_GT(out.stats->prepare_time, 0.0);
  EXPECT_GT(out.stats->warm_start_time, 0.0);
  EXPECT_GE(out.stats->refine_time, 0.0);
  EXPECT_LE(out.stats->prepare_time + out.stats->warm_start_time +
                out.stats->refine_time,
            out.stats->solve_time);
  // Time went backwards: the stream restarts, again under its own budget.
  pipeline.process(fixture.setFor(f, 0.5), nullptr, false, &out);
  EXPECT_FALSE(out.stats->warm_started);
  EXPECT_FALSE(out.stats->budget_exhausted);
  EXPECT_EQ(out.stats->inner_iterations, 60);
  EXPECT_FALSE(out.note.empty());

  fixture.settings.warm_start = false;
  FusionPipeline cold(fixture.settings, TopicNames::defaults(2));
  for (double stamp : {1.0, 1.1}) {
    cold.process(fixture.setFor(f, stamp), nullptr, false, &out);
    EXPECT_FALSE(out.stats->warm_started);
    EXPECT_TRUE(out.stats->budget_exhausted);
    EXPECT_LT(out.stats->inner_iterations, 60);
    EXPECT_TRUE(out.note.empty()) << out.note;
  }
}

/// reserveFor(): a live stream's buffers reserved from the first
/// camera_info's size; the sets are then fused as without it. Refused
/// (nothing done) when the stream is not live or for a size no set may have.
TEST(Pipeline, ReservesALiveStreamsBuffersBeforeTheFirstSet) {
  SceneFixture fixture;
  // Live, with a budget that the iteration caps end first: the bits repeat.
  fixture.settings.solver.time_budget_ms = 1e6;
  fixture.settings.solver.max_total_inner_iterations = 60;
  const test::NoisyFrame f =
      test::noisyFrame(synthetic::renderScene(0, 64, 48), 5);
  FusionPipeline reserved(fixture.settings, TopicNames::defaults(2));
  FusionPipeline plain(fixture.settings, TopicNames::defaults(2));
  double seconds = 0.0;
  EXPECT_FALSE(reserved.reserveFor(1, 48, &seconds));
  EXPECT_FALSE(
      reserved.reserveFor(fixture.settings.max_pixels / 48 + 1, 48, &seconds));
  EXPECT_EQ(seconds, 0.0);
  ASSERT_TRUE(reserved.reserveFor(64, 48, &seconds));
  EXPECT_GT(seconds, 0.0);
  for (double stamp : {1.0, 1.033}) {
    PipelineOutput a, b;
    reserved.process(fixture.setFor(f, stamp), nullptr, false, &a);
    plain.process(fixture.setFor(f, stamp), nullptr, false, &b);
    EXPECT_EQ(a.stats->warm_started, stamp > 1.0);
    EXPECT_EQ(a.stats->inner_iterations, b.stats->inner_iterations);
    const NormalMap& x = reserved.fusedNormals();
    const NormalMap& y = plain.fusedNormals();
    ASSERT_TRUE(x.sameSize(y));
    EXPECT_TRUE(std::equal(x.data(), x.data() + 3 * x.pixelCount(), y.data()))
        << "set at " << stamp;
  }
  // max_pixels 0: no bound, any size is reserved.
  fixture.settings.max_pixels = 0;
  FusionPipeline unbounded(fixture.settings, TopicNames::defaults(2));
  EXPECT_TRUE(unbounded.reserveFor(64, 48, &seconds));
  // Not live: warm starts off, or no time budget.
  fixture.settings.warm_start = false;
  FusionPipeline one_shot(fixture.settings, TopicNames::defaults(2));
  EXPECT_FALSE(one_shot.reserveFor(64, 48, &seconds));
  fixture.settings.warm_start = true;
  fixture.settings.solver.time_budget_ms = 0.0;
  FusionPipeline offline(fixture.settings, TopicNames::defaults(2));
  EXPECT_FALSE(offline.reserveFor(64, 48, &seconds));
}

TEST(Pipeline, RotationCompensatedWarmStartUsesTheLookup) {
  SceneFixture fixture;
  fixture.settings.fixed_frame = "world";
  const auto frames = synthetic::renderSequence(0, 64, 48, 2, 1.0, 30.0);
  FusionPipeline pipeline(fixture.settings, TopicNames::defaults(2));
  PipelineOutput out;
  int calls = 0;
  // R_cur_prev from the sequence's exact poses.
  const auto& P0 = frames[0].pose.R;
  const auto& P1 = frames[1].pose.R;
  RotationLookup lookup = [&](const std::string& frame, const ros::Time& prev,
                              const ros::Time& cur, std::array<double, 9>* R,
                              std::string*) {
    ++calls;
    EXPECT_EQ(frame, "camera");
    EXPECT_LT(prev, cur);
    // R_cur_prev = R_cam1_world * R_cam0_world^T.
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) {
        double s = 0;
        for (int k = 0; k < 3; ++k) s += P1[3 * r + k] * P0[3 * c + k];
        (*R)[3 * r + c] = s;
      }
    }
    return true;
  };
  pipeline.process(fixture.setFor(test::noisyFrame(frames[0], 1), 2.0), lookup,
                   false, &out);
  EXPECT_EQ(calls, 0);
  pipeline.process(fixture.setFor(test::noisyFrame(frames[1], 2), 2.033),
                   lookup, false, &out);
  EXPECT_EQ(calls, 1);
  EXPECT_TRUE(out.stats->warm_started);
  EXPECT_TRUE(out.stats->rotation_compensated);
  // An unknown rotation: cold start, with a warning that says why.
  RotationLookup failing = [](const std::string&, const ros::Time&,
                              const ros::Time&, std::array<double, 9>*,
                              std::string* reason) {
    *reason = "no transform";
    return false;
  };
  pipeline.process(fixture.setFor(test::noisyFrame(frames[1], 3), 2.066),
                   failing, false, &out);
  EXPECT_FALSE(out.stats->warm_started);
  EXPECT_NE(out.warning.find("no transform"), std::string::npos);
}

/// Temporal averaging of the inputs (temporal_frames): a still camera's noisy
/// sets averaged give a better map than the same stream without; the
/// averages follow the stream (restart on a gap, and on an unknown rotation,
/// with a warning that says so) and run with warm starts off too.
// Over 80 lines: one stream's history, checked in the order it happens.
TEST(Pipeline, TemporalAveragingFollowsTheStream) {
  const synthetic::Frame frame = synthetic::renderScene(0, 96, 72);
  SceneFixture plain_fixture, averaged_fixture;
  averaged_fixture.settings.temporal.frames = 8;
  FusionPipeline plain(plain_fixture.settings, TopicNames::defaults(2));
  FusionPipeline averaged(averaged_fixture.settings, TopicNames::defaults(2));
  PipelineOutput plain_out, averaged_out;
  for (int k = 0; k < 8; ++k) {
    const test::NoisyFrame f = test::noisyFrame(frame, 40 + k);
    const double stamp = 1.0 + 0.033 * k;
    plain.process(plain_fixture.setFor(f, stamp), nullptr, false, &plain_out);
    averaged.process(averaged_fixture.setFor(f, stamp), nullptr, false,
                     &averaged_out);
    EXPECT_EQ(averaged_out.stats->inputs_averaged, k > 0) << "set " << k;
    EXPECT_FALSE(plain_out.stats->inputs_averaged);
    EXPECT_EQ(plain_out.stats->input_average_time, 0.0);
    EXPECT_GT(averaged_out.stats->input_average_time, 0.0);
  }
  const double p_plain =
      psnr(test::normalsFromImage(*plain_out.fused), frame.normals_gt);
  const double p_averaged =
      psnr(test::normalsFromImage(*averaged_out.fused), frame.normals_gt);
  EXPECT_GT(p_averaged, p_plain + 1.0)
      << "plain " << p_plain << " dB, averaged " << p_averaged << " dB";
  // Turned off for a set and on again: the old averages are not used.
  NodeSettings off = averaged_fixture.settings;
  off.temporal.frames = 0;
  averaged.setSettings(off);
  averaged.process(averaged_fixture.setFor(test::noisyFrame(frame, 58), 1.3),
                   nullptr, false, &averaged_out);
  EXPECT_FALSE(averaged_out.stats->inputs_averaged);
  averaged.setSettings(averaged_fixture.settings);
  averaged.process(averaged_fixture.setFor(test::noisyFrame(frame, 59), 1.333),
                   nullptr, false, &averaged_out);
  EXPECT_FALSE(averaged_out.stats->inputs_averaged) << "stale averages used";
  EXPECT_TRUE(averaged_out.stats->warm_started);
  // A gap ends the stream: the averages restart with the warm start.
  averaged.process(averaged_fixture.setFor(test::noisyFrame(frame, 60), 9.0),
                   nullptr, false, &averaged_out);
  EXPECT_FALSE(averaged_out.stats->inputs_averaged);
  EXPECT_FALSE(averaged_out.stats->warm_started);

  // Warm starts off: every set cold-started, the inputs still averaged.
  SceneFixture cold_fixture;
  cold_fixture.settings.warm_start = false;
  cold_fixture.settings.temporal.frames = 8;
  FusionPipeline cold(cold_fixture.settings, TopicNames::defaults(2));
  PipelineOutput cold_out;
  for (int k = 0; k < 3; ++k) {
    cold.process(
        cold_fixture.setFor(test::noisyFrame(frame, 70 + k), 1.0 + 0.033 * k),
        nullptr, false, &cold_out);
    EXPECT_FALSE(cold_out.stats->warm_started);
    EXPECT_EQ(cold_out.stats->inputs_averaged, k > 0) << "set " << k;
  }

  // With a fixed frame, a rotation that cannot be looked up restarts them.
  SceneFixture tf_fixture;
  tf_fixture.settings.fixed_frame = "world";
  tf_fixture.settings.temporal.frames = 8;
  FusionPipeline tf(tf_fixture.settings, TopicNames::defaults(2));
  PipelineOutput tf_out;
  RotationLookup identity = [](const std::string&, const ros::Time&,
                               const ros::Time&, std::array<double, 9>* R,
                               std::string*) {
    *R = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    return true;
  };
  RotationLookup failing = [](const std::string&, const ros::Time&,
                              const ros::Time&, std::array<double, 9>*,
                              std::string* reason) {
    *reason = "no transform";
    return false;
  };
  tf.process(tf_fixture.setFor(test::noisyFrame(frame, 80), 1.0), identity,
             false, &tf_out);
  tf.process(tf_fixture.setFor(test::noisyFrame(frame, 81), 1.033), identity,
             false, &tf_out);
  EXPECT_TRUE(tf_out.stats->inputs_averaged);
  EXPECT_TRUE(tf_out.stats->rotation_compensated);
  tf.process(tf_fixture.setFor(test::noisyFrame(frame, 82), 1.066), failing,
             false, &tf_out);
  EXPECT_FALSE(tf_out.stats->inputs_averaged);
  EXPECT_NE(tf_out.warning.find("input averages restarted"), std::string::npos)
      << tf_out.warning;
  EXPECT_NE(tf_out.warning.find("cold start"), std::string::npos)
      << tf_out.warning;
}

TEST(Pipeline, RotationLookupInATfBufferGivesTheCameraRotation) {
  const auto frames = synthetic::renderSequence(0, 32, 24, 2, 5.0, 10.0);
  tf2::BufferCore buffer;
  buffer.setTransform(test::cameraInWorld(frames[0].pose, 3.0), "test");
  buffer.setTransform(test::cameraInWorld(frames[1].pose, 3.1), "test");
  const RotationLookup lookup = rotationLookupFromBuffer(buffer, "world");
  std::array<double, 9> R{};
  std::string reason;
  ASSERT_TRUE(lookup("camera", ros::Time(3.0), ros::Time(3.1), &R, &reason))
      << reason;
  // Expected R_cur_prev = R_cam1_world R_cam0_world^T.
  const auto& P0 = frames[0].pose.R;
  const auto& P1 = frames[1].pose.R;
  double largest_entry_of_difference = 0.0, rotation_angle = 0.0;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) {
      double expected = 0.0;
      for (int k = 0; k < 3; ++k) expected += P1[3 * r + k] * P0[3 * c + k];
      largest_entry_of_difference = std::max(largest_entry_of_difference,
                                             std::abs(expected - R[3 * r + c]));
    }
  }
  rotation_angle = std::acos(std::min(1.0, (R[0] + R[4] + R[8] - 1) / 2));
  EXPECT_LT(largest_entry_of_difference, 1e-9);
  EXPECT_GT(rotation_angle, 0.05);  // the sequence turned by 5 degrees
  // Outside the buffer: false, with the reason.
  EXPECT_FALSE(lookup("camera", ros::Time(1.0), ros::Time(3.1), &R, &reason));
  EXPECT_FALSE(reason.empty());
}

TEST(Pipeline, OptionalInputMayBeAbsent) {
  SceneFixture fixture;
  const test::NoisyFrame f =
      test::noisyFrame(synthetic::renderScene(0, 64, 48), 9);
  FusionPipeline pipeline(fixture.settings, TopicNames::defaults(2));
  PipelineOutput out;
  pipeline.process(fixture.setFor(f, 1.0, false), nullptr, false, &out);
  EXPECT_EQ(out.stats->inputs_present, (std::vector<std::uint8_t>{1, 0}));
  // The state stays compatible: the next frame with both inputs warm-starts.
  pipeline.process(fixture.setFor(f, 1.03, true), nullptr, false, &out);
  EXPECT_TRUE(out.stats->warm_started);
}

TEST(Pipeline, BadInputThrowsAndTheNextGoodSetIsAnswered) {
  SceneFixture fixture;
  const test::NoisyFrame f =
      test::noisyFrame(synthetic::renderScene(0, 64, 48), 4);
  FusionPipeline pipeline(fixture.settings, TopicNames::defaults(2));
  PipelineOutput out;
  std::vector<std::pair<std::string, InputSet>> bad;
  {
    InputSet set = fixture.setFor(f, 1.0);
    set.camera_info.reset();
    bad.emplace_back("camera_info", set);
  }
  {
    InputSet set = fixture.setFor(f, 1.0);
    auto info = boost::make_shared<sensor_msgs::CameraInfo>(*set.camera_info);
    info->K.fill(0.0);
    set.camera_info = info;
    bad.emplace_back("camera_info", set);
  }
  {
    InputSet set = fixture.setFor(f, 1.0);
    auto normals = boost::make_shared<sensor_msgs::Image>(*set.normals[1]);
    normals->header.frame_id = "elsewhere";
    set.normals[1] = normals;
    bad.emplace_back("normals_1", set);
  }
  {
    InputSet set = fixture.setFor(f, 1.0);
    NormalMap nan(64, 48, 3, NAN);
    set.normals[0] = normalsMessage(nan, makeHeader(1.0));
    bad.emplace_back("normals_0", set);
  }
  {
    InputSet set = fixture.setFor(f, 1.0);
    auto info = boost::make_shared<sensor_msgs::CameraInfo>(*set.camera_info);
    info->header.frame_id = "elsewhere";
    set.camera_info = info;
    bad.emplace_back("camera_info: frame_id 'elsewhere'", set);
  }
  {
    // A confidence in another frame (the pipeline reads it when
    // use_confidence_0 is set).
    InputSet set = fixture.setFor(f, 1.0);
    sensor_msgs::ImagePtr confidence = boost::make_shared<sensor_msgs::Image>();
    confidence->header = makeHeader(1.0, "elsewhere");
    confidence->encoding = "32FC1";
    confidence->width = 64;
    confidence->height = 48;
    confidence->step = 64 * 4;
    confidence->data.assign(confidence->step * 48, 0);
    set.confidence[0] = confidence;
    bad.emplace_back("confidence_0: frame_id 'elsewhere'", set);
  }
  {
    InputSet set = fixture.setFor(f, 1.0);
    auto image = boost::make_shared<sensor_msgs::Image>(*set.image);
    image->width = 1;
    image->step = 3;
    image->data.assign(3 * image->height, 0);
    set.image = image;
    bad.emplace_back("image: expected at least 2x2 pixels, got 1x48", set);
  }
  NodeSettings with_confidence = fixture.settings;
  with_confidence.inputs[0].use_confidence = true;
  pipeline.setSettings(with_confidence);
  for (const auto& entry : bad) {
    try {
      pipeline.process(entry.second, nullptr, false, &out);
      ADD_FAILURE() << "expected an InputError naming " << entry.first;
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find(entry.first), std::string::npos)
          << e.what();
    }
  }
  pipeline.process(fixture.setFor(f, 2.0), nullptr, false, &out);
  EXPECT_EQ(out.fused->header.stamp, ros::Time(2.0));
  EXPECT_EQ(pipeline.framesProcessed(), 1u);
}

}  // namespace
}  // namespace node
}  // namespace normal_fusion
