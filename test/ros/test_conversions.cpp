// Tests of the ROS message conversions without a master: every image and
// normal encoding, the checks on arrival and of camera_info (InputError naming
// the topic), resampling and the output messages.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "normal_fusion/errors.h"
#include "normal_fusion/ros/conversions.h"
#include "normal_fusion/ros/pipeline.h"
#include "ros_test_util.h"

namespace normal_fusion {
namespace node {
namespace {

using test::makeHeader;

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

}  // namespace
}  // namespace node
}  // namespace normal_fusion
