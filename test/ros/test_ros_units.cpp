// Tests of the ROS interface that need no master: parameters, conversions
// and the per-set pipeline (the nodelet's and fuse_bag's shared core).
#include <gtest/gtest.h>
#include <normal_fusion/NormalFusionConfig.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <random>

#include "eval/synthetic.h"
#include "normal_fusion/errors.h"
#include "normal_fusion/ros/conversions.h"
#include "normal_fusion/ros/parameters.h"
#include "normal_fusion/ros/pipeline.h"
#include "ros_test_util.h"

namespace normal_fusion {
namespace node {
namespace {

using test::cameraInfoMessage;
using test::imageMessage;
using test::makeHeader;
using test::normalsMessage;

// ---------------------------------------------------------------- conversions

sensor_msgs::Image rawImage(const std::string& encoding, int W, int H,
                            int bytes_per_pixel) {
  sensor_msgs::Image msg;
  msg.encoding = encoding;
  msg.width = W;
  msg.height = H;
  msg.step = W * bytes_per_pixel;
  msg.data.assign(static_cast<std::size_t>(msg.step) * H, 0);
  return msg;
}

TEST(Conversions, EveryImageEncodingGivesTheSameIntensities) {
  // Pixel (1, 0) has R = 200, G = 100, B = 50 in every colour encoding.
  struct Case {
    const char* encoding;
    int channels, bytes;
    int r, g, b;
  } cases[] = {{"rgb8", 3, 1, 0, 1, 2},  {"bgr8", 3, 1, 2, 1, 0},
               {"rgba8", 4, 1, 0, 1, 2}, {"bgra8", 4, 1, 2, 1, 0},
               {"rgb16", 3, 2, 0, 1, 2}, {"bgr16", 3, 2, 2, 1, 0}};
  for (const Case& c : cases) {
    sensor_msgs::Image msg = rawImage(c.encoding, 3, 2, c.channels * c.bytes);
    msg.step += 4;  // padded rows
    msg.data.assign(static_cast<std::size_t>(msg.step) * 2, 0);
    const int values[3] = {200, 100, 50};
    const int where[3] = {c.r, c.g, c.b};
    for (int k = 0; k < 3; ++k) {
      const std::size_t at = (1 * c.channels + where[k]) * c.bytes;
      if (c.bytes == 1) {
        msg.data[at] = values[k];
      } else {
        const std::uint16_t v = values[k] * 257;
        std::memcpy(&msg.data[at], &v, 2);
      }
    }
    ColorImage image;
    imageFromMessage(msg, "image", image);
    ASSERT_EQ(image.channels(), 3) << c.encoding;
    EXPECT_NEAR(image.at(0, 0, 1), 200 / 255.0, 1e-6) << c.encoding;
    EXPECT_NEAR(image.at(1, 0, 1), 100 / 255.0, 1e-6) << c.encoding;
    EXPECT_NEAR(image.at(2, 0, 1), 50 / 255.0, 1e-6) << c.encoding;
    EXPECT_EQ(image.at(0, 1, 1), 0.0f) << c.encoding;
  }
  sensor_msgs::Image mono = rawImage("mono16", 2, 2, 2);
  const std::uint16_t v = 65535;
  std::memcpy(&mono.data[2], &v, 2);
  ColorImage grey;
  imageFromMessage(mono, "image", grey);
  ASSERT_EQ(grey.channels(), 1);
  EXPECT_FLOAT_EQ(grey.at(0, 0, 1), 1.0f);
  EXPECT_FLOAT_EQ(grey.at(0, 0, 0), 0.0f);
}

template <typename F>
std::string inputErrorOf(F f) {
  try {
    f();
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

TEST(Conversions, BadImagesThrowInputErrorsNamingTheTopic) {
  ColorImage image;
  NormalMap normals;
  sensor_msgs::Image yuv = rawImage("yuv422", 4, 4, 2);
  EXPECT_NE(inputErrorOf([&] {
              imageFromMessage(yuv, "/cam/image", image);
            }).find("/cam/image: unsupported encoding 'yuv422'"),
            std::string::npos);
  sensor_msgs::Image short_data = rawImage("rgb8", 4, 4, 3);
  short_data.data.resize(20);
  EXPECT_NE(inputErrorOf([&] {
              imageFromMessage(short_data, "/img", image);
            }).find("/img: expected height * step"),
            std::string::npos);
  sensor_msgs::Image short_step = rawImage("rgb8", 4, 4, 3);
  short_step.step = 8;
  short_step.data.resize(32);
  EXPECT_NE(inputErrorOf([&] {
              imageFromMessage(short_step, "/img", image);
            }).find("step 8 is shorter"),
            std::string::npos);
  sensor_msgs::Image empty = rawImage("rgb8", 0, 0, 3);
  EXPECT_NE(inputErrorOf([&] { imageFromMessage(empty, "/img", image); }), "");
  // A mono16 image is not a normal map.
  sensor_msgs::Image mono = rawImage("mono16", 4, 4, 2);
  EXPECT_NE(inputErrorOf([&] {
              normalsFromMessage(mono, "/normals_0", 0.1, normals);
            }).find("/normals_0: unsupported encoding"),
            std::string::npos);
}

sensor_msgs::Image floatNormals(int W, int H, float x, float y, float z) {
  sensor_msgs::Image msg = rawImage("32FC3", W, H, 12);
  for (int i = 0; i < W * H; ++i) {
    const float v[3] = {x, y, z};
    std::memcpy(&msg.data[i * 12], v, 12);
  }
  return msg;
}

TEST(Conversions, NormalMapsAreCheckedAndNormalized) {
  NormalMap normals;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  // Nearly unit vectors are normalized.
  normalsFromMessage(floatNormals(3, 2, 0.0f, 0.0f, -1.05f), "n", 0.1, normals);
  EXPECT_FLOAT_EQ(normals.at(2, 1, 2), -1.0f);
  // Non-unit vectors, all-NaN maps and infinities are errors naming the
  // topic.
  EXPECT_NE(inputErrorOf([&] {
              normalsFromMessage(floatNormals(3, 2, 0, 0, -3), "/n0", 0.1,
                                 normals);
            }).find("/n0: 6 of 6 normals are not unit vectors"),
            std::string::npos);
  EXPECT_NE(inputErrorOf([&] {
              normalsFromMessage(floatNormals(3, 2, nan, nan, nan), "/n0", 0.1,
                                 normals);
            }).find("/n0: no valid normal"),
            std::string::npos);
  EXPECT_NE(inputErrorOf([&] {
              normalsFromMessage(floatNormals(3, 2, 0, 0, -INFINITY), "/n0",
                                 0.1, normals);
            }).find("infinite"),
            std::string::npos);
  // Zero vectors and NaN are missing, not errors, while others are valid.
  sensor_msgs::Image mixed = floatNormals(2, 1, 0.0f, 0.0f, -1.0f);
  const float zero[3] = {0, 0, 0};
  std::memcpy(&mixed.data[0], zero, 12);
  normalsFromMessage(mixed, "n", 0.1, normals);
  EXPECT_TRUE(std::isnan(normals.at(0, 0, 0)));
  EXPECT_FLOAT_EQ(normals.at(2, 0, 1), -1.0f);
}

TEST(Conversions, ColourCodedNormalsDecodeInEveryChannelOrder) {
  // n = (0.6, 0, -0.8): c = (n + 1) / 2 * 255 = (204, 127.5, 25.5).
  for (const char* encoding : {"rgb8", "8UC3", "bgr8", "rgba8", "bgra8"}) {
    const bool bgr = encoding[0] == 'b';
    const int C = std::string(encoding).find('a') != std::string::npos ? 4 : 3;
    sensor_msgs::Image msg = rawImage(encoding, 2, 1, C);
    const std::uint8_t rgb[3] = {204, 128, 26};
    for (int k = 0; k < 3; ++k) msg.data[bgr ? 2 - k : k] = rgb[k];
    NormalMap normals;
    normalsFromMessage(msg, "n", 0.1, normals);
    EXPECT_NEAR(normals.at(0, 0, 0), 0.6f, 0.01f) << encoding;
    EXPECT_NEAR(normals.at(1, 0, 0), 0.0f, 0.01f) << encoding;
    EXPECT_NEAR(normals.at(2, 0, 0), -0.8f, 0.01f) << encoding;
    EXPECT_TRUE(std::isnan(normals.at(0, 0, 1))) << "black is missing";
  }
}

TEST(Conversions, AKThatCannotGiveFiniteRaysIsRefusedNamingTheTopic) {
  sensor_msgs::CameraInfo info;
  info.width = 640;
  info.height = 480;
  // Each of these passed the checks before and gave NaN normals.
  const std::vector<std::array<double, 9>> bad = {
      {1e-150, 0, 320, 0, 1e-150, 240, 0, 0, 1},  // focal length 1e-150
      {500, 0, 1e30, 0, 500, 240, 0, 0, 1},       // principal point 1e30
      {1e200, 0, 320, 0, 1e200, 240, 0, 0, 1},    // det(K) = inf
      {1e-3, 0, 320, 0, 500, 240, 0, 0, 1},       // 89.9999 degrees
  };
  for (const auto& K : bad) {
    std::copy(K.begin(), K.end(), info.K.begin());
    const std::string error =
        inputErrorOf([&] { intrinsicsFromCameraInfo(info, "/ci", 640, 480); });
    EXPECT_EQ(error.rfind("/ci: ", 0), 0u) << error;
    EXPECT_NE(error.find("camera intrinsics: "), std::string::npos) << error;
  }
  // A 170-degree fisheye-like focal length and a principal point outside the
  // image (a crop) are fine.
  info.K = {28, 0, 320, 0, 28, 240, 0, 0, 1};
  EXPECT_NO_THROW(intrinsicsFromCameraInfo(info, "/ci", 640, 480));
  info.K = {500, 0, -200, 0, 500, 900, 0, 0, 1};
  EXPECT_NO_THROW(intrinsicsFromCameraInfo(info, "/ci", 640, 480));
}

TEST(Conversions, ArrivalChecksNameTheTopicAndRefuseBeforeAllocating) {
  std_msgs::Header header;
  header.stamp = ros::Time(10, 0);
  header.stamp.nsec = 1000000000u;  // not normalized
  EXPECT_NE(inputErrorOf([&] {
              precheckMessage("/image", header, nullptr);
            }).find("/image: stamp nsec = 1000000000 is not normalized"),
            std::string::npos);
  header.stamp = ros::Time(4102444800u, 0);  // the year 2100 is fine
  EXPECT_NO_THROW(precheckMessage("/image", header, nullptr));
  // An 8000x6000 header without data: refused on its size alone.
  sensor_msgs::Image big;
  big.encoding = "rgb8";
  big.width = 8000;
  big.height = 6000;
  big.step = 24000;
  MessageLimits limits;
  const std::string error =
      inputErrorOf([&] { precheckMessage("/image", header, &big, limits); });
  EXPECT_NE(error.find("/image: a 8000x6000 image (48000000 pixels) is larger "
                       "than max_pixels = 12000000"),
            std::string::npos)
      << error;
  limits.max_pixels = 0;  // no bound: the data size is checked next
  EXPECT_NE(inputErrorOf([&] {
              precheckMessage("/image", header, &big, limits);
            }).find("height * step"),
            std::string::npos);
  // Gaps between stamps of any two times, in seconds, without overflow.
  EXPECT_NEAR(secondsBetween(ros::Time(4102444800u, 0), ros::Time(100, 0)),
              4102444700.0, 1e-3);
  EXPECT_NEAR(secondsBetween(ros::Time(100, 0), ros::Time(4102444800u, 0)),
              -4102444700.0, 1e-3);
}

TEST(Conversions, CameraInfoIsChecked) {
  sensor_msgs::CameraInfo info;
  info.K = {500, 0, 320, 0, 500, 240, 0, 0, 1};
  info.width = 640;
  info.height = 480;
  const CameraIntrinsics K = intrinsicsFromCameraInfo(info, "ci", 640, 480);
  EXPECT_EQ(K.fx(), 500.0);
  EXPECT_NE(inputErrorOf([&] {
              intrinsicsFromCameraInfo(info, "/ci", 320, 240);
            }).find("/ci: camera_info is for a 640x480 image"),
            std::string::npos);
  sensor_msgs::CameraInfo zero = info;
  zero.K = {0, 0, 0, 0, 0, 0, 0, 0, 0};
  EXPECT_NE(inputErrorOf([&] {
              intrinsicsFromCameraInfo(zero, "/ci", 640, 480);
            }).find("/ci: expected K with fx, fy > 0"),
            std::string::npos);
  sensor_msgs::CameraInfo nan = info;
  nan.K[2] = std::numeric_limits<double>::quiet_NaN();
  EXPECT_NE(inputErrorOf([&] {
              intrinsicsFromCameraInfo(nan, "/ci", 640, 480);
            }).find("/ci: K[2] is not finite"),
            std::string::npos);
}

TEST(Conversions, ResamplingKeepsNormalsAndRejectsAnotherAspectRatio) {
  // A 4x3 map: left half one normal, right half another, one hole.
  NormalMap small(4, 3, 3);
  const float a = std::sqrt(0.5f);
  for (int y = 0; y < 3; ++y) {
    for (int x = 0; x < 4; ++x) {
      small.at(0, y, x) = x < 2 ? a : -a;
      small.at(1, y, x) = 0.0f;
      small.at(2, y, x) = -a;
    }
  }
  small.at(0, 1, 0) = small.at(1, 1, 0) = small.at(2, 1, 0) = NAN;
  for (Resampling method : {Resampling::kNearest, Resampling::kBilinear}) {
    NormalMap big;
    resampleMap(small, 16, 12, method, true, "n", big);
    ASSERT_EQ(big.width(), 16);
    for (int y = 0; y < 12; ++y) {
      for (int x = 0; x < 16; ++x) {
        const float nx = big.at(0, y, x), nz = big.at(2, y, x);
        if (std::isnan(nx)) {
          EXPECT_EQ(method, Resampling::kNearest) << "bilinear fills holes";
          continue;
        }
        // Unit length and facing the camera everywhere.
        EXPECT_NEAR(nx * nx + big.at(1, y, x) * big.at(1, y, x) + nz * nz, 1.0,
                    1e-5);
        if (x < 6) {
          EXPECT_NEAR(nx, a, 1e-5);  // far from the change
        }
        if (x > 9) {
          EXPECT_NEAR(nx, -a, 1e-5);
        }
      }
    }
  }
  NormalMap big;
  EXPECT_NE(inputErrorOf([&] {
              resampleMap(small, 16, 9, Resampling::kBilinear, true,
                          "/normals_1", big);
            }).find("/normals_1: a 4x3 map cannot be resampled"),
            std::string::npos);
  // Rows on several threads: the same values (NaN where the same).
  for (Resampling method : {Resampling::kNearest, Resampling::kBilinear}) {
    NormalMap one, three;
    resampleMap(small, 16, 12, method, true, "n", one, 1);
    resampleMap(small, 16, 12, method, true, "n", three, 3);
    ASSERT_EQ(one.pixelCount(), three.pixelCount());
    EXPECT_EQ(0, std::memcmp(one.data(), three.data(),
                             one.pixelCount() * 3 * sizeof(float)));
  }
}

/// Bilinear resampling of normals against its definition, pixel by pixel:
/// the valid neighbours (finite, non-zero) weighted bilinearly, renormalized,
/// NaN where none with weight is valid. Random normals with a fifth of them
/// NaN, infinite or zero, upsampled 2x and 3x, on one and two threads.
TEST(Conversions, BilinearNormalsFollowTheirDefinition) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> uni(-1.0f, 1.0f);
  const int w = 37, h = 23;
  NormalMap small(w, h, 3);
  for (std::size_t i = 0; i < small.pixelCount(); ++i) {
    float v[3] = {uni(rng), uni(rng), -1.0f};
    const float len = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    const float kind = 0.5f * (uni(rng) + 1.0f);
    for (int c = 0; c < 3; ++c) {
      float value = v[c] / len;
      if (kind < 0.07f)
        value = NAN;
      else if (kind < 0.13f)
        value = 0.0f;
      else if (kind < 0.2f && c == 1)
        value = INFINITY;
      small.plane(c)[i] = value;
    }
  }
  auto valid = [&](int x, int y) {
    const std::size_t i = static_cast<std::size_t>(y) * w + x;
    return isValidNormal(small.plane(0)[i], small.plane(1)[i],
                         small.plane(2)[i]);
  };
  for (int factor : {2, 3}) {
    const int W = factor * w, H = factor * h;
    for (int threads : {1, 2}) {
      NormalMap big;
      resampleMap(small, W, H, Resampling::kBilinear, true, "n", big, threads);
      int nan_pixels = 0;
      for (int y = 0; y < H; ++y) {
        const double vs =
            std::min(std::max((y + 0.5) / factor - 0.5, 0.0), h - 1.0);
        const int y0 = static_cast<int>(vs), y1 = std::min(y0 + 1, h - 1);
        const float fy = static_cast<float>(vs - y0);
        for (int x = 0; x < W; ++x) {
          const double us =
              std::min(std::max((x + 0.5) / factor - 0.5, 0.0), w - 1.0);
          const int x0 = static_cast<int>(us), x1 = std::min(x0 + 1, w - 1);
          const float fx = static_cast<float>(us - x0);
          const int xs[4] = {x0, x1, x0, x1}, ys[4] = {y0, y0, y1, y1};
          const float ws[4] = {(1 - fx) * (1 - fy), fx * (1 - fy),
                               (1 - fx) * fy, fx * fy};
          double acc[3] = {0, 0, 0}, total = 0;
          for (int k = 0; k < 4; ++k) {
            if (ws[k] <= 0.0f || !valid(xs[k], ys[k])) continue;
            for (int c = 0; c < 3; ++c) {
              acc[c] += ws[k] * small.at(c, ys[k], xs[k]);
            }
            total += ws[k];
          }
          const double len =
              std::sqrt(acc[0] * acc[0] + acc[1] * acc[1] + acc[2] * acc[2]);
          for (int c = 0; c < 3; ++c) {
            const float got = big.at(c, y, x);
            if (total <= 1e-6 || len <= 1e-6) {
              ASSERT_TRUE(std::isnan(got)) << x << "," << y;
              nan_pixels += c == 0;
            } else {
              ASSERT_NEAR(got, acc[c] / len, 1e-5)
                  << x << "," << y << " x" << factor << " threads " << threads;
            }
          }
        }
      }
      EXPECT_GT(nan_pixels, 0) << "some pixels have no valid neighbour";
    }
  }
}

TEST(Conversions, OutputsCodeTheNormals) {
  NormalMap normals(2, 1, 3);
  normals.at(0, 0, 0) = 0.6f;
  normals.at(1, 0, 0) = 0.0f;
  normals.at(2, 0, 0) = -0.8f;
  normals.at(0, 0, 1) = normals.at(1, 0, 1) = normals.at(2, 0, 1) = NAN;
  sensor_msgs::Image fused, vis;
  const std_msgs::Header header = makeHeader(12.5, "cam");
  normalsToMessage(normals, header, fused);
  normalsToVisMessage(normals, header, vis);
  EXPECT_EQ(fused.encoding, "32FC3");
  EXPECT_EQ(fused.header.stamp, header.stamp);
  EXPECT_EQ(fused.header.frame_id, "cam");
  const NormalMap back = test::normalsFromImage(fused);
  EXPECT_EQ(back.at(2, 0, 0), -0.8f);
  EXPECT_EQ(vis.encoding, "rgb8");
  EXPECT_EQ(vis.data[0], 204);
  EXPECT_EQ(vis.data[1], 128);
  EXPECT_NEAR(vis.data[2], 25.5, 0.5);  // (-0.8 + 1) * 127.5 = 25.5
  EXPECT_EQ(vis.data[3] + vis.data[4] + vis.data[5], 0);
}

// ------------------------------------------------------------------- pipeline

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

/// Under a frame budget too short for anything, a stream's first frame (and
/// its restart after time went backwards) is solved under
/// cold_start_budget_ms (none: the iteration caps) and says so in a note;
/// the warm frames in between keep the frame budget. With warm starts off
/// every frame is a one-shot cold start under the frame budget.
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

TEST(Pipeline, RotationCompensatedWarmStartUsesTheLookup) {
  SceneFixture fixture;
  fixture.settings.fixed_frame = "world";
  const auto frames = synthetic::renderSequence(0, 64, 48, 2, 1.0, 30.0);
  FusionPipeline pipeline(fixture.settings, TopicNames::defaults(2));
  PipelineOutput out;
  int calls = 0;
  // R_cur_prev from the sequence's exact poses.
  const auto& P0 = frames[0].pose.R_cam_world;
  const auto& P1 = frames[1].pose.R_cam_world;
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
  const auto& P0 = frames[0].pose.R_cam_world;
  const auto& P1 = frames[1].pose.R_cam_world;
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
