// Tests of the ROS interface that need no master: parameters, conversions,
// the synchronizer and the per-set pipeline (the nodelet's and fuse_bag's
// shared core).
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
#include "normal_fusion/ros/synchronizer.h"
#include "ros_test_util.h"

namespace normal_fusion {
namespace node {
namespace {

using test::cameraInfoMessage;
using test::imageMessage;
using test::makeHeader;
using test::normalsMessage;

bool mentions(const std::vector<std::string>& warnings,
              const std::string& word) {
  return std::any_of(
      warnings.begin(), warnings.end(),
      [&](const std::string& w) { return w.find(word) != std::string::npos; });
}

// ----------------------------------------------------------------- parameters

TEST(Parameters, YamlFileHoldsEveryParameterWithTheCodeDefaults) {
  std::vector<std::string> warnings;
  const ParameterMap from_file = parametersFromYamlFile(
      NF_SOURCE_DIR "/config/normal_fusion.yaml", &warnings);
  EXPECT_TRUE(warnings.empty());
  const ParameterMap defaults = parametersFromSettings(NodeSettings());
  for (const auto& entry : defaults) {
    auto it = from_file.find(entry.first);
    ASSERT_NE(it, from_file.end())
        << "config/normal_fusion.yaml lacks " << entry.first;
    ParameterValue value = it->second;
    // YAML writes 0.0 as a double and 1 as an int: compare as the code types.
    if (std::holds_alternative<double>(entry.second) &&
        std::holds_alternative<int>(value)) {
      value = static_cast<double>(std::get<int>(value));
    }
    EXPECT_EQ(value, entry.second)
        << entry.first << ": file " << toString(it->second) << ", code "
        << toString(entry.second);
  }
  for (const auto& entry : from_file) {
    EXPECT_EQ(defaults.count(entry.first), 1u)
        << "unknown parameter in the file: " << entry.first;
  }
  // And read back through the one function: no correction needed.
  ParameterMap params = from_file;
  warnings.clear();
  settingsFromParameters(params, &warnings);
  EXPECT_TRUE(warnings.empty()) << warnings.front();
}

TEST(Parameters, RoundTripKeepsEveryValue) {
  NodeSettings settings;
  settings.solver.lambda = 2.5;
  settings.solver.edges.color_mode = EdgeColorMode::kLuminance;
  settings.solver.backend = SolverBackend::kReference;
  settings.num_inputs = 3;
  settings.inputs[2].weight = 4.0;
  settings.inputs[2].orientation_name = "opengl";
  settings.inputs[1].use_confidence = true;
  settings.fixed_frame = "odom";
  settings.resampling = Resampling::kNearest;
  ParameterMap params = parametersFromSettings(settings);
  std::vector<std::string> warnings;
  const NodeSettings back = settingsFromParameters(params, &warnings);
  EXPECT_TRUE(warnings.empty());
  EXPECT_EQ(parametersFromSettings(back), parametersFromSettings(settings));
  EXPECT_EQ(back.inputs[2].orientation.M, Orientation::opengl().M);
}

TEST(Parameters, InvalidValuesAreRefusedWithAWarningNamingThem) {
  ParameterMap params;
  params["lambda"] = -1.0;
  params["edge_w_min"] = 2.0;
  params["inner_iterations"] = 2.5;
  params["max_outer_iterations"] = std::string("many");
  params["penalty"] = std::string("cubic");
  params["orientation_1"] = std::string("sideways");
  params["num_inputs"] = 20;
  params["weight_0"] = std::numeric_limits<double>::quiet_NaN();
  params["warm_start"] = 1;
  params["no_such_parameter"] = 3;
  std::vector<std::string> warnings;
  const NodeSettings s = settingsFromParameters(params, &warnings);
  const NodeSettings defaults;
  EXPECT_EQ(s.solver.lambda, defaults.solver.lambda);  // > 0 required
  EXPECT_EQ(std::get<double>(params["lambda"]), defaults.solver.lambda);
  // Out of range: refused, not clamped (a bound may mean "off").
  EXPECT_EQ(s.solver.edges.w_min, defaults.solver.edges.w_min);
  EXPECT_EQ(s.solver.inner_iterations, 3);  // rounded
  EXPECT_EQ(s.solver.max_outer_iterations,
            defaults.solver.max_outer_iterations);
  EXPECT_EQ(s.solver.penalty, defaults.solver.penalty);
  EXPECT_EQ(s.inputs[1].orientation.M, Orientation::optical().M);
  EXPECT_EQ(s.num_inputs, defaults.num_inputs);
  EXPECT_EQ(s.inputs[0].weight, defaults.inputs[0].weight);
  EXPECT_TRUE(s.warm_start);
  for (const char* name :
       {"'lambda'", "'edge_w_min'", "'inner_iterations'",
        "'max_outer_iterations'", "'penalty'", "'orientation_1'",
        "'num_inputs'", "'weight_0'", "'warm_start'", "'no_such_parameter'"}) {
    EXPECT_TRUE(mentions(warnings, name)) << "no warning names " << name;
  }
  EXPECT_EQ(warnings.size(), 10u);
  // The corrected map reads back without any warning.
  warnings.clear();
  params.erase("no_such_parameter");
  settingsFromParameters(params, &warnings);
  EXPECT_TRUE(warnings.empty()) << warnings.front();
}

TEST(Parameters, AnInvalidValueKeepsTheValueInUseAndEveryOtherSetting) {
  // The settings in use, as a live stream has them.
  NodeSettings current;
  current.solver.time_budget_ms = 33.0;
  current.solver.huber_eps = 0.01;
  current.solver.edges.smoothing_sigma = 1.0;
  current.inputs[0].weight = 2.0;
  current.fixed_frame = "odom";
  const ParameterMap in_use = parametersFromSettings(current);
  const double inf = std::numeric_limits<double>::infinity();
  const double nan = std::numeric_limits<double>::quiet_NaN();
  // Each of these, sent alone (as rqt_reconfigure does), is refused.
  const std::vector<std::pair<std::string, ParameterValue>> bad = {
      {"huber_eps", inf},
      {"edge_smoothing_sigma", inf},
      {"edge_smoothing_sigma", 1e4},
      {"weight_0", inf},
      {"time_budget_ms", -1.0},
      {"time_budget_ms", nan},
      {"lambda", inf},
      {"edge_alpha", -inf},
      {"relative_tolerance", nan},
      {"max_interval", 1e9},
      {"inner_iterations", -5},
      {"temporal_gate_deg", 0.0},
  };
  for (const auto& [name, value] : bad) {
    ParameterMap params = in_use;
    params[name] = value;
    std::vector<std::string> warnings;
    const NodeSettings s = settingsFromParameters(params, &warnings, current);
    EXPECT_EQ(parametersFromSettings(s), in_use)
        << name << " = " << toString(value) << " changed the settings";
    EXPECT_EQ(params, in_use) << name << ": the map was not corrected";
    ASSERT_EQ(warnings.size(), 1u) << name;
    EXPECT_TRUE(mentions(warnings, "'" + name + "'")) << warnings.front();
  }
}

TEST(Parameters, StepSizesComeInPairsAndMeetTheStepCondition) {
  ParameterMap params{{"tau", 0.1}};
  std::vector<std::string> warnings;
  NodeSettings s = settingsFromParameters(params, &warnings);
  EXPECT_EQ(s.solver.tau, 0.0);
  EXPECT_EQ(s.solver.sigma, 0.0);
  EXPECT_TRUE(mentions(warnings, "'tau'"));
  params = {{"tau", 0.5}, {"sigma", 0.5}, {"num_inputs", 2}};
  warnings.clear();
  s = settingsFromParameters(params, &warnings);
  EXPECT_EQ(s.solver.tau, 0.0);  // 0.25 * 10 >= 1
  EXPECT_TRUE(mentions(warnings, "tau * sigma"));
  params = {{"tau", 0.2}, {"sigma", 0.2}, {"num_inputs", 2}};
  warnings.clear();
  s = settingsFromParameters(params, &warnings);
  EXPECT_EQ(s.solver.tau, 0.2);
  EXPECT_TRUE(warnings.empty());
}

TEST(Parameters, DynamicReconfigureListsExactlyTheDynamicParameters) {
  const auto& descriptions =
      normal_fusion::NormalFusionConfig::__getParamDescriptions__();
  std::map<std::string, std::string> cfg;
  for (const auto& d : descriptions) cfg[d->name] = d->type;
  const ParameterMap all = parametersFromSettings(NodeSettings());
  for (const auto& entry : all) {
    if (!isDynamicParameter(entry.first)) {
      EXPECT_EQ(cfg.count(entry.first), 0u) << entry.first;
      continue;
    }
    ASSERT_EQ(cfg.count(entry.first), 1u)
        << entry.first << " is missing from cfg/NormalFusion.cfg";
    const char* expected[] = {"bool", "int", "double", "str"};
    EXPECT_EQ(cfg[entry.first], expected[entry.second.index()]) << entry.first;
  }
  for (const auto& entry : cfg) {
    EXPECT_EQ(all.count(entry.first), 1u) << "cfg has unknown " << entry.first;
  }
}

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

// --------------------------------------------------------------- synchronizer

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

TEST(Pipeline, WarmStartNeedsASmallForwardGapAndTheSameK) {
  SceneFixture fixture;
  fixture.settings.warm_start_max_gap = 0.2;
  const test::NoisyFrame f =
      test::noisyFrame(synthetic::renderScene(0, 64, 48), 5);
  FusionPipeline pipeline(fixture.settings, TopicNames::defaults(2));
  PipelineOutput out;
  pipeline.process(fixture.setFor(f, 1.0), nullptr, false, &out);
  pipeline.process(fixture.setFor(f, 1.1), nullptr, false, &out);
  EXPECT_TRUE(out.stats->warm_started);
  pipeline.process(fixture.setFor(f, 3.0), nullptr, false, &out);
  EXPECT_FALSE(out.stats->warm_started) << "gap above warm_start_max_gap";
  // Time going backwards resets the warm start, with a warning.
  pipeline.process(fixture.setFor(f, 0.5), nullptr, false, &out);
  EXPECT_FALSE(out.stats->warm_started);
  EXPECT_NE(out.warning.find("time went backwards"), std::string::npos);
  // Another K: cold.
  InputSet set = fixture.setFor(f, 0.6);
  auto info = boost::make_shared<sensor_msgs::CameraInfo>(*set.camera_info);
  info->K[0] *= 1.1;
  set.camera_info = info;
  pipeline.process(set, nullptr, false, &out);
  EXPECT_FALSE(out.stats->warm_started);
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

/// The stamp gap that the previous set's own processing opened (sets that
/// arrive meanwhile are dropped) does not end the warm start: with
/// warm_start_max_gap 0, a set 0.5 ms after one that took longer than that
/// to solve (2000 iterations) still warm-starts; one 100 s later does not.
TEST(Pipeline, TheGapOfTheProcessingItselfDoesNotEndTheWarmStart) {
  SceneFixture fixture;
  fixture.settings.warm_start_max_gap = 0.0;
  fixture.settings.solver.max_total_inner_iterations = 2000;
  fixture.settings.solver.max_outer_iterations = 100;
  fixture.settings.solver.relative_tolerance = 0.0;
  const test::NoisyFrame f =
      test::noisyFrame(synthetic::renderScene(0, 64, 48), 5);
  FusionPipeline pipeline(fixture.settings, TopicNames::defaults(2));
  PipelineOutput out;
  pipeline.process(fixture.setFor(f, 1.0), nullptr, false, &out);
  EXPECT_EQ(out.stats->inner_iterations, 2000);
  ASSERT_GT(out.stats->latency, 0.0005);
  pipeline.process(fixture.setFor(f, 1.0005), nullptr, false, &out);
  EXPECT_TRUE(out.stats->warm_started) << out.warning << out.note;
  pipeline.process(fixture.setFor(f, 101.0), nullptr, false, &out);
  EXPECT_FALSE(out.stats->warm_started);
  EXPECT_NE(out.note.find("exceeds warm_start_max_gap"), std::string::npos)
      << out.note;
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
