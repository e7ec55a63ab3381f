// Depth files (io::readDepthMap / writeDepthMap, REP 118 units) and the
// depth_to_normals command-line tool run as a process: outputs equal to the
// library's, exit codes and one-line errors.
#include <gtest/gtest.h>
#include <stdlib.h>
#include <sys/wait.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "normal_fusion/depth.h"
#include "normal_fusion/errors.h"
#include "normal_fusion/io.h"

#ifndef DEPTH_TO_NORMALS_BIN
#define DEPTH_TO_NORMALS_BIN ""
#endif

namespace normal_fusion {
namespace {

namespace fs = std::filesystem;

constexpr int kWidth = 40, kHeight = 30;

class DepthFilesTest : public ::testing::Test {
 protected:
  void SetUp() override {
    std::string pattern =
        (fs::temp_directory_path() / "nf_depth_XXXXXX").string();
    ASSERT_NE(mkdtemp(pattern.data()), nullptr);
    dir_ = pattern;
    K_ = CameraIntrinsics(36.0, 36.0, 19.5, 14.5);
    // A tilted plane 1 - 2 m away, whole millimetres, with a hole.
    depth_ = ScalarMap(kWidth, kHeight, 1);
    for (int y = 0; y < kHeight; ++y) {
      for (int x = 0; x < kWidth; ++x) {
        depth_.at(0, y, x) = std::round(1000.0f + 20.0f * x + 5.0f * y) / 1000;
      }
    }
    depth_.at(0, 12, 8) = NAN;
    io::writeCameraInfo(path("camera.yaml"), K_, kWidth, kHeight);
    io::writeCameraInfo(path("other.yaml"), K_, kWidth / 2, kHeight / 2);
  }
  void TearDown() override {
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }
  std::string path(const std::string& name) const {
    return (dir_ / name).string();
  }

  struct Result {
    int exit_code = -1;
    std::string err;
  };
  Result run(const std::string& args) const {
    const std::string binary = DEPTH_TO_NORMALS_BIN;
    const std::string err_file = path("stderr.txt");
    const std::string command =
        "'" + binary + "' " + args + " >/dev/null 2>'" + err_file + "'";
    const int status = std::system(command.c_str());
    Result r;
    r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
    std::ifstream in(err_file);
    std::stringstream text;
    text << in.rdbuf();
    r.err = text.str();
    return r;
  }

  fs::path dir_;
  CameraIntrinsics K_;
  ScalarMap depth_;
};

TEST_F(DepthFilesTest, PngMillimetresAndExrMetresRoundTrip) {
  io::writeDepthMap(path("d.png"), depth_);
  io::writeDepthMap(path("d.exr"), depth_);
  const ScalarMap png = io::readDepthMap(path("d.png"));
  const ScalarMap exr = io::readDepthMap(path("d.exr"));
  ASSERT_TRUE(png.sameSize(depth_));
  ASSERT_TRUE(exr.sameSize(depth_));
  for (std::size_t i = 0; i < depth_.pixelCount(); ++i) {
    const float d = depth_.data()[i];
    if (std::isnan(d)) {
      EXPECT_TRUE(std::isnan(png.data()[i]));  // 0 mm
      EXPECT_TRUE(std::isnan(exr.data()[i]));
    } else {
      EXPECT_NEAR(png.data()[i], d, 1e-6);
      EXPECT_EQ(exr.data()[i], d);
    }
  }
  // An 8-bit picture is no depth image.
  io::writeImage(path("grey.png"), ColorImage(kWidth, kHeight, 1, 0.5f));
  EXPECT_THROW(io::readDepthMap(path("grey.png")), InputError);
  EXPECT_THROW(io::readDepthMap(path("none.png")), InputError);
  EXPECT_THROW(io::writeDepthMap(path("d.jpg"), depth_), InputError);
}

TEST_F(DepthFilesTest, ToolWritesTheLibrarysNormalsAndConfidence) {
  ASSERT_TRUE(fs::exists(DEPTH_TO_NORMALS_BIN)) << DEPTH_TO_NORMALS_BIN;
  io::writeDepthMap(path("d.png"), depth_);
  for (const char* method : {"plane_fit", "central_difference"}) {
    const Result r =
        run("--depth " + path("d.png") + " --camera-info " +
            path("camera.yaml") + " --output " + path("n.exr") +
            " --confidence " + path("c.exr") + " --method " + method);
    ASSERT_EQ(r.exit_code, 0) << r.err;
    EXPECT_TRUE(fs::exists(path("n.png")));
    depth::DepthNormalSettings settings;
    settings.method = depth::normalMethodFromString(method);
    NormalMap expected;
    ScalarMap expected_c;
    depth::depthToNormals(io::readDepthMap(path("d.png")), K_, settings,
                          expected, &expected_c);
    const NormalMap n = io::readNormalMap(path("n.exr"));
    const ScalarMap c = io::readScalarMap(path("c.exr"));
    ASSERT_TRUE(n.sameSize(expected));
    for (int ch = 0; ch < 3; ++ch) {
      for (std::size_t i = 0; i < n.pixelCount(); ++i) {
        const float a = n.plane(ch)[i], b = expected.plane(ch)[i];
        ASSERT_EQ(std::isnan(a), std::isnan(b)) << method << " " << i;
        if (!std::isnan(a)) {
          ASSERT_EQ(a, b) << method << " " << i;
        }
      }
    }
    for (std::size_t i = 0; i < c.pixelCount(); ++i) {
      ASSERT_EQ(c.data()[i], expected_c.data()[i]) << method << " " << i;
    }
    // The hole has no normal.
    EXPECT_TRUE(std::isnan(n.at(0, 12, 8))) << method;
  }
}

TEST_F(DepthFilesTest, ToolRefusesBadInputAndUsage) {
  ASSERT_TRUE(fs::exists(DEPTH_TO_NORMALS_BIN)) << DEPTH_TO_NORMALS_BIN;
  io::writeDepthMap(path("d.exr"), depth_);
  const std::string prefix = "depth_to_normals: error: ";
  const std::string good = "--depth " + path("d.exr") + " --camera-info " +
                           path("camera.yaml") + " --output " + path("n.exr");
  EXPECT_EQ(run(good).exit_code, 0);
  struct Case {
    std::string args;
    int exit_code;
    std::string says;
  };
  const Case cases[] = {
      {good + " --method sobel", 2, "unknown method 'sobel'"},
      {good + " --window-radius 0", 2, "window_radius"},
      {good + " --bogus 1", 2, "unknown option '--bogus'"},
      {"--depth " + path("d.exr") + " --output " + path("n.exr"), 2,
       "missing --camera-info"},
      {"--depth " + path("d.exr") + " --camera-info " + path("camera.yaml") +
           " --output " + path("n.png"),
       2, ".exr or .pfm"},
      {"--depth " + path("missing.png") + " --camera-info " +
           path("camera.yaml") + " --output " + path("n.exr"),
       1, "no such file"},
      {"--depth " + path("d.exr") + " --camera-info " + path("other.yaml") +
           " --output " + path("n.exr"),
       1, "expected the same size"},
  };
  for (const Case& c : cases) {
    const Result r = run(c.args);
    EXPECT_EQ(r.exit_code, c.exit_code) << c.args << ": " << r.err;
    EXPECT_EQ(r.err.rfind(prefix, 0), 0u) << r.err;
    EXPECT_NE(r.err.find(c.says), std::string::npos) << r.err;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
  }
}

}  // namespace
}  // namespace normal_fusion
