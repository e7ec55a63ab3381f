// File formats: float normal maps (EXR, PFM), colour-coded PNGs, images,
// heatmaps and camera_info YAML; typed errors for bad files.
#include <gtest/gtest.h>
#include <stdlib.h>
#include <yaml-cpp/yaml.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <random>
#include <string>

#include "normal_fusion/errors.h"
#include "normal_fusion/io.h"

namespace normal_fusion {
namespace {

namespace fs = std::filesystem;
constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

/// A fresh directory under the system's temp directory, removed afterwards.
class IoTest : public ::testing::Test {
 protected:
  void SetUp() override {
    std::string pattern = (fs::temp_directory_path() / "nf_io_XXXXXX").string();
    ASSERT_NE(mkdtemp(pattern.data()), nullptr);
    dir_ = pattern;
  }
  void TearDown() override {
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }
  std::string path(const std::string& name) const {
    return (fs::path(dir_) / name).string();
  }
  void writeText(const std::string& name, const std::string& text) const {
    std::ofstream(path(name)) << text;
  }

  fs::path dir_;
};

/// Runs `action` and expects an InputError whose message contains `needle`.
void expectInputError(const std::function<void()>& action,
                      const std::string& needle) {
  try {
    action();
    ADD_FAILURE() << "expected an InputError mentioning '" << needle << "'";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find(needle), std::string::npos)
        << "message: " << e.what();
  }
}

/// A 5 x 4 map with distinct values per pixel and channel, pixel (0, 0) =
/// (0.1, 0.2, 0.3), pixel (2, 1) missing, pixel (4, 3) with only y missing.
NormalMap distinctNormals() {
  NormalMap n(5, 4, 3);
  for (int y = 0; y < 4; ++y) {
    for (int x = 0; x < 5; ++x) {
      for (int c = 0; c < 3; ++c) {
        n.at(c, y, x) = 0.1f * (c + 1) + 0.01f * x - 0.03f * y;
      }
    }
  }
  for (int c = 0; c < 3; ++c) n.at(c, 1, 2) = kNaN;
  n.at(1, 3, 4) = kNaN;
  return n;
}

void expectSameFloats(const PlanarImage& expected, const PlanarImage& actual) {
  ASSERT_EQ(actual.width(), expected.width());
  ASSERT_EQ(actual.height(), expected.height());
  ASSERT_EQ(actual.channels(), expected.channels());
  for (int c = 0; c < expected.channels(); ++c) {
    for (int y = 0; y < expected.height(); ++y) {
      for (int x = 0; x < expected.width(); ++x) {
        const float e = expected.at(c, y, x);
        const float a = actual.at(c, y, x);
        if (std::isnan(e)) {
          EXPECT_TRUE(std::isnan(a)) << "c " << c << " y " << y << " x " << x;
        } else {
          EXPECT_EQ(a, e) << "c " << c << " y " << y << " x " << x;
        }
      }
    }
  }
}

class FloatFormatTest : public IoTest,
                        public ::testing::WithParamInterface<std::string> {};

TEST_P(FloatFormatTest, NormalMapRoundTripKeepsValuesOrderAndNaN) {
  const NormalMap written = distinctNormals();
  const std::string file = path("normals" + GetParam());
  io::writeNormalMap(file, written);
  const NormalMap read = io::readNormalMap(file);
  expectSameFloats(written, read);
  EXPECT_EQ(read.at(0, 0, 0), 0.1f);
  EXPECT_EQ(read.at(1, 0, 0), 0.2f);
  EXPECT_EQ(read.at(2, 0, 0), 0.3f);
}

TEST_P(FloatFormatTest, ChannelZeroOfTheFileIsX) {
  const NormalMap written = distinctNormals();
  const std::string file = path("normals" + GetParam());
  io::writeNormalMap(file, written);
  // The contract: channel c as OpenCV's imread returns it is component c.
  const cv::Mat raw = cv::imread(file, cv::IMREAD_UNCHANGED);
  ASSERT_EQ(raw.type(), CV_32FC3);
  ASSERT_EQ(raw.cols, 5);
  ASSERT_EQ(raw.rows, 4);
  const cv::Vec3f px = raw.at<cv::Vec3f>(0, 0);
  EXPECT_EQ(px[0], 0.1f);
  EXPECT_EQ(px[1], 0.2f);
  EXPECT_EQ(px[2], 0.3f);
  EXPECT_EQ(raw.at<cv::Vec3f>(3, 1)[0], written.at(0, 3, 1));
}

TEST_P(FloatFormatTest, ScalarMapRoundTrip) {
  ScalarMap written(3, 2, 1);
  for (int i = 0; i < 6; ++i) written.data()[i] = 0.125f * i - 0.2f;
  written.at(0, 1, 2) = kNaN;
  const std::string file = path("scalar" + GetParam());
  io::writeScalarMap(file, written);
  expectSameFloats(written, io::readScalarMap(file));
}

TEST_P(FloatFormatTest, WrongChannelCountIsAnInputError) {
  ScalarMap one_plane(4, 3, 1, 0.5f);
  const std::string scalar_file = path("one" + GetParam());
  io::writeScalarMap(scalar_file, one_plane);
  expectInputError([&] { io::readNormalMap(scalar_file); }, "3 channels");

  const std::string normal_file = path("three" + GetParam());
  io::writeNormalMap(normal_file, distinctNormals());
  expectInputError([&] { io::readScalarMap(normal_file); }, "single-channel");
}

INSTANTIATE_TEST_SUITE_P(ExrAndPfm, FloatFormatTest,
                         ::testing::Values(".exr", ".pfm"),
                         [](const auto& info) { return info.param.substr(1); });

TEST_F(IoTest, PictureRoundTripIsWithinQuantization) {
  NormalMap written(16, 9, 3);
  std::mt19937 rng(7);
  std::normal_distribution<float> gauss(0.0f, 1.0f);
  for (std::size_t i = 0; i < written.pixelCount(); ++i) {
    float v[3] = {gauss(rng), gauss(rng), gauss(rng)};
    const float len = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    for (int c = 0; c < 3; ++c) written.plane(c)[i] = v[c] / len;
  }
  const std::string file = path("picture.png");
  io::writeNormalPicture(file, written);
  const NormalMap read = io::readNormalMap(file);
  ASSERT_TRUE(read.sameSize(written));
  // Rounding moves each component of c by <= 0.5 / 255, of n = 2c - 1 by
  // <= 1 / 255, the vector by d <= sqrt(3) / 255; normalizing adds <= d.
  const double bound = 2.0 * std::sqrt(3.0) / 255.0;
  for (std::size_t i = 0; i < written.pixelCount(); ++i) {
    double dist2 = 0.0;
    double len2 = 0.0;
    for (int c = 0; c < 3; ++c) {
      const double d = read.plane(c)[i] - written.plane(c)[i];
      dist2 += d * d;
      len2 += read.plane(c)[i] * read.plane(c)[i];
    }
    EXPECT_LE(std::sqrt(dist2), bound) << "pixel " << i;
    EXPECT_NEAR(len2, 1.0, 1e-5) << "pixel " << i;
  }
}

TEST_F(IoTest, PictureCodesXAsRedYAsGreenZAsBlue) {
  NormalMap n(2, 1, 3, 0.0f);
  n.at(0, 0, 0) = 1.0f;   // +x
  n.at(2, 0, 1) = -1.0f;  // -z
  const std::string file = path("axes.png");
  io::writeNormalPicture(file, n);
  const cv::Mat raw = cv::imread(file, cv::IMREAD_UNCHANGED);
  ASSERT_EQ(raw.type(), CV_8UC3);
  // OpenCV order B, G, R; c = (n + 1) / 2 * 255, 127.5 rounds to 128.
  EXPECT_EQ(raw.at<cv::Vec3b>(0, 0), cv::Vec3b(128, 128, 255));
  EXPECT_EQ(raw.at<cv::Vec3b>(0, 1), cv::Vec3b(0, 128, 128));
}

TEST_F(IoTest, BlackPixelsAreMissingBothWays) {
  // Reading: black is missing, other colours decode to unit vectors.
  cv::Mat raw(1, 2, CV_8UC3);
  raw.at<cv::Vec3b>(0, 0) = cv::Vec3b(0, 0, 0);
  raw.at<cv::Vec3b>(0, 1) = cv::Vec3b(0, 128, 128);  // B = 0: z = -1
  const std::string file = path("coded.png");
  ASSERT_TRUE(cv::imwrite(file, raw));
  const NormalMap read = io::readNormalMap(file);
  for (int c = 0; c < 3; ++c) EXPECT_TRUE(std::isnan(read.at(c, 0, 0)));
  // 128 codes 2 * 128 / 255 - 1 = 1 / 255, the nearest level to 0.
  EXPECT_NEAR(read.at(0, 0, 1), 0.0f, 1.0 / 255.0);
  EXPECT_NEAR(read.at(1, 0, 1), 0.0f, 1.0 / 255.0);
  EXPECT_NEAR(read.at(2, 0, 1), -1.0f, 1e-4);

  // Writing: NaN and zero vectors become black.
  NormalMap n(3, 1, 3, 0.0f);
  for (int c = 0; c < 3; ++c) n.at(c, 0, 0) = kNaN;
  n.at(2, 0, 2) = -1.0f;
  const std::string out = path("missing.png");
  io::writeNormalPicture(out, n);
  const cv::Mat written = cv::imread(out, cv::IMREAD_UNCHANGED);
  EXPECT_EQ(written.at<cv::Vec3b>(0, 0), cv::Vec3b(0, 0, 0));
  EXPECT_EQ(written.at<cv::Vec3b>(0, 1), cv::Vec3b(0, 0, 0));
  EXPECT_NE(written.at<cv::Vec3b>(0, 2), cv::Vec3b(0, 0, 0));
}

TEST_F(IoTest, ColorCodeMapsToUnitInterval) {
  NormalMap n(2, 1, 3, 0.0f);
  n.at(1, 0, 0) = -1.0f;
  for (int c = 0; c < 3; ++c) n.at(c, 0, 1) = kNaN;
  const ColorImage picture = io::colorCode(n);
  ASSERT_EQ(picture.channels(), 3);
  EXPECT_FLOAT_EQ(picture.at(0, 0, 0), 0.5f);
  EXPECT_FLOAT_EQ(picture.at(1, 0, 0), 0.0f);
  EXPECT_FLOAT_EQ(picture.at(2, 0, 0), 0.5f);
  for (int c = 0; c < 3; ++c) EXPECT_EQ(picture.at(c, 0, 1), 0.0f);
}

TEST_F(IoTest, ReadImageScalesDepthsAndOrdersRgb) {
  cv::Mat grey8(2, 3, CV_8UC1, cv::Scalar(51));
  cv::Mat grey16(2, 3, CV_16UC1, cv::Scalar(13107));
  cv::Mat bgr(2, 3, CV_8UC3, cv::Scalar(255, 102, 0));  // B = 1, G = 0.4, R = 0
  ASSERT_TRUE(cv::imwrite(path("g8.png"), grey8));
  ASSERT_TRUE(cv::imwrite(path("g16.png"), grey16));
  ASSERT_TRUE(cv::imwrite(path("bgr.png"), bgr));

  const ColorImage g8 = io::readImage(path("g8.png"));
  ASSERT_EQ(g8.channels(), 1);
  EXPECT_EQ(g8.width(), 3);
  EXPECT_EQ(g8.height(), 2);
  EXPECT_FLOAT_EQ(g8.at(0, 1, 2), 0.2f);
  const ColorImage g16 = io::readImage(path("g16.png"));
  ASSERT_EQ(g16.channels(), 1);
  EXPECT_FLOAT_EQ(g16.at(0, 1, 2), 0.2f);
  const ColorImage rgb = io::readImage(path("bgr.png"));
  ASSERT_EQ(rgb.channels(), 3);
  EXPECT_FLOAT_EQ(rgb.at(0, 1, 1), 0.0f);  // R
  EXPECT_FLOAT_EQ(rgb.at(1, 1, 1), 0.4f);  // G
  EXPECT_FLOAT_EQ(rgb.at(2, 1, 1), 1.0f);  // B
}

TEST_F(IoTest, WriteImageRoundTrip) {
  ColorImage rgb(4, 2, 3);
  for (int c = 0; c < 3; ++c) {
    for (int x = 0; x < 4; ++x) {
      rgb.at(c, 0, x) = (c * 4 + x) / 11.0f;
      rgb.at(c, 1, x) = 1.0f - (c * 4 + x) / 11.0f;
    }
  }
  io::writeImage(path("rgb.png"), rgb);
  const ColorImage read = io::readImage(path("rgb.png"));
  ASSERT_EQ(read.channels(), 3);
  ASSERT_TRUE(read.sameSize(rgb));
  for (std::size_t i = 0; i < rgb.pixelCount() * 3; ++i) {
    // 8 bits: the round trip moves a value by at most half a step.
    EXPECT_NEAR(read.data()[i], rgb.data()[i], 0.5 / 255.0 + 1e-6);
  }
  ColorImage grey(2, 2, 1, 0.6f);
  io::writeImage(path("grey.png"), grey);
  const ColorImage grey_read = io::readImage(path("grey.png"));
  ASSERT_EQ(grey_read.channels(), 1);
  EXPECT_NEAR(grey_read.at(0, 1, 1), 0.6f, 0.5 / 255.0);
}

TEST_F(IoTest, HeatmapIsBlackForNaNAndBrighterForLargerValues) {
  ScalarMap values(3, 1, 1);
  values.at(0, 0, 0) = 0.0f;
  values.at(0, 0, 1) = 10.0f;
  values.at(0, 0, 2) = kNaN;
  io::writeHeatmap(path("heat.png"), values, 0.0, 10.0);
  const cv::Mat raw = cv::imread(path("heat.png"), cv::IMREAD_UNCHANGED);
  ASSERT_EQ(raw.type(), CV_8UC3);
  const auto brightness = [&](int x) {
    const cv::Vec3b p = raw.at<cv::Vec3b>(0, x);
    return p[0] + p[1] + p[2];
  };
  EXPECT_EQ(raw.at<cv::Vec3b>(0, 2), cv::Vec3b(0, 0, 0));
  EXPECT_GT(brightness(1), brightness(0) + 300);
  EXPECT_THROW(io::writeHeatmap(path("bad.png"), values, 1.0, 1.0),
               ParameterError);
}

TEST_F(IoTest, CameraInfoRoundTrip) {
  const CameraIntrinsics K(525.123456789, 524.25, 319.75, 239.5);
  io::writeCameraInfo(path("cam.yaml"), K, 640, 480, "rgb_optical");
  int width = 0;
  int height = 0;
  const CameraIntrinsics read =
      io::readCameraInfo(path("cam.yaml"), &width, &height);
  EXPECT_EQ(width, 640);
  EXPECT_EQ(height, 480);
  for (int i = 0; i < 9; ++i) EXPECT_EQ(read.K[i], K.K[i]) << "entry " << i;

  // The file carries every key of the ROS camera_calibration format.
  const YAML::Node root = YAML::LoadFile(path("cam.yaml"));
  EXPECT_EQ(root["camera_name"].as<std::string>(), "rgb_optical");
  EXPECT_EQ(root["distortion_model"].as<std::string>(), "plumb_bob");
  EXPECT_EQ(root["distortion_coefficients"]["data"].size(), 5u);
  EXPECT_EQ(root["rectification_matrix"]["data"].size(), 9u);
  ASSERT_EQ(root["projection_matrix"]["data"].size(), 12u);
  EXPECT_EQ(root["projection_matrix"]["data"][0].as<double>(), K.fx());
  EXPECT_EQ(root["projection_matrix"]["data"][6].as<double>(), K.cy());
}

TEST_F(IoTest, ReadsFilesOfRosCameraCalibration) {
  writeText("ros.yaml",
            "image_width: 640\n"
            "image_height: 480\n"
            "camera_name: narrow_stereo\n"
            "camera_matrix:\n"
            "  rows: 3\n"
            "  cols: 3\n"
            "  data: [ 615.5, 0., 320.25, 0., 616.75, 241.5, 0., 0., 1. ]\n"
            "distortion_model: plumb_bob\n"
            "distortion_coefficients:\n"
            "  rows: 1\n"
            "  cols: 5\n"
            "  data: [ 0.1, -0.2, 0., 0., 0. ]\n"
            "rectification_matrix:\n"
            "  rows: 3\n"
            "  cols: 3\n"
            "  data: [ 1., 0., 0., 0., 1., 0., 0., 0., 1. ]\n"
            "projection_matrix:\n"
            "  rows: 3\n"
            "  cols: 4\n"
            "  data: [ 615.5, 0., 320.25, 0., 0., 616.75, 241.5, 0., 0., 0., "
            "1., 0. ]\n");
  int width = 0;
  int height = 0;
  const CameraIntrinsics K =
      io::readCameraInfo(path("ros.yaml"), &width, &height);
  EXPECT_EQ(width, 640);
  EXPECT_EQ(height, 480);
  EXPECT_EQ(K.fx(), 615.5);
  EXPECT_EQ(K.fy(), 616.75);
  EXPECT_EQ(K.cx(), 320.25);
  EXPECT_EQ(K.cy(), 241.5);
}

TEST_F(IoTest, BadCameraInfoIsAnInputError) {
  const std::string matrix =
      "camera_matrix:\n  rows: 3\n  cols: 3\n"
      "  data: [500, 0, 160, 0, 500, 120, 0, 0, 1]\n";
  writeText("no_matrix.yaml", "image_width: 320\nimage_height: 240\n");
  expectInputError([&] { io::readCameraInfo(path("no_matrix.yaml")); },
                   "camera_matrix");
  writeText("no_width.yaml", "image_height: 240\n" + matrix);
  expectInputError([&] { io::readCameraInfo(path("no_width.yaml")); },
                   "image_width");
  writeText("no_data.yaml",
            "image_width: 320\nimage_height: 240\n"
            "camera_matrix:\n  rows: 3\n  cols: 3\n");
  expectInputError([&] { io::readCameraInfo(path("no_data.yaml")); },
                   "camera_matrix.data");
  writeText("singular.yaml",
            "image_width: 320\nimage_height: 240\n"
            "camera_matrix:\n  rows: 3\n  cols: 3\n"
            "  data: [0, 0, 160, 0, 500, 120, 0, 0, 1]\n");
  expectInputError([&] { io::readCameraInfo(path("singular.yaml")); },
                   "singular");
  writeText("eight.yaml",
            "image_width: 320\nimage_height: 240\n"
            "camera_matrix:\n  rows: 3\n  cols: 3\n"
            "  data: [500, 0, 160, 0, 500, 120, 0, 0]\n");
  expectInputError([&] { io::readCameraInfo(path("eight.yaml")); },
                   "8 numbers");
  writeText("text.yaml", "image_width: wide\nimage_height: 240\n" + matrix);
  expectInputError([&] { io::readCameraInfo(path("text.yaml")); }, "integer");
  writeText("broken.yaml", "image_width: [320\n");
  expectInputError([&] { io::readCameraInfo(path("broken.yaml")); }, "YAML");
  EXPECT_THROW(io::writeCameraInfo(path("out.yaml"),
                                   CameraIntrinsics(0, 1, 0, 0), 10, 10),
               InputError);
}

TEST_F(IoTest, MissingFilesAreInputErrorsNamingThePath) {
  const std::string missing = path("nothing_here.exr");
  expectInputError([&] { io::readNormalMap(missing); }, missing);
  expectInputError([&] { io::readScalarMap(missing); }, missing);
  expectInputError([&] { io::readImage(path("nothing_here.png")); },
                   "nothing_here.png");
  expectInputError([&] { io::readCameraInfo(path("nothing_here.yaml")); },
                   "nothing_here.yaml");
}

TEST_F(IoTest, UnreadableOrWrongFilesAreInputErrors) {
  writeText("not_an_image.png", "plain text, no PNG signature\n");
  expectInputError([&] { io::readNormalMap(path("not_an_image.png")); },
                   "could not decode");
  expectInputError([&] { io::readImage(path("not_an_image.png")); },
                   "could not decode");
  // A grey PNG is no colour-coded normal map; a float file is no image.
  ASSERT_TRUE(
      cv::imwrite(path("grey.png"), cv::Mat(2, 2, CV_8UC1, cv::Scalar(9))));
  expectInputError([&] { io::readNormalMap(path("grey.png")); }, "found 1");
  io::writeNormalMap(path("float.exr"), distinctNormals());
  expectInputError([&] { io::readImage(path("float.exr")); }, "32-bit float");
}

TEST_F(IoTest, BadWritesAreInputErrors) {
  const NormalMap n = distinctNormals();
  expectInputError([&] { io::writeNormalMap(path("normals.png"), n); },
                   ".exr or .pfm");
  expectInputError(
      [&] { io::writeNormalMap(path("no_such_dir/normals.exr"), n); },
      "does not exist");
  expectInputError(
      [&] { io::writeNormalMap(path("one.exr"), ScalarMap(2, 2, 1)); },
      "3 plane");
  expectInputError([&] { io::writeImage(path("empty.png"), ColorImage()); },
                   "1 or 3 planes");
}

}  // namespace
}  // namespace normal_fusion
